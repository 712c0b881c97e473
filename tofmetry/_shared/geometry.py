"""Small geometric helpers used by several packages: rotation angle, SVD plane fit, principal axes,
rigid transform of points, a ray's length per unit of depth.

Pure functions on arrays; points are (N, 3) in any length unit (the result keeps it).
"""

from __future__ import annotations

import numpy as np

from tofmetry.errors import InputError


def rotation_angle_deg(transform: np.ndarray) -> float:
    """Angle [deg] of the rotation part of a pose: ``arccos((trace(R) - 1) / 2)``.

    Parameters
    ----------
    transform : (3, 3) rotation or (4, 4) rigid transform (its upper-left 3x3 is used)

    Returns
    -------
    float in [0, 180]; the argument of the arccos is clipped to [-1, 1] (rounding).
    """
    R = np.asarray(transform, dtype=np.float64)[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def displacement_at(transform: np.ndarray, point: np.ndarray) -> float:
    """How far a rigid ``transform`` (4, 4) moves ``point`` (3,) [m]: ``|R p + t - p|`` [m] (a pose
    error or a loop closure measured at the object, not at the frame's origin)."""
    p = np.asarray(point, np.float64)
    return float(np.linalg.norm(transform[:3, :3] @ p + transform[:3, 3] - p))


def principal_axes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid and principal axes of a point set (eigen-decomposition of the 3 x 3 scatter matrix
    of the centred points: the SVD's axes, at a fraction of its cost for 10^5 points).

    Parameters
    ----------
    points : (N, 3) float, N >= 3

    Returns
    -------
    centroid : (3,) float64
    axes : (3, 3) float64, one unit axis per row, by decreasing spread; the last row is the
        normal of the least-squares plane.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) < 3:
        raise InputError(f"points: at least 3 points are needed for principal axes, found {len(p)}")
    c = p.mean(axis=0)
    q = p - c
    _, vec = np.linalg.eigh(np.einsum("ni,nj->ij", q, q))
    return c, vec[:, ::-1].T


def fit_plane_svd(points: np.ndarray, orient: np.ndarray | None = None) -> np.ndarray:
    """Least-squares (orthogonal) plane through points.

    Parameters
    ----------
    points : (N, 3) float, N >= 3
    orient : optional (3,) direction; the normal is flipped to make a non-negative dot product
        with it (e.g. the normal of a previous fit, or the optical axis).

    Returns
    -------
    (4,) float64 plane ``(n, d)`` with unit normal ``n``: a point ``X`` is on it when
    ``n . X + d = 0``; ``n . X + d`` is the signed distance of ``X``.
    """
    c, axes = principal_axes(points)
    n = axes[2]
    if orient is not None and n @ np.asarray(orient, dtype=np.float64)[:3] < 0:
        n = -n
    return np.r_[n, -n @ c]


def ray_factor(xy: np.ndarray) -> np.ndarray:
    """``rho = sqrt(1 + x^2 + y^2)`` [-] of normalised rays ``xy`` (..., 2): a point's ray length is ``Z rho``
    (camera frame: x right, y down, z forward; Z the depth along the optical axis)."""
    xy = np.asarray(xy, dtype=np.float64)
    return np.sqrt(1.0 + xy[..., 0] ** 2 + xy[..., 1] ** 2)


def skew(v: np.ndarray) -> np.ndarray:
    """(3, 3) cross-product matrix of ``v`` (3,): ``skew(v) @ x == np.cross(v, x)``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def transform_points(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(N, 3) points carried by the (4, 4) rigid transform ``T`` (``p' = R p + t``, same unit as ``t``)."""
    return np.asarray(points) @ T[:3, :3].T + T[:3, 3]


#: above this correlation of a fitted scale and surface offset the shape cannot tell them apart (a
#: box: every face moves alike under both); used wherever a scale is read off a surface
SCALE_OFFSET_MAX_CORRELATION = 0.98


def similarity_offset_jacobian(centred: np.ndarray, normals: np.ndarray, length: float) -> np.ndarray:
    """(N, 8) Jacobian of point-to-plane residuals under a small rotation, translation, scale and
    normal offset: ``n . (w x q + t + s q) + o`` for ``(w / length, t, s, o)``.

    Parameters
    ----------
    centred : (N, 3) points about their centroid [m]; normals : (N, 3) unit normals, all outward
    length : RMS radius of the points [m] (scales the rotation's columns for conditioning)
    """
    q, n = np.asarray(centred, np.float64), np.asarray(normals, np.float64)
    return np.c_[np.cross(q, n) / length, n, np.einsum("ij,ij->i", n, q), np.ones(len(q))]
