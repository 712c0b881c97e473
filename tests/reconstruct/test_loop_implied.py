"""Hypotheses a loop implies (:mod:`tofmetry.reconstruct._loop_implied`): a successive pair registered
wrong, whose right pose the global search missed, is found again from the loop the closing edge
makes, where the pair's own points fit that pose better; never where they do not."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

import tofmetry.reconstruct._register as reg
from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct import PairResult, PoseGraphBuilder
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._loop_implied import METHOD, loop_implied_hypotheses
from tofmetry.reconstruct._regview import RegView


def _rot_z(deg: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", deg, degrees=True).as_matrix()
    T[:3, 3] = t
    return T


def _circle(n: int) -> list[np.ndarray]:
    step = 360.0 / n
    return [_rot_z(step * k, (np.cos(np.radians(step * k)), np.sin(np.radians(step * k)), 0.0)) for k in range(n)]


def _true(P, i, j) -> np.ndarray:
    return np.linalg.inv(P[j]) @ P[i]


def _edge(T, i, j, fit, method="test"):
    return PairResult(i, j, T, fit, 1.0, np.eye(6) * 1000, method, True)


def _scan(n=9, wrong_deg=49.5, wrong_fit=0.69):
    """A circle of ``n`` views; successive pair 0 -> 1 registered ``wrong_deg`` off (about the axis
    through the object), every other pair and the closing 0 -> n-1 right."""
    P = _circle(n)
    pairs = [_edge(_true(P, 0, 1) @ _rot_z(wrong_deg), 0, 1, wrong_fit)]
    pairs += [_edge(_true(P, i, i + 1), i, i + 1, 0.97) for i in range(1, n - 1)]
    pairs.append(_edge(_true(P, 0, n - 1), 0, n - 1, 0.97))
    return P, pairs


def _register_on(P, fit_right: float):
    """A pair's ICP from ``init``: converges to the true pose when started within 5 deg of it, with
    fitness ``fit_right``; elsewhere stays put with fitness 0.3 (rejected)."""
    calls = []

    def register(i, j, init):
        calls.append((i, j))
        T = _true(P, i, j)
        E = np.linalg.inv(init) @ T
        ang = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
        if ang <= 5.0:
            return _edge(T, i, j, fit_right, "init+icp")
        return PairResult(i, j, init, 0.3, 5.0, np.eye(6), "init+icp", False)
    return register, calls


def _select(pg):
    return pg.select_hypotheses(2.0, 10.0, 0.05)


def _graph(pairs, n: int) -> PoseGraphBuilder:
    pg = PoseGraphBuilder(n, [f"{k:02d}" for k in range(n)])
    for p in pairs:
        pg.add(p)
    return pg


def test_the_pose_the_loop_implies_replaces_a_wrong_pair_its_points_fit_worse():
    P, pairs = _scan()
    pg = _graph(pairs, len(P))
    before = list(pg.pairs)
    first = _select(pg)
    assert first["dropped"] == ["00->08"]  # the selection alone drops the right closing edge
    register, calls = _register_on(P, 0.99)
    new, found = loop_implied_hypotheses(len(P), before, list(pg.pairs), register, 0.05)
    assert [f["edge"] for f in found] == [(0, 1)]  # only the wrong pair's loop-implied pose is new
    # every pair of the loop was tried from the pose the others imply (the right ones' implied poses
    # carry the wrong pair's error: their ICP from there fails, in this mock)
    assert sorted(calls) == [(i, i + 1) for i in range(8)]
    pg.pairs = new
    again = _select(pg)
    assert not again["dropped"] and again["changed"] == ["00->01"], again
    assert next(p for p in pg.pairs if (p.source, p.target) == (0, 1)).method == METHOD
    res = pg.optimize(0.003)
    assert res.consistency["reliable"], res.consistency
    for k in range(len(P)):
        np.testing.assert_allclose(res.poses[k], np.linalg.inv(P[0]) @ P[k], atol=1e-6)


def test_no_hypothesis_where_the_pairs_points_do_not_fit_the_implied_pose_better():
    # the implied pose fits only as well as the kept one (within the margin): the pair's data do not
    # prefer it, and a hypothesis derived from the loop would close that loop by construction
    P, pairs = _scan()
    pg = _graph(pairs, len(P))
    before = list(pg.pairs)
    _select(pg)
    register, _ = _register_on(P, 0.72)
    _, found = loop_implied_hypotheses(len(P), before, list(pg.pairs), register, 0.05)
    assert found == []


def test_nothing_to_do_without_a_dropped_edge():
    P = _circle(6)
    pairs = [_edge(_true(P, i, i + 1), i, i + 1, 0.97) for i in range(5)] + [_edge(_true(P, 0, 5), 0, 5, 0.97)]
    register, calls = _register_on(P, 0.99)
    new, found = loop_implied_hypotheses(6, pairs, pairs, register, 0.05)
    assert found == [] and calls == [] and new == pairs


class _Names:
    """A scan's names, all the pipeline's selection step reads of it."""

    def __init__(self, n: int):
        self.names = [f"{k:02d}" for k in range(n)]

    def __len__(self) -> int:
        return len(self.names)


def _pipeline_selection(monkeypatch, fit_right: float):
    """The pipeline's selection step on :func:`_scan`, the pair ICP mocked by :func:`_register_on`."""
    import tofmetry.reconstruct._select_stage as stage
    from tofmetry.reconstruct import ReconstructionPipeline

    P, pairs = _scan()
    register, _ = _register_on(P, fit_right)
    monkeypatch.setattr(stage, "register_pair", lambda src, tgt, i, j, rc, init, global_search: register(i, j, init))
    pipe = ReconstructionPipeline(_Names(len(P)))
    pg = _graph(pairs, len(P))
    stage.select_with_implied(pg, [None] * len(P), pipe.cfg.registration)
    return pipe, pg


def test_the_pipeline_keeps_the_reselection_and_says_so(monkeypatch):
    from tofmetry.reconstruct._verdict import assess

    pipe, pg = _pipeline_selection(monkeypatch, 0.99)
    assert not pg.selection["dropped"]
    assert pg.selection["loop_implied"] == [{"edge": "00->01", "fitness": 0.99, "replaced_fitness": 0.69,
                                            "implied_by": "00->08"}]
    res = pg.optimize(0.003)
    verdict = assess(pipe.ds.names, res.edges, res.consistency, {}, None, None)
    assert verdict["reliable"], verdict["reasons"]
    assert any("00->01 registered again from the pose its loop implies" in w for w in verdict["warnings"])


def test_the_pipeline_keeps_the_first_selection_when_the_loops_imply_nothing_better(monkeypatch):
    pipe, pg = _pipeline_selection(monkeypatch, 0.70)  # the implied pose fits as well as the wrong one
    assert pg.selection["dropped"] == ["00->08"] and "loop_implied" not in pg.selection


def _bumpy_view():
    """A bumpy patch 0.2 m square, 1 m in front of the camera (ripples of 10 mm over 50-70 mm):
    points and normals every 2 mm, the same cloud for every role of a RegView [m]."""
    x, y = np.meshgrid(np.arange(-0.1, 0.1, 0.002), np.arange(-0.1, 0.1, 0.002))
    k1, k2 = 2 * np.pi / 0.07, 2 * np.pi / 0.05
    z = 1.0 + 0.01 * np.sin(k1 * x) * np.cos(k2 * y)
    gx, gy = 0.01 * k1 * np.cos(k1 * x) * np.cos(k2 * y), -0.01 * k2 * np.sin(k1 * x) * np.sin(k2 * y)
    p = np.stack([x, y, z], -1).reshape(-1, 3)
    n = np.stack([gx, gy, -np.ones_like(x)], -1).reshape(-1, 3)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return RegView("patch", p, n, p, p, n)


def test_a_loop_closure_icp_whose_wide_stages_slide_away_falls_back_on_its_last_stage(monkeypatch):
    """Without the global search, the pair's ICP may move only within the loop-closure jump bound of
    the pose it starts from. Where the wide stages slide beyond it (as on a smooth object's partial
    overlap), the last stage alone from that pose gives the hypothesis; where that one leaves the
    bound too, there is none."""
    v = _bumpy_view()
    cfg = RegistrationConfig()
    init = _rot_z(1.0, (0.001, 0.0, 0.0))
    slide = _rot_z(20.0)
    monkeypatch.setattr(reg, "refine_mid", lambda src, tgt, T, c: slide @ T)
    p = reg.register_pair(v, v, 0, 1, cfg, init=init, global_search=False)
    # the same cloud on both sides: the right pose is the identity, to the ICP's convergence
    assert p.accepted and p.method.startswith("init+fine-icp")
    assert rotation_angle_deg(p.transform) < 0.05 and np.linalg.norm(p.transform[:3, 3]) < 2e-4
    monkeypatch.setattr(reg, "refine_fine", lambda src, tgt, T, c: slide @ T)
    q = reg.register_pair(v, v, 0, 1, cfg, init=init, global_search=False)
    assert not q.accepted and q.method == "none"


def test_a_retry_not_kept_restores_the_first_selections_tied_choices(monkeypatch):
    # the first selection's tied choices go with its pairs: a retry that is not kept must not leave its own
    import tofmetry.reconstruct._posegraph as posegraph

    calls = []
    original = posegraph.PoseGraphBuilder.select_hypotheses

    def select(self, *a, **k):
        report = original(self, *a, **k)
        calls.append(1)
        self.tied = [["first"]] if len(calls) == 1 else [["retry"]]
        return report

    import tofmetry.reconstruct._select_stage as stage

    monkeypatch.setattr(posegraph.PoseGraphBuilder, "select_hypotheses", select)
    # the loops imply a hypothesis the selection then does not choose: the retry is not kept
    monkeypatch.setattr(stage, "loop_implied_hypotheses", lambda n, before, chosen, register, gain: (
        chosen, [{"edge": (0, 1), "fitness": 0.5, "kept_fitness": 0.69, "implied_by": (0, 8)}]))
    _, pg = _pipeline_selection(monkeypatch, 0.70)
    assert len(calls) == 2 and pg.tied == [["first"]] and "loop_implied" not in pg.selection
