"""The global adjustment's pose prior, on a surface of revolution (its axis leaves one rotation free)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tofmetry.reconstruct import AdjustView, global_adjust, rotation_angle_deg
from tofmetry.reconstruct._adjust_prior import pose_prior_terms

from .test_adjust import _look_at


def _vase(n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Vase about the world z axis, radius 60-100 mm over 250 mm of height [m]; samples and outward normals."""
    h = rng.random(n) * 0.25
    t = rng.random(n) * 2 * np.pi
    r = 0.08 + 0.02 * np.sin(h * 25.0)
    dr = 0.02 * 25.0 * np.cos(h * 25.0)
    p = np.column_stack([r * np.cos(t), r * np.sin(t), h])
    nrm = np.column_stack([np.cos(t), np.sin(t), -dr])
    return p, nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def _views(poses, rng, noise_m, n=30000, surface=_vase):
    """Each camera's visible samples of ``surface(n, rng) -> (points, normals)`` with depth noise, as AdjustViews."""
    out = []
    for T in poses:
        p, nrm = surface(n, rng)
        vis = np.einsum("ij,ij->i", nrm, T[:3, 3] - p) / np.linalg.norm(T[:3, 3] - p, axis=1) > 0.3
        Ti = np.linalg.inv(T)
        pc = p[vis] @ Ti[:3, :3].T + Ti[:3, 3]
        nc = nrm[vis] @ Ti[:3, :3].T
        pc = pc * (1 + rng.normal(0, noise_m, (len(pc), 1)) / pc[:, 2:3])  # depth noise along the rays
        out.append(AdjustView(pc[::3], nc[::3], pc, nc))
    return out


def _about_axis(T: np.ndarray, deg: float) -> np.ndarray:
    R = np.eye(4)
    R[:3, :3] = Rotation.from_rotvec([0, 0, np.radians(deg)]).as_matrix()
    return R @ T


def _scan(rng, noise_m):
    ang = np.radians([0, 40, 80, 120])
    poses = np.array([_look_at(np.array([0.9 * np.cos(a), 0.9 * np.sin(a), 0.45]), np.array([0, 0, 0.12]))
                      for a in ang])
    rel = np.array([np.linalg.inv(poses[0]) @ T for T in poses])  # view 0's frame is the world
    return _views(poses, rng, noise_m), rel


def test_prior_terms_vanish_at_the_prior_and_pull_back_in_one_step():
    rng = np.random.default_rng(0)
    P0 = np.array([_look_at(np.array([np.cos(a), np.sin(a), 0.4]), np.zeros(3)) for a in (0.0, 0.7, 1.4)])
    c = np.array([0.0, 0.0, 0.1])
    H, b = pose_prior_terms(P0, P0, c, np.radians(0.5), 5e-3, 1.0)
    assert H.shape == (12, 12) and np.allclose(b, 0)
    # a rotation about the object centre moves the centre by nothing: charged as rotation only
    P = P0.copy()
    Tc = np.eye(4)
    Tc[:3, :3] = Rotation.from_rotvec(rng.normal(size=3) * 0.01).as_matrix()
    Tc[:3, 3] = c - Tc[:3, :3] @ c
    P[1] = Tc @ P0[1]
    H, b = pose_prior_terms(P, P0, c, np.radians(0.5), 5e-3, 1.0)
    dx = -np.linalg.solve(H, b)
    assert np.allclose(dx[6:], 0) and np.allclose(dx[:3], -Rotation.from_matrix(Tc[:3, :3]).as_rotvec(), atol=1e-6)
    assert np.linalg.norm(dx[3:6] + np.cross(dx[:3], c)) < 1e-6  # and the centre stays: w x c + t = 0


def _axis_coordinates(T_rel: np.ndarray, T0: np.ndarray) -> np.ndarray:
    """Distance of the camera from the vase's axis and its height along it [m]: what the geometry
    of a surface of revolution observes (its rotation about the axis it does not)."""
    c = (T0 @ T_rel)[:3, 3]
    return np.array([np.hypot(c[0], c[1]), c[2]])


def test_the_prior_holds_the_free_rotation_and_leaves_the_observed_directions_to_the_points():
    """Four noisy views of a vase (0.5 mm along the rays), started at the truth except view 2,
    rotated 1 deg about the vase's axis, and view 3, shifted 3 mm across it.

    Without the prior the rotation the geometry leaves free runs away (noise alone moves it by
    degrees: measured 2-95 deg); with a 0.5 deg prior every view stays within that of its start,
    while the shift the points do observe (the camera's distance from the axis, its height) is
    removed to within 0.5 mm."""
    rng = np.random.default_rng(4)
    views, rel = _scan(rng, noise_m=0.5e-3)
    T0 = _look_at(np.array([0.9, 0.0, 0.45]), np.array([0, 0, 0.12]))  # view 0 = the world; the vase's frame
    to_vase = np.linalg.inv(T0)
    start = rel.copy()
    start[2] = to_vase @ _about_axis(T0 @ rel[2], 1.0)
    radial = to_vase[:3, :3] @ ((T0 @ rel[3])[:3, 3] * [1.0, 1.0, 0.0])
    start[3][:3, 3] += 3e-3 * radial / np.linalg.norm(radial)
    assert abs(_axis_coordinates(start[3], T0) - _axis_coordinates(rel[3], T0))[0] > 2.9e-3
    free = global_adjust(views, start, 0.9, estimate_gain=False, sigma_inflation=5.0)
    held = global_adjust(views, start, 0.9, estimate_gain=False, sigma_inflation=5.0,
                         pose_prior_deg=0.5, pose_prior_m=5e-3)
    walk = [rotation_angle_deg(np.linalg.inv(start[k]) @ P) for k, P in enumerate(free.poses)]
    assert max(walk) > 2.0, walk
    walk = [rotation_angle_deg(np.linalg.inv(start[k]) @ P) for k, P in enumerate(held.poses)]
    assert max(walk) < 0.5, walk
    for k in range(1, 4):
        err = _axis_coordinates(held.poses[k], T0) - _axis_coordinates(rel[k], T0)
        assert np.abs(err).max() < 0.5e-3, (k, err)
