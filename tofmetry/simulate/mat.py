"""The printed dot mat as the virtual sensor sees it: a texture of the ground plane
(:class:`tofmetry._shared.dot_mat.DotMat`, the study's flat targets as a pattern)."""

from __future__ import annotations

import numpy as np

from tofmetry._shared.dot_mat import A1_M, DotMat, dot_mask, dot_mat_image

__all__ = ["A1_M", "DotMat", "dot_mask", "dot_mat_image", "dot_mat_texture"]


def dot_mat_texture(mat: DotMat, ground_albedo: float, label: int = 0):
    """The ground plane's texture with ``mat`` on it (:data:`~tofmetry.simulate.surfaces.Texture`;
    the plane's (s, t) are world x, y [m])."""

    def tex(s, t):
        on, dot = dot_mask(mat, s, t)
        alb = np.where(on, np.where(dot, mat.dark, mat.light), ground_albedo)
        n = s.shape[0]
        return alb, np.full(n, label, np.int32), np.zeros(n, bool), np.zeros(n)

    return tex
