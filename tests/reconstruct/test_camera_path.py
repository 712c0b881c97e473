"""The cameras' walk around the object (tofmetry.reconstruct._camera_path)."""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct._camera_path import closes_once, path_anomalies, path_steps
from tofmetry.simulate.paths import handheld, turntable, two_rings

CENTRE = np.array([0.1, -0.2, 0.05])
UP = np.array([0.0, 0.0, 1.0])


def _turn(P: np.ndarray, deg: float) -> np.ndarray:
    """``P`` (camera-to-world) carried about the vertical through CENTRE by ``deg``."""
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = CENTRE - R @ CENTRE
    return T @ P


def test_random_hand_held_and_turntable_paths_walk():
    # every path the simulator draws steps one way, each step within its +-35 % of the mean
    rng = np.random.default_rng(3)
    for k in range(200):
        n = int(rng.integers(6, 17))
        d = float(rng.uniform(0.6, 1.5))
        el = float(rng.uniform(15, 45))
        start = float(rng.uniform(0, 360))
        for path in (handheld(n, d, el, CENTRE, rng, start), turntable(n, d, el, CENTRE, start)):
            P = np.array(path.poses)
            s = path_steps(P, CENTRE, UP if k % 2 else -UP)  # the vertical's sign does not matter
            assert np.isfinite(s).all() and not path_anomalies(s), (k, path.kind, np.round(s))
    ring = turntable(8, 1.0, 30.0, CENTRE)
    np.testing.assert_allclose(np.abs(path_steps(np.array(ring.poses), CENTRE, UP)), 45.0, atol=1e-9)


def test_a_run_of_views_turned_over_steps_back_where_it_begins_and_ends():
    # views 2..4 of 8 placed half a turn about the vertical (a box matched turned over): the steps
    # into and out of the run go back by 135 deg against 45 deg steps
    P = np.array(turntable(8, 1.0, 30.0, CENTRE).poses)
    Q = P.copy()
    Q[2:5] = [_turn(T, 180.0) for T in P[2:5]]
    assert path_anomalies(path_steps(Q, CENTRE, UP)) == [1, 4]
    # a quarter turn: into the run 135 deg on (3 median steps: not yet a leap), out of it 45 deg back
    Q[2:5] = [_turn(T, 90.0) for T in P[2:5]]
    s = path_steps(Q, CENTRE, UP)
    assert path_anomalies(s) == [4] and path_anomalies(s, max_ratio=2.5) == [1, 4]


def test_zenithal_views_and_a_second_ring_have_no_step():
    # the plan's two rings: the step from the lower ring to the higher one is no step of either
    s = path_steps(np.array(two_rings(6, 4, 1.0, 25.0, 60.0, CENTRE).poses), CENTRE, UP)
    assert np.isnan(s[5]) and np.isfinite(np.delete(s, 5)).all() and not path_anomalies(s)
    P = np.array(turntable(6, 1.0, 30.0, CENTRE).poses)
    top = np.array(turntable(1, 1.0, 85.0, CENTRE).poses)
    s = path_steps(np.concatenate([P[:3], top, P[3:]]), CENTRE, UP)
    assert np.isnan(s[2]) and np.isnan(s[3]) and not path_anomalies(s)
    assert path_anomalies(s[:2]) == []  # too few steps: no verdict
    # a view left out: the step across it spans two scan steps, and is taken per scan step
    s = path_steps(np.delete(np.array(turntable(9, 1.0, 30.0, CENTRE).poses), [2, 3, 4], axis=0), CENTRE, UP)
    assert path_anomalies(s) == [1] and path_anomalies(s, gaps=[1, 4, 1, 1, 1]) == []


def _centres(P: np.ndarray) -> np.ndarray:
    """The object centre in each camera's frame."""
    return np.array([np.linalg.inv(T)[:3, :3] @ CENTRE + np.linalg.inv(T)[:3, 3] for T in P])


def test_a_scan_that_goes_round_closes_once_and_one_that_does_not_never():
    rng = np.random.default_rng(5)
    for k in range(100):
        n = int(rng.integers(6, 17))
        d, el, start = float(rng.uniform(0.6, 1.5)), float(rng.uniform(15, 45)), float(rng.uniform(0, 360))
        for path in (handheld(n, d, el, CENTRE, rng, start), turntable(n, d, el, CENTRE, start)):
            P = np.array(path.poses)
            views = list(range(n))
            assert closes_once(P, views, n, _centres(P), UP if k % 2 else -UP, 3.0), (k, path.kind)
            # a view left out of the model: the step across it counts per scan step
            m = int(rng.integers(1, n - 1))
            keep = [v for v in views if v != m]
            assert closes_once(P[keep], keep, n, _centres(P), None, 3.0), (k, path.kind, m)
    # half a turn in 6 views (30 deg steps): closing it leaps 180 deg
    P = np.array(turntable(12, 1.0, 30.0, CENTRE).poses)[:6]
    assert not closes_once(P, list(range(6)), 6, _centres(P), UP, 3.0)
    # a run of views turned over (a box matched turned by its symmetry) does not walk
    Q = np.array(turntable(8, 1.0, 30.0, CENTRE).poses)
    Q[3:6] = [_turn(T, 180.0) for T in Q[3:6]]
    assert not closes_once(Q, list(range(8)), 8, _centres(Q), UP, 3.0)
    # too few views to tell
    P = np.array(turntable(3, 1.0, 30.0, CENTRE).poses)
    assert not closes_once(P, [0, 1, 2], 3, _centres(P), UP, 3.0)
