"""The IR albedo as a photometric ICP term fixes a slide that the geometry leaves free (issue 16)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from tofmetry.reconstruct._o3d import icp
from tofmetry.reconstruct._photometric import albedo_intensity, photometric_icp


def _painted_cylinder(rng, shift_m: float, n: int = 6000):
    """Upper half of a horizontal cylinder (radius 40 mm, 300 mm long, axis along x) with a
    two-tone checker pattern (45 mm period along the axis, 4 cells round it; log albedo +-0.55), sampled at random; the
    whole view shifted by ``shift_m`` along the axis (points and pattern move together)."""
    x = rng.uniform(-0.15, 0.15, n)
    a = rng.uniform(0.15 * np.pi, 0.85 * np.pi, n)
    r = 0.04
    p = np.c_[x, -r * np.sin(a), 1.0 - r * np.cos(a)]  # camera looks along +z at the cylinder from above (y down)
    nrm = np.c_[np.zeros(n), -np.sin(a), -np.cos(a)]
    la = 0.55 * np.tanh(np.sin(2 * np.pi * x / 0.045) * np.cos(4 * a) / 0.3) + rng.normal(0, 0.05, n)
    p = p + [shift_m, 0.0, 0.0] + rng.normal(0, 0.0005, (n, 3))  # 0.5 mm depth noise
    return SimpleNamespace(icp_points=p, icp_normals=nrm, icp_ir=la)


def test_albedo_intensity_range():
    v = albedo_intensity(np.array([-10.0, -1.1, 0.0, 1.1, 10.0]))
    assert v.min() == 0.0 and v.max() == 1.0 and v[2] == 0.5 and np.isclose(v[3] - v[1], 0.55)


def test_photometric_icp_fixes_the_slide_along_a_cylinder():
    rng = np.random.default_rng(3)
    tgt = _painted_cylinder(rng, 0.0)
    src = _painted_cylinder(rng, 0.0)  # another sampling of the same surface: truth is the identity
    init = np.eye(4)
    init[0, 3] = 0.008  # started 8 mm along the axis
    geo = icp(src.icp_points, tgt.icp_points, tgt.icp_normals, init, 0.006).transform
    pho = photometric_icp(src, tgt, init, (0.006, 0.003))
    def moved_mm(T):  # largest displacement of the surface points by T (truth: identity)
        p = tgt.icp_points
        return 1e3 * np.linalg.norm(p @ T[:3, :3].T + T[:3, 3] - p, axis=1).max()

    # the geometry holds the slide where it started (a cylinder matches itself along and round its axis)...
    assert moved_mm(geo) > 6.0
    # ...the pattern brings it back to within the noise (0.5 mm) and a fraction of a pattern cell
    assert moved_mm(pho) < 1.0


def test_photometric_icp_without_correspondences_returns_none():
    """A start that leaves no source point within the radius of the target is a failed refinement
    (None: the caller keeps its geometric registration), not an Open3D error out of the run."""
    rng = np.random.default_rng(4)
    tgt = _painted_cylinder(rng, 0.0)
    src = _painted_cylinder(rng, 0.0)
    init = np.eye(4)
    init[2, 3] = 0.5  # 0.5 m away along the line of sight: nothing within 6 mm
    assert photometric_icp(src, tgt, init, (0.006, 0.003)) is None
