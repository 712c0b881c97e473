"""The model's world frame: the support plane as z = 0 (study §5: objects stand on a table or the ground).

A model left in the first camera's frame is tilted and far from the origin: a user cannot place
it, measure heights or compare it with a drawing. :func:`support_plane_frame` builds the frame

* z: the support plane's normal, pointing up (toward the cameras), the plane at z = 0;
* origin: the object's footprint centre (the centroid of its points projected on the plane);
* x: the first camera's viewing direction projected on the plane (a turntable's "front");

and :func:`transform_plane` (with :func:`tofmetry._shared.geometry.transform_points`) carries the plane,
poses, clouds and meshes into it. Without a support plane (segmentation skipped) the first camera's
frame is kept.
"""

from __future__ import annotations

import numpy as np

from tofmetry.errors import InputError


def support_plane_frame(plane: np.ndarray, object_points: np.ndarray, camera0: np.ndarray) -> np.ndarray:
    """(4, 4) transform from the reconstruction frame to the support-plane frame (module docstring).

    Parameters
    ----------
    plane : (4,) support plane in the reconstruction frame, unit normal up (toward the cameras),
        height = n . p + d [m]
    object_points : (N, 3) [m] object points in the reconstruction frame
    camera0 : (4, 4) camera-to-world pose of the first view in the reconstruction frame

    Returns
    -------
    (4, 4) float64 rigid transform: world_new = W @ world_old
    """
    pl = np.asarray(plane, np.float64).reshape(4)
    n = pl[:3] / np.linalg.norm(pl[:3])
    d = pl[3] / np.linalg.norm(pl[:3])
    if len(object_points) == 0:
        raise InputError("support_plane_frame: no object points")
    c = np.asarray(object_points, np.float64).mean(0)
    o = c - (n @ c + d) * n
    fwd = np.asarray(camera0, np.float64)[:3, 2]
    x = fwd - (fwd @ n) * n
    if np.linalg.norm(x) < 1e-6:  # camera looking straight down: use its x axis
        x = camera0[:3, 0] - (camera0[:3, 0] @ n) * n
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    R = np.stack([x, y, n])  # rows: new axes in old coordinates
    W = np.eye(4)
    W[:3, :3] = R
    W[:3, 3] = -R @ o
    return W


def transform_plane(plane: np.ndarray, W: np.ndarray) -> np.ndarray:
    """A plane (n, d) with n . p + d = 0 carried by the rigid ``W``."""
    n = W[:3, :3] @ plane[:3]
    return np.r_[n, plane[3] - n @ W[:3, 3]]
