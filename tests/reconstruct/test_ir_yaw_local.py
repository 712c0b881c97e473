"""A smooth painted object: the support planes hold the tilt, the pattern picks the yaw (issue 16)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy.spatial import cKDTree

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct._ir_yaw_local import plane_yaw_icp, yaw_sweep_near
from tofmetry.reconstruct._photometric import ir_agreement

NOISE_M = 0.0005  # 0.5 mm depth noise


def _ellipsoid_cap(rng, n: int = 5000, a: float = 0.08, b: float = 0.05, h: float = 0.04):
    """Points and unit normals (pointing up, +z) of the upper half of an ellipsoid lying on z = 0."""
    r = np.sqrt(rng.uniform(0, 0.97, n))
    t = rng.uniform(0, 2 * np.pi, n)
    x, y = a * r * np.cos(t), b * r * np.sin(t)
    z = h * np.sqrt(1 - (x / a) ** 2 - (y / b) ** 2)
    nrm = np.c_[x / a ** 2, y / b ** 2, z / h ** 2]
    return np.c_[x, y, z], nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def _rz(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_plane_yaw_icp_recovers_the_turn_and_shift_of_a_shape_with_a_yaw():
    # an elongated dome (80 x 50 mm, 40 mm high): its outline fixes the yaw. Source and target are
    # two samplings of it; the source's frame turned by 25 deg and shifted by (12, -7) mm
    rng = np.random.default_rng(1)
    q, _ = _ellipsoid_cap(rng)
    b, bn = _ellipsoid_cap(rng)
    yaw_t, t_t = 25.0, np.array([0.012, -0.007])
    a = (q - np.r_[t_t, 0.0]) @ _rz(yaw_t)  # rows: R^T (q - t), so that R a + t = q
    a += rng.normal(0, NOISE_M, a.shape)
    tree = cKDTree(b)
    yaw, shift, _ = plane_yaw_icp(a, b, bn, tree, np.radians(yaw_t + 8.0), t_t + [0.008, 0.006], 0.015)
    yaw, shift, n = plane_yaw_icp(a, b, bn, tree, yaw, shift, 0.006)
    assert n > 0.8 * len(a)
    assert abs(np.degrees(yaw) - yaw_t) < 0.3  # the noise and the sampling: a few tenths of a degree at most
    assert np.linalg.norm(shift - t_t) < 5e-4


def _painted_dome_views(rng, yaw_deg: float, n: int = 5000):
    """A spherical cap (radius 80 mm, 30 mm high) on a table 1 m below a camera that looks straight
    down (x right, y down, z forward = down): a surface of revolution, so its geometry leaves the yaw
    free. Log albedo: two paint blobs. The source camera is turned by ``yaw_deg`` about the cap's
    vertical axis. Returns (source, target, true source -> target transform)."""
    R, h = 0.08, 0.03
    rmax = np.sqrt(R ** 2 - (R - h) ** 2)

    def sample():
        r = rmax * np.sqrt(rng.uniform(0, 0.97, n))
        t = rng.uniform(0, 2 * np.pi, n)
        x, y = r * np.cos(t), r * np.sin(t)
        up = np.sqrt(R ** 2 - r ** 2) - (R - h)  # height above the table
        nrm = np.c_[x, y, np.sqrt(R ** 2 - r ** 2)] / R  # object frame, z up
        la = 0.6 * np.exp(-((x - 0.02) ** 2 + (y - 0.015) ** 2) / 0.012 ** 2) \
            - 0.5 * np.exp(-((x + 0.015) ** 2 + (y + 0.02) ** 2) / 0.015 ** 2)
        return np.c_[x, y, up], nrm, la + rng.normal(0, 0.05, n)

    flip = np.diag([1.0, -1.0, -1.0])  # object (z up) -> camera (z down the view); table at z = 1 m
    centre = np.array([0.0, 0.0, 1.0])

    def view(turn):
        p, nrm, la = sample()
        p, nrm = p @ _rz(-turn).T, nrm @ _rz(-turn).T  # the object seen turned by -turn
        pc = p @ flip.T + centre + rng.normal(0, NOISE_M, p.shape)
        ncam = nrm @ flip.T
        return SimpleNamespace(obj_points=pc, mid_points=pc, icp_points=pc, mid_normals=ncam, obj_normals=ncam,
                               obj_ir=la, icp_ir=la, tree=cKDTree(pc), near_depth_m=None, intr=None,
                               plane=np.array([0.0, 0.0, -1.0, 1.0]))

    src, tgt = view(yaw_deg), view(0.0)
    T = np.eye(4)
    T[:3, :3] = flip @ _rz(yaw_deg) @ flip.T
    T[:3, 3] = centre - T[:3, :3] @ centre
    return src, tgt, T


def _turned(T: np.ndarray, deg: float) -> np.ndarray:
    """``T`` followed by a turn of ``deg`` about the dome's axis (the camera's z axis at x = y = 0)."""
    U = np.eye(4)
    U[:3, :3] = _rz(deg)
    return U @ T


def test_the_pattern_picks_the_yaw_the_geometry_leaves_free():
    rng = np.random.default_rng(2)
    src, tgt, T_true = _painted_dome_views(rng, 40.0)
    start = _turned(T_true, 9.0)  # the geometric registration kept a pose 9 deg off (as on the pebbles)
    swept = yaw_sweep_near(src, tgt, start, 15.0, 1.0, (0.015, 0.006))
    assert len(swept) == 31
    errs = np.array([rotation_angle_deg(np.linalg.inv(T_true) @ T) for _, T in swept])
    fits = np.array([_fitness(src, tgt, T) for _, T in swept])
    assert fits.max() - fits.min() < 0.02  # the geometry cannot tell the yaws apart...
    corr = np.array([ir_agreement(src, tgt, T, 0.003) for _, T in swept])
    best = int(np.argmax(corr))
    # ...the pattern can: its peak lies at the truth, within the step and the noise's share
    assert errs[best] < 1.0 + 0.5, (errs[best], corr[best])
    assert corr[best] > 0.8 and corr[best] - corr[np.argmax(errs)] > 0.1  # blobs 12-15 mm wide: a broad peak


def test_the_sweep_fits_the_shift_where_the_turn_is_not_about_the_object_centre():
    # the same dome, the start turned 9 deg about an axis 40 mm beside the dome's: the sweep turns
    # about the target object's centre and refits the shift, so the yaw nearest the truth lands on it
    rng = np.random.default_rng(5)
    src, tgt, T_true = _painted_dome_views(rng, -25.0)
    U = np.eye(4)
    U[:3, :3] = _rz(9.0)
    U[:3, 3] = np.array([0.04, 0.0, 0.0]) - _rz(9.0) @ np.array([0.04, 0.0, 0.0])
    swept = yaw_sweep_near(src, tgt, U @ T_true, 15.0, 1.0, (0.015, 0.006))
    errs = [rotation_angle_deg(np.linalg.inv(T_true) @ T) for _, T in swept]
    k = int(np.argmin(errs))
    E = np.linalg.inv(T_true) @ swept[k][1]
    assert abs(abs(swept[k][0]) - 9.0) < 1e-9
    assert rotation_angle_deg(E) < 0.2 and np.linalg.norm(E[:3, 3]) < 1e-3


def _fitness(src, tgt, T, radius_m: float = 0.003) -> float:
    """Share of the source points within ``radius_m`` of the target under ``T`` (every point visible here)."""
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    d, _ = tgt.tree.query(p, distance_upper_bound=radius_m)
    return float(np.isfinite(d).mean())

