"""Hypotheses the scan's path implies (tofmetry.reconstruct._path_implied): a box whose pairs were
registered turned over, with no other hypothesis, is found again from the path's steps -- and a
pair whose points do not fit the implied pose is left as it was."""

from __future__ import annotations

import numpy as np

import tofmetry.reconstruct._select_stage as stage
from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct import PairResult, PoseGraphBuilder
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._path_implied import METHOD, path_implied_hypotheses
from tofmetry.simulate.paths import handheld

CENTRE = np.array([0.0, 0.0, 0.1])


def _half_turn() -> np.ndarray:
    T = np.diag([-1.0, -1.0, 1.0, 1.0])
    T[:3, 3] = 2 * CENTRE * [1, 1, 0]  # about the vertical through CENTRE
    return T


def _scan(n: int = 7, seed: int = 5):
    """A hand-held loop of ``n`` views about CENTRE; pairs 0->1 and 3->4 registered turned over by
    half a turn about the object's vertical (their only hypothesis), every other pair right, and
    the closing pair 0 -> n-1: the two half turns cancel, the loop closes."""
    P = [np.asarray(T) for T in handheld(n, 1.0, 30.0, CENTRE, np.random.default_rng(seed)).poses]
    pairs = []
    for i in range(n - 1):
        T = np.linalg.inv(P[i + 1]) @ (_half_turn() if i in (0, 3) else np.eye(4)) @ P[i]
        pairs.append(PairResult(i, i + 1, T, 0.95, 1.0, np.eye(6) * 1000, "fpfh+icp", True))
    pairs.append(PairResult(0, n - 1, np.linalg.inv(P[n - 1]) @ P[0], 0.95, 1.0, np.eye(6) * 1000, "fpfh+icp", True))
    return P, pairs


def _register_on(P, fit: float, steps: list | None = None):
    """A pair's search for a turn of ``step`` +- ``tol`` [deg]: finds the true pose (fitness ``fit``);
    ``steps`` collects the turns asked for."""
    calls = []

    def register(i, j, step, tol):
        calls.append((i, j))
        if steps is not None:
            steps.append((step, tol))
        return PairResult(i, j, np.linalg.inv(P[j]) @ P[i], fit, 1.0, np.eye(6) * 1000, "plane-yaw+icp", True)
    return register, calls


def _mock(register):
    """register_pair as the selection stage calls it for a turn (no init), the search mocked."""
    def call(src, tgt, i, j, rc, init=None, global_search=True):
        assert init is None and rc.turntable_step_deg is not None
        return register(i, j, rc.turntable_step_deg, rc.turntable_tol_deg)
    return call


def _graph(P, pairs) -> PoseGraphBuilder:
    pg = PoseGraphBuilder(len(P), [f"{k:02d}" for k in range(len(P))])
    for p in pairs:
        pg.add(p)
    pg.centres = np.array([np.linalg.inv(T)[:3, :3] @ CENTRE + np.linalg.inv(T)[:3, 3] for T in P])
    pg.ups = np.array([T[:3, :3].T @ [0.0, 0.0, 1.0] for T in P])
    return pg


def test_the_steps_that_do_not_walk_get_the_pose_the_path_implies():
    P, pairs = _scan()
    pg = _graph(P, pairs)
    rep = pg.select_hypotheses(2.0, 10.0, 0.05, path_max_ratio=3.0)
    assert rep["path_steps"] == ["00->01", "03->04"], rep
    asked = []
    register, calls = _register_on(P, 0.95, asked)
    new, found = path_implied_hypotheses(len(P), pairs, pg.pairs, pg.centres, pg.ups, register, 3.0, 0.3)
    assert calls == [(0, 1), (3, 4)] and [f["edge"] for f in found] == [(0, 1), (3, 4)], found
    for step, tol in asked:  # the path's median step (the loop's 7 steps of 360 / 7 +- 35 %), +- half of it
        assert 35.0 < step < 70.0 and tol == 0.5 * step
    for k in (0, 3):
        alt = new[k].alternatives[-1]
        assert alt.method == METHOD and new[k].transform is pairs[k].transform
        np.testing.assert_allclose(alt.transform, np.linalg.inv(P[k + 1]) @ P[k], atol=1e-9)


def _staged(monkeypatch, fit: float):
    """:func:`_scan`'s pairs through the selection stage, the search finding the true pose at ``fit``."""
    P, pairs = _scan()
    register, _ = _register_on(P, fit)
    monkeypatch.setattr(stage, "register_pair", _mock(register))
    pg = _graph(P, pairs)
    stage.select_with_implied(pg, [None] * len(P), RegistrationConfig())
    return P, pg


def test_the_selection_stage_takes_the_walk_and_says_so(monkeypatch):
    P, pg = _staged(monkeypatch, 0.95)
    sel = pg.selection
    assert not sel["reasons"] and not sel.get("path_steps"), sel
    assert [d["edge"] for d in sel["path_implied"]] == ["00->01", "03->04"], sel
    res = pg.optimize(0.003)
    for k in range(len(P)):
        E = np.linalg.inv(np.linalg.inv(P[0]) @ P[k]) @ res.poses[k]
        assert rotation_angle_deg(E) < 1e-4, k  # deg (arccos near 1)


def test_a_pair_whose_points_do_not_fit_the_implied_pose_is_left(monkeypatch):
    # the search about the implied turn matches far fewer points (0.5 against 0.95 kept): not a hypothesis
    _, pg = _staged(monkeypatch, 0.5)
    assert pg.selection["path_steps"] == ["00->01", "03->04"] and not pg.selection.get("path_implied")
    assert any("do not walk around the object" in r for r in pg.selection["reasons"])


def test_turned_skip_edges_that_bridge_failed_pairs_are_searched_again(monkeypatch):
    # a box's 7 views: the successive pairs 0->1 and 3->4 failed the gates and the skip edges 0->2
    # and 3->5 that bridge them were registered turned over: views 1-3 sit on the far side, the
    # path steps back at 00->01 and 03->04; the search at those steps finds both failed pairs and
    # both skip edges right, and the choice that walks is taken
    P, _ = _scan()
    n = len(P)

    def edge(i, j, ok=True, turned=False):
        T = np.linalg.inv(P[j]) @ (_half_turn() if turned else np.eye(4)) @ P[i]
        return PairResult(i, j, T, 0.95 if ok else 0.2, 1.0, np.eye(6) * 1000, "fpfh+icp", ok)

    pairs = [edge(0, 1, ok=False), edge(0, 2, turned=True), edge(1, 2), edge(2, 3), edge(3, 4, ok=False),
             edge(3, 5, turned=True), edge(4, 5), edge(5, 6), edge(0, n - 1)]
    register, _ = _register_on(P, 0.95)
    monkeypatch.setattr(stage, "register_pair", _mock(register))
    pg = _graph(P, pairs)
    stage.select_with_implied(pg, [None] * n, RegistrationConfig())
    sel = pg.selection
    assert not sel["reasons"], sel
    assert sorted(d["edge"] for d in sel["path_implied"]) == ["00->01", "00->02", "03->04", "03->05"], sel
    res = pg.optimize(0.003)
    for k in range(n):
        E = np.linalg.inv(np.linalg.inv(P[0]) @ P[k]) @ res.poses[k]
        assert rotation_angle_deg(E) < 1e-4, k
