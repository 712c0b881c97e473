"""The points a target camera observed (:func:`tofmetry.reconstruct._regview.seen_by`) and the ICP stage
that matches only those (:func:`tofmetry.reconstruct._icp_stages.stage_icp`, ``icp_seen_only``)."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import minimum_filter

from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._icp_stages import stage_icp
from tofmetry.reconstruct._o3d import icp
from tofmetry.reconstruct._regview import RegView, seen_by
from tofmetry.sensor import CameraIntrinsics

INTR = CameraIntrinsics(512, 424, 365.0, 365.0, 256.0, 212.0)


def _wall_target(z_m: float = 1.0) -> RegView:
    """A target camera that saw a wall at ``z_m`` filling its image (its depth image is all the test uses)."""
    p = np.array([[0.0, 0.0, z_m]])
    n = np.array([[0.0, 0.0, -1.0]])
    near = np.full((INTR.height, INTR.width), z_m, np.float32)
    return RegView("wall", p, n, p, p, n, near_depth_m=near, intr=INTR)


def test_only_the_points_on_what_the_target_saw_count_as_seen():
    tgt = _wall_target(1.0)
    toward = [0.0, 0.0, -1.0]
    pts = np.array([
        [0.0, 0.0, 1.002],   # on the wall, facing the camera: seen
        [0.1, 0.05, 0.998],  # on the wall: seen
        [0.0, 0.0, 1.05],    # 50 mm behind the wall: hidden from it
        [0.0, 0.0, 0.95],    # 50 mm in front: in space the camera saw through
        [0.0, 0.0, 1.0],     # on the wall but facing away
        [2.0, 0.0, 1.0],     # outside the image
        [0.0, 0.0, -1.0],    # behind the camera
    ])
    nrm = np.array([toward, toward, toward, toward, [0.0, 0.0, 1.0], toward, toward])
    m = seen_by(pts, nrm, tgt, np.eye(4), 0.01)
    assert m.tolist() == [True, True, False, False, False, False, False]
    # the same points moved by the pose: 60 mm toward the camera puts the hidden one on the wall
    T = np.eye(4)
    T[2, 3] = -0.05
    assert seen_by(pts, nrm, tgt, T, 0.01)[2]


def test_without_a_depth_image_every_point_counts():
    tgt = RegView("t", np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)))
    assert seen_by(np.ones((4, 3)), np.ones((4, 3)), tgt, np.eye(4), 0.01).all()


def _bumpy_wall(n: int = 60):
    """A wall 1 m away with Gaussian bumps (so that every pose is determined): points, normals toward -z."""
    g = np.linspace(-0.15, 0.15, n)
    X, Y = np.meshgrid(g, g)
    Z = 1.0 + 0.02 * np.exp(-((X - 0.05) ** 2 + Y ** 2) / 0.002) - 0.015 * np.exp(-((X + 0.06) ** 2 + (Y - 0.05) ** 2) / 0.001)
    P = np.stack([X, Y, Z], -1).reshape(-1, 3)
    N = np.cross(np.gradient(np.stack([X, Y, Z], -1), axis=1), np.gradient(np.stack([X, Y, Z], -1), axis=0)).reshape(-1, 3)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    N *= -np.sign(N[:, 2:3])
    return P, N


def test_with_the_option_off_the_stage_is_the_plain_icp_and_with_it_on_it_finds_the_same_pose():
    P, N = _bumpy_wall()
    near = np.full((INTR.height, INTR.width), np.inf, np.float32)
    uv = np.rint(INTR.project(P)).astype(int)
    near[uv[:, 1], uv[:, 0]] = P[:, 2]
    tgt = RegView("t", P, N, P, P, N, near_depth_m=minimum_filter(near, size=5), intr=INTR)
    start = np.eye(4)
    start[:3, 3] = [0.004, -0.003, 0.002]
    off = RegistrationConfig()
    T_off = stage_icp(P, N, P, N, tgt, start, 0.015, off, 50)
    assert np.allclose(T_off, icp(P, P, N, start, 0.015, kernel=off.kernel, max_iter=50).transform)
    T_on = stage_icp(P, N, P, N, tgt, start, 0.015, RegistrationConfig(icp_seen_only=True), 50)
    # every point is on what the target saw: the same surface, the same pose (the identity), to the ICP's convergence
    for T in (T_off, T_on):
        assert np.linalg.norm(T[:3, 3]) < 2e-4
