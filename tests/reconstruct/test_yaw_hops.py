"""Yaw hops after a pair's ICP (:func:`tofmetry.reconstruct._icp_stages.yaw_hops`): the last ICP stage
locked one period off on a ribbed object is brought back where the object points match better,
and a pose the points do not decide (a plain surface of revolution) is left where it was."""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._icp_stages import refine_fine, yaw_hops
from tofmetry.reconstruct._regview import RegView, object_fitness

AXIS = np.array([0.0, 0.0, 1.0])  # the column's axis (parallel to y, the support plane's normal) [m]
PLANE = np.array([0.0, -1.0, 0.0, 0.3])  # support plane y = 0.3 m, normal up (toward -y)


def _column(rib_mm: float, boss_mm: float, period_deg: float = 8.0, spacing_m: float = 0.002):
    """Points and outward normals of a column of radius 80 mm, 100 mm tall, standing on the support
    plane 1 m in front of the camera: ribs of ``rib_mm`` every ``period_deg`` and one raised boss of
    ``boss_mm`` (20 deg x 50 mm) that only the right yaw lines up. (N, 3) [m] each."""
    r0 = 0.08
    th = np.radians(np.arange(0.0, 360.0, np.degrees(spacing_m / r0)))
    T, Y = np.meshgrid(th, np.arange(0.2, 0.3, spacing_m))
    boss = (np.abs(np.degrees(T) - 90.0) < 10.0) & (np.abs(Y - 0.25) < 0.025)
    R = r0 + 1e-3 * (rib_mm * np.cos(2 * np.pi * np.degrees(T) / period_deg) + boss_mm * boss)
    P = np.stack([R * np.cos(T), Y, AXIS[2] + R * np.sin(T)], -1)
    N = np.cross(np.gradient(P, axis=0), np.gradient(P, axis=1))
    N /= np.linalg.norm(N, axis=-1, keepdims=True)
    N *= np.sign(np.sum(N[..., [0, 2]] * (P[..., [0, 2]] - AXIS[[0, 2]]), -1))[..., None]
    return P.reshape(-1, 3), N.reshape(-1, 3)


def _view(rib_mm: float, boss_mm: float) -> RegView:
    p, n = _column(rib_mm, boss_mm)
    return RegView("column", p, n, p, p, n, plane=PLANE, mid_points=p, mid_normals=n)


def _turned(deg: float) -> np.ndarray:
    """The column turned by ``deg`` about its own axis, (4, 4)."""
    a = np.radians(deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0.0, -np.sin(a)], [0.0, 1.0, 0.0], [np.sin(a), 0.0, np.cos(a)]]
    T[:3, 3] = AXIS - T[:3, :3] @ AXIS
    return T


def test_a_pose_locked_one_rib_off_hops_back_to_where_the_boss_lines_up():
    v = _view(rib_mm=2.0, boss_mm=8.0)
    cfg = RegistrationConfig()
    for start in (8.0, -8.0, 5.0):
        stuck = refine_fine(v, v, _turned(start), cfg)
        # the last ICP stage alone stays a rib period off: the ribs hold it there
        assert rotation_angle_deg(stuck) > 7.0
        fit_stuck = object_fitness(v, v, stuck, 0.003)[0]
        T = yaw_hops(v, v, stuck, cfg)
        # the same points as target: the right pose is the identity, to the ICP's convergence
        assert rotation_angle_deg(T) < 0.1 and np.linalg.norm(T[:3, 3]) < 1e-4
        assert object_fitness(v, v, T, 0.003)[0] > fit_stuck + cfg.yaw_hop_min_gain
        # without hops, the pose is the ICP's
        assert np.array_equal(yaw_hops(v, v, stuck, cfg.model_copy(update={"yaw_hops_deg": ()})), stuck)


def test_a_yaw_the_points_do_not_decide_is_left_alone():
    # a plain column: every yaw matches alike, so no hop raises the share of points matched
    v = _view(rib_mm=0.0, boss_mm=0.0)
    cfg = RegistrationConfig()
    start = refine_fine(v, v, _turned(6.0), cfg)
    assert np.array_equal(yaw_hops(v, v, start, cfg), start)


def test_the_hops_look_nearby_only():
    # two rib periods off, the best pose is 16 deg away: beyond the reach, not taken (the reach is the
    # largest hop, 8 deg, unless set; the default's reach, whatever it is, holds the same way)
    v = _view(rib_mm=2.0, boss_mm=8.0)
    for cfg in (RegistrationConfig(yaw_hop_reach_deg=None), RegistrationConfig(yaw_hop_reach_deg=12.0),
                RegistrationConfig()):
        stuck = refine_fine(v, v, _turned(16.0), cfg)
        reach = cfg.yaw_hop_reach_deg or 8.0
        assert rotation_angle_deg(np.linalg.inv(stuck) @ yaw_hops(v, v, stuck, cfg)) <= reach + 1e-6


def test_the_hops_reach_as_far_as_asked():
    # within the reach, two hops in a row bring a pose two rib periods off back to the right one
    v = _view(rib_mm=2.0, boss_mm=8.0)
    cfg = RegistrationConfig(yaw_hop_reach_deg=20.0)
    stuck = refine_fine(v, v, _turned(16.0), cfg)
    assert rotation_angle_deg(stuck) > 15.0
    T = yaw_hops(v, v, stuck, cfg)
    assert rotation_angle_deg(T) < 0.1 and np.linalg.norm(T[:3, 3]) < 1e-4


def test_views_without_a_support_plane_are_not_hopped():
    from dataclasses import replace

    v = replace(_view(rib_mm=2.0, boss_mm=8.0), plane=None)
    T = _turned(8.0)
    assert yaw_hops(v, v, T, RegistrationConfig()) is T
