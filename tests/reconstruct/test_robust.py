"""Robustness of the registration to symmetric objects and partial scans (issue #5).

Fast synthetic tests of the three mechanisms (multi-view hypothesis selection, loop gate over
every fundamental cycle, free-space test) and one small end-to-end case: the chamfered box
(nearly 180-degree symmetric) seen from 6 views, which the coarse step used to register turned
over while the gate passed it.
"""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct import PairResult, PoseGraphBuilder, RegView, consistency_gate
from tofmetry.reconstruct._loops import loop_closures
from tofmetry.reconstruct._verdict import assess
from tofmetry.reconstruct._regview import free_space_violation, visibility_violation
from tofmetry.sensor import KINECT_V2


def _rot_z(deg: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    a = np.radians(deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = t
    return T


def _circle_poses(n: int, arc_deg: float = 360.0) -> list[np.ndarray]:
    """Cameras on a circle of radius 1 m about the world z axis (the object's symmetry axis), step arc / n."""
    step = arc_deg / n
    return [_rot_z(step * k, (np.cos(np.radians(step * k)), np.sin(np.radians(step * k)), 0.0)) for k in range(n)]


def _edge(poses, i, j, fit=0.9, flip=False, alts=()):
    """Pair i -> j; ``flip``: the object matched turned by 180 deg about its axis (world z through the origin)."""
    T = np.linalg.inv(poses[j]) @ (_rot_z(180.0) if flip else np.eye(4)) @ poses[i]
    return PairResult(i, j, T, fit, 1.0, np.eye(6) * 1000, "test", True, list(alts))


def _flipped_alt(poses, i, j, fit):
    return _edge(poses, i, j, fit, flip=True)


def test_selection_takes_the_alternative_that_closes_the_circle():
    # 6 views; edge 2->3 registered turned over (fitness 0.9), its true hypothesis an alternative
    # (0.8); the circle closes only with the alternative: it must be chosen, the run reliable
    P = _circle_poses(6)
    pg = PoseGraphBuilder(6, [f"{k:02d}" for k in range(6)])
    for i in range(5):
        if i == 2:
            true = _edge(P, 2, 3, 0.8)
            pg.add(_edge(P, 2, 3, 0.9, flip=True, alts=[true]))
        else:
            pg.add(_edge(P, i, i + 1))
    pg.add(_edge(P, 0, 5))
    rep = pg.select_hypotheses(2.0, 10.0, 0.05)
    assert rep["changed"] == ["02->03"] and not rep["reasons"], rep
    res = pg.optimize(0.003)
    assert res.consistency["reliable"], res.consistency
    for k in range(6):  # exact edges: exact poses (relative to view 0)
        np.testing.assert_allclose(res.poses[k], np.linalg.inv(P[0]) @ P[k], atol=1e-6)


def _even_flips(n: int) -> PoseGraphBuilder:
    """Views 0-5 of ``n`` on a circle, a perfectly symmetric object: edges 1->2 and 3->4 both have a
    turned-over alternative of the same fitness; views 6.. are linked by no pair."""
    P = _circle_poses(n)
    pg = PoseGraphBuilder(n, [f"{k:02d}" for k in range(n)])
    for i in range(5):
        alts = [_flipped_alt(P, i, i + 1, 0.9)] if i in (1, 3) else []
        pg.add(_edge(P, i, i + 1, 0.9, alts=alts))
    pg.add(_edge(P, 0, 5))
    return pg


def test_selection_flags_an_even_number_of_indistinguishable_flips():
    # flipping both edges also closes the circle -> the geometry cannot decide
    pg = _even_flips(6)
    rep = pg.select_hypotheses(2.0, 10.0, 0.05)
    assert any("registration ambiguous" in r for r in rep["reasons"]), rep
    assert not pg.optimize(0.003).consistency["reliable"]


def _walk_frame(pg: PoseGraphBuilder, n: int) -> PoseGraphBuilder:
    """The object centre (world origin) and the vertical (world z) in each camera frame of
    :func:`_circle_poses`, as the pipeline gives them to the selection."""
    P = _circle_poses(n)
    pg.centres = np.array([np.linalg.inv(T)[:3, 3] for T in P])
    pg.ups = np.array([T[:3, :3].T @ [0.0, 0.0, 1.0] for T in P])
    return pg


def test_the_camera_path_decides_between_indistinguishable_flips():
    # edges 1->2 and 3->4 as in _even_flips: turning views 2-3 over puts their cameras on the far
    # side, so the path steps back by 120 deg into and out of them; the walk decides, the run is
    # not ambiguous -- also where the turned-over choice scores higher (0.1, within the margin)
    P = _circle_poses(6)
    for fit_right in (0.9, 0.85):
        pg = PoseGraphBuilder(6, [f"{k:02d}" for k in range(6)])
        for i in range(5):
            alts = [_flipped_alt(P, i, i + 1, 0.9)] if i in (1, 3) else []
            pg.add(_edge(P, i, i + 1, fit_right if i in (1, 3) else 0.9, alts=alts))
        pg.add(_edge(P, 0, 5))
        rep = _walk_frame(pg, 6).select_hypotheses(2.0, 10.0, 0.05, path_max_ratio=3.0, path_margin=0.3)
        assert not rep["reasons"] and not rep["changed"], rep
        if fit_right < 0.9:
            assert rep["decided_by_path"]["steps_before"] == ["01->02", "03->04"], rep
            res = pg.optimize(0.003)
            verdict = assess(pg.names, res.edges, res.consistency, {}, None, None)
            assert verdict["reliable"] and any("walks them around the object" in w for w in verdict["warnings"])


def test_a_path_no_closing_choice_walks_is_flagged():
    # both edges registered turned over and no alternative: the loop closes (two flips cancel) but
    # the cameras of views 2-3 step back: unreliable, and said why
    P = _circle_poses(6)
    pg = PoseGraphBuilder(6, [f"{k:02d}" for k in range(6)])
    for i in range(5):
        pg.add(_edge(P, i, i + 1, 0.9, flip=i in (1, 3)))
    pg.add(_edge(P, 0, 5))
    rep = _walk_frame(pg, 6).select_hypotheses(2.0, 10.0, 0.05, path_max_ratio=3.0)
    assert rep["path_steps"] == ["01->02", "03->04"], rep
    assert any("do not walk around the object" in r for r in rep["reasons"]), rep
    # without the walk the loop check alone passes it
    pg2 = PoseGraphBuilder(6, pg.names)
    for p in pg.pairs:
        pg2.add(p)
    assert not pg2.select_hypotheses(2.0, 10.0, 0.05)["reasons"]


def test_wrong_closing_edge_of_a_partial_scan_is_dropped_and_flagged():
    # half circle, 4 views: the direct 0 -> 3 match (views 180 deg apart) is a false, turned-over
    # match; the chain of successive views is kept, and with no loop left the run is unreliable
    P = _circle_poses(4, 180.0)
    pg = PoseGraphBuilder(4, [f"{k:02d}" for k in range(4)])
    for i in range(3):
        pg.add(_edge(P, i, i + 1, 0.5))
    pg.add(_edge(P, 0, 3, 0.97, flip=True))
    rep = pg.select_hypotheses(2.0, 10.0, 0.05)
    assert rep["dropped"] == ["00->03"], rep
    res = pg.optimize(0.003)
    np.testing.assert_allclose(res.poses[3], np.linalg.inv(P[0]) @ P[3], atol=1e-6)
    assert not res.consistency["reliable"] and "no closed loop" in " ".join(res.consistency["reasons"])


def test_a_dropped_edge_against_an_unchecked_chain_is_flagged():
    # 7 views round the object: the skip edges 0->2 and 1->3 are both turned over, so the loop
    # 0-1-3-2 closes (two flips cancel); the right closing edge 0->6 contradicts the chain
    # 0-2-3-4-5-6 and is dropped, leaving 3-4-5-6 on no loop: one chain against one edge, nothing
    # decides which is wrong (a family baluster 179 deg off, reported reliable before)
    P = _circle_poses(7)
    pg = PoseGraphBuilder(7, [f"{k:02d}" for k in range(7)])
    pg.add(_edge(P, 0, 1))
    pg.add(_edge(P, 0, 2, 0.6, flip=True))
    pg.add(_edge(P, 1, 3, 0.6, flip=True))
    for i in range(2, 6):
        pg.add(_edge(P, i, i + 1))
    pg.add(_edge(P, 0, 6, 0.6))
    rep = pg.select_hypotheses(2.0, 10.0, 0.05)
    assert rep["dropped"] == ["00->06"] and rep["undecided"] == ["00->06"], rep
    assert not pg.optimize(0.003).consistency["reliable"]


def test_a_dropped_edge_against_a_checked_chain_is_not_flagged():
    # the same scan with 2->4 and 4->6 registered too (right): the chain from 0 to 6 is checked by
    # loops all the way, so the turned-over closing edge 0->6 it contradicts is dropped, not doubted
    P = _circle_poses(7)
    pg = PoseGraphBuilder(7, [f"{k:02d}" for k in range(7)])
    for i in range(6):
        pg.add(_edge(P, i, i + 1))
    pg.add(_edge(P, 0, 2))
    pg.add(_edge(P, 2, 4))
    pg.add(_edge(P, 4, 6))
    pg.add(_edge(P, 0, 6, 0.6, flip=True))
    rep = pg.select_hypotheses(2.0, 10.0, 0.05)
    assert rep["dropped"] == ["00->06"] and not rep.get("undecided") and not rep["reasons"], rep
    assert pg.optimize(0.003).consistency["reliable"]


def test_a_view_left_out_does_not_void_the_selections_checks():
    # the indistinguishable flips of the test above, with one more view (06) that no pair links:
    # the choice is made on the views that are linked, and its ambiguity still flags the run
    rep = _even_flips(7).select_hypotheses(2.0, 10.0, 0.05)
    assert rep["resolved"] and any("registration ambiguous" in r for r in rep["reasons"]), rep


def _right_edges(n: int, edges) -> PoseGraphBuilder:
    """``n`` views on a circle with the right registrations ``edges`` [(i, j)] only."""
    P = _circle_poses(n)
    pg = PoseGraphBuilder(n, [f"{k:02d}" for k in range(n)])
    for i, j in edges:
        pg.add(_edge(P, i, j))
    return pg


def test_an_unchecked_skip_edge_is_flagged_when_view_0_is_left_out():
    # 8 views; 00 and 04 link to nothing: the chain 1-2-3-5-6-7 crosses the left-out 04 by the
    # skip edge 3->5, which no loop checks (a family baluster 90 deg off, reported reliable before:
    # with view 0 unreached every selection was skipped, and its checks with it)
    rep = _right_edges(8, ((1, 2), (2, 3), (3, 5), (5, 6), (6, 7))).select_hypotheses(2.0, 10.0, 0.05)
    assert rep["resolved"] and rep["unverified"] == ["03->05"], rep
    assert any("between non-successive views" in r for r in rep["reasons"]), rep


def test_a_skip_edge_in_a_group_left_out_is_not_judged():
    # views 0-4 linked in a closed circle; 5 and 7 linked only to each other by a skip edge: that
    # group is left out of the model (and said so), its unchecked skip edge is no reason
    rep = _right_edges(8, ((0, 1), (1, 2), (2, 3), (3, 4), (0, 4), (5, 7))).select_hypotheses(2.0, 10.0, 0.05)
    assert rep["resolved"] and not rep.get("unverified") and not rep["reasons"], rep


def test_loop_gate_sees_a_wrong_bridge_when_the_circle_is_broken():
    # successive edge 4->5 missing, bridged by 3->5 (right) and 4->6 (turned over): the successive
    # circle test does not apply; the fundamental cycles through the bridges must fail
    P = _circle_poses(8)
    pairs = [_edge(P, i, i + 1) for i in range(7) if i != 4] + [_edge(P, 3, 5), _edge(P, 4, 6, flip=True), _edge(P, 0, 7)]
    loops = loop_closures(8, pairs, [f"{k:02d}" for k in range(8)])
    assert len(loops) == 2  # 9 edges on 8 views: 2 independent cycles
    c = consistency_gate([], None, 2.0, 10.0, loops)
    assert not c["reliable"] and "loop closed by edge" in c["reasons"][0], c
    ok = loop_closures(8, [_edge(P, i, i + 1) for i in range(7)] + [_edge(P, 0, 7)])
    assert len(ok) == 1 and ok[0]["n_edges"] == 8 and ok[0]["closure_mm"] < 1e-6
    assert {frozenset(m) for m in ok[0]["members"]} == {frozenset((str(i), str(i + 1))) for i in range(7)} | {
        frozenset(("0", "7"))}   # the cycle's edges, the closing one first
    assert ok[0]["members"][0] == ["0", "7"]


def _wall_view(z_m: float) -> RegView:
    """Target camera (Kinect v2 depth intrinsics) seeing a fronto-parallel wall at ``z_m``."""
    intr = KINECT_V2.depth
    near = np.full(intr.shape, z_m, np.float32)
    pts = np.array([[0.0, 0.0, z_m], [0.05, -0.02, z_m]])
    n = np.tile([0.0, 0.0, -1.0], (len(pts), 1))
    return RegView("t", pts, n, pts, pts, n, plane=None, near_depth_m=near, intr=intr)


def _points_view(pts: np.ndarray) -> RegView:
    n = np.tile([0.0, 0.0, -1.0], (len(pts), 1))
    return RegView("s", pts, n, pts, pts, n)


def test_free_space_violation_counts_points_in_front_of_the_observed_surface():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.1, 0.1, (200, 2))
    tgt = _wall_view(1.0)
    tol = 0.015  # the default see-through tolerance [m]
    at = _points_view(np.c_[xy, np.full(200, 1.0)])  # on the wall: consistent
    front = _points_view(np.c_[xy, np.full(200, 0.9)])  # 100 mm in front: the camera saw through them
    behind = _points_view(np.c_[xy, np.full(200, 1.1)])  # hidden behind the wall: no evidence against
    assert free_space_violation(at, tgt, np.eye(4), tol) == 0.0
    assert free_space_violation(front, tgt, np.eye(4), tol) == pytest.approx(1.0)
    assert free_space_violation(behind, tgt, np.eye(4), tol) == 0.0
    # within the tolerance (10 mm in front < 15 mm) nothing counts; no depth image -> 0
    assert free_space_violation(_points_view(np.c_[xy, np.full(200, 0.99)]), tgt, np.eye(4), tol) == 0.0
    assert visibility_violation(front, _points_view(front.obj_points), np.eye(4), tol) == 0.0


def test_free_space_leaves_out_what_the_target_sees_at_its_limb():
    """Surface the target would see at grazing incidence (its silhouette band, where its pixels mix
    with the background) is no evidence; the same points facing the target are."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.1, 0.1, (200, 2))
    tgt = _wall_view(1.0)
    front = _points_view(np.c_[xy, np.full(200, 0.9)])
    grazing = RegView("s", front.icp_points, front.icp_normals, front.obj_points, front.obj_points,
                      front.icp_normals, obj_normals=np.tile([1.0, 0.0, -0.2], (200, 1)) / np.hypot(1.0, 0.2))
    assert free_space_violation(front, tgt, np.eye(4), 0.015) == pytest.approx(1.0)
    assert free_space_violation(grazing, tgt, np.eye(4), 0.015) == 0.0


@pytest.fixture(scope="module")
def box_scan(tmp_path_factory):
    """Chamfered box 30 x 20 x 15 cm (symmetric under a 180-degree turn), 6 views, 2 frames, all error terms."""
    from scipy.spatial import ConvexHull

    from tofmetry.simulate import ErrorModel, datasets

    pts = []
    for X in (-1, 1):
        for Y in (-1, 1):
            for Z in (-1, 1):
                corner = np.array([X * 0.15, Y * 0.10, Z * 0.075])
                for ax in range(3):
                    p = corner.copy()
                    p[ax] -= np.sign(p[ax]) * 0.015
                    pts.append(p)
    v = np.array(pts)
    f = ConvexHull(v).simplices.copy()
    for k, (a, b, c) in enumerate(f):  # outward winding
        if np.cross(v[b] - v[a], v[c] - v[a]) @ v[a] < 0:
            f[k] = [a, c, b]
    out = tmp_path_factory.mktemp("box") / "scan"
    datasets.scan(out, n_views=6, n_frames=2, mesh=(v, f), errors=ErrorModel(), seed=0)
    return out


def test_symmetric_box_is_registered_right_or_flagged(box_scan):
    """Raw depth (no calibration: the gain self-calibration absorbs part of the bias); the
    requirement is the issue's: never a wrong model flagged reliable. Measured with the fix:
    every edge right (the turned-over hypotheses are seen through by the other camera), all
    cameras within 0.3 deg / 7 mm on 4 frames with calibration."""
    from tofmetry.io import ScanDataset, read_json
    from tofmetry.reconstruct import ReconstructionPipeline, relative_pose_errors

    res = ReconstructionPipeline(ScanDataset(box_scan), None).run()
    Tt = [np.array(v["camera_to_world"]) for v in read_json(box_scan / "truth.json")["views"]]
    err = relative_pose_errors(res.poses, Tt)
    print("box, rotation [deg] / translation [mm] per view:", err.round(2).tolist(), res.diagnostics["consistency"]["reasons"])
    wrong = err[:, 0].max() > 2.0 or err[:, 1].max() > 20.0
    assert not (wrong and res.diagnostics["reliable"]), err
    # the see-through test removes the turned-over matches: no pair may be accepted that the other camera sees through
    assert all(e["see_through"] <= 0.2 for e in res.edges if e["accepted"])
    assert err[:, 0].max() < 2.0, err


def test_selection_search_is_bounded():
    # 8 edges with 2 alternatives each + a droppable closing edge: 3^8 * 4 = 26244 selections;
    # the search is capped (max_combos) by dropping the alternatives farthest below their primary
    P = _circle_poses(8)
    pg = PoseGraphBuilder(8, [f"{k:02d}" for k in range(8)])
    for i in range(7):
        pg.add(_edge(P, i, i + 1, 0.9, alts=[_flipped_alt(P, i, i + 1, 0.4 + 0.01 * i), _flipped_alt(P, i, i + 1, 0.3)]))
    pg.add(_edge(P, 0, 7, 0.9, alts=[_flipped_alt(P, 0, 7, 0.35)]))
    rep = pg.select_hypotheses(2.0, 10.0, 0.05, max_combos=256)
    assert 0 < rep["tested"] <= 256 and rep["resolved"] and not rep["changed"] and not rep["reasons"], rep


def test_shifted_yaw_seeds_keep_the_support_plane():
    # every shifted seed maps the source support plane onto the target one (a shift within the
    # plane and a yaw about its normal); 12 yaws x 8 shifts at the default 30 deg step
    from tofmetry.reconstruct._register import plane_consistent, shifted_yaw_candidates

    rng = np.random.default_rng(1)
    obj = np.c_[rng.uniform(-0.2, 0.2, 300), rng.uniform(-0.05, 0.05, 300), rng.uniform(0.9, 1.1, 300)]
    plane = np.array([0.0, -1.0, 0.0, 0.3])  # y = 0.3 m below the camera axis, normal up (toward -y)
    n3 = np.tile([0.0, -1.0, 0.0], (300, 1))
    v = RegView("v", obj, n3, obj, obj, n3, plane=plane)
    seeds = shifted_yaw_candidates(v, v, 30.0)
    assert len(seeds) == 96
    assert all(plane_consistent(v, v, T, 0.01, 0.01) for T in seeds)
    shifts = {round(float(np.linalg.norm(T[:3, 3] - seeds[0][:3, 3])), 6) for T in seeds[:8]}
    assert len(shifts) > 1  # the 8 seeds of one yaw differ by in-plane shifts


def test_the_ir_albedo_decides_between_flips_the_geometry_cannot_tell_apart():
    # as above (two indistinguishable flips), but the object is painted: the true hypotheses line
    # the albedo pattern up (correlation 0.8), the turned-over ones do not (0.1); the selection takes
    # the flips' alternatives only where the IR says so, and the run is no longer ambiguous
    from dataclasses import replace

    P = _circle_poses(6)
    for flipped_primary in (False, True):
        pg = PoseGraphBuilder(6, [f"{k:02d}" for k in range(6)])
        for i in range(5):
            if i in (1, 3):
                true, flip = replace(_edge(P, i, i + 1, 0.9), ir_corr=0.8), replace(_flipped_alt(P, i, i + 1, 0.9),
                                                                                      ir_corr=0.1)
                a, b = (flip, true) if flipped_primary else (true, flip)
                pg.add(replace(a, alternatives=[b]))
            else:
                pg.add(replace(_edge(P, i, i + 1), ir_corr=0.8))
        pg.add(replace(_edge(P, 0, 5), ir_corr=0.8))
        rep = pg.select_hypotheses(2.0, 10.0, 0.05)
        assert not rep["reasons"], rep
        # whichever the registration put first, the true one lines the pattern up and the flip does
        # not: the IR vetoes the flips at once (no tie left for it to decide)
        assert rep["ir_vetoed"] == ["01->02", "03->04"] and "decided_by_ir" not in rep, rep
        res = pg.optimize(0.003)
        for k in range(6):
            np.testing.assert_allclose(res.poses[k], np.linalg.inv(P[0]) @ P[k], atol=1e-6)


def test_a_flip_that_matches_more_points_is_refused_where_an_alternative_lines_the_pattern_up():
    # a painted dome (measured, session 21): two of its pairs were registered half a turn off, with
    # more points matched (0.99) than the true poses (0.90), far beyond the ambiguity margin, and the
    # flips close the loop as well (two flips). The flips line the pattern up at 0.45 (a band round
    # the dome correlates at any turn), the true poses at 0.95: the flips are refused, the true
    # poses chosen; without the albedo the geometry's choice (the flips) stands
    from dataclasses import replace

    P = _circle_poses(6)
    for painted in (True, False):
        pg = PoseGraphBuilder(6, [f"{k:02d}" for k in range(6)])
        for i in range(5):
            if i in (1, 3):
                flip = replace(_flipped_alt(P, i, i + 1, 0.99), ir_corr=0.45 if painted else None)
                true = replace(_edge(P, i, i + 1, 0.90), ir_corr=0.95 if painted else None)
                pg.add(replace(flip, alternatives=[true]))
            else:
                pg.add(replace(_edge(P, i, i + 1), ir_corr=0.95 if painted else None))
        pg.add(replace(_edge(P, 0, 5), ir_corr=0.95 if painted else None))
        rep = pg.select_hypotheses(2.0, 10.0, 0.05)
        res = pg.optimize(0.003)
        truth = all(np.allclose(res.poses[k], np.linalg.inv(P[0]) @ P[k], atol=1e-6) for k in range(6))
        if painted:
            assert rep["ir_vetoed"] == ["01->02", "03->04"] and rep["changed"] == ["01->02", "03->04"], rep
            assert truth
        else:
            assert not rep["ir_vetoed"] and not rep["changed"] and not truth, rep


def test_without_albedo_contrast_the_flips_stay_ambiguous():
    from dataclasses import replace

    P = _circle_poses(6)
    pg = PoseGraphBuilder(6, [f"{k:02d}" for k in range(6)])
    for i in range(5):
        alts = [replace(_flipped_alt(P, i, i + 1, 0.9), ir_corr=None)] if i in (1, 3) else []
        pg.add(_edge(P, i, i + 1, 0.9, alts=alts))
    pg.add(_edge(P, 0, 5))
    rep = pg.select_hypotheses(2.0, 10.0, 0.05)
    assert any("registration ambiguous" in r for r in rep["reasons"]) and "decided_by_ir" not in rep


def test_alternatives_the_pattern_contradicts_are_not_chosen_for_a_trivially_closing_loop():
    # a painted vase: every edge's pattern-decided yaw (correlation 0.9) carries a small error, so
    # their loop closes only to ~3 deg / 40 mm; the geometric alternatives put every camera at the
    # same place on the turned surface (no turn at all), a loop that closes exactly, at a slightly
    # higher fitness. The pattern contradicts them (correlation 0.0): the selection must keep the
    # pattern's choice and spread its closure, not turn the cameras into one.
    from dataclasses import replace

    P = _circle_poses(8)
    pg = PoseGraphBuilder(8, [f"{k:02d}" for k in range(8)])
    edges = [(i, i + 1) for i in range(7)] + [(0, 7)]
    for i, j in edges:
        e = _edge(P, i, i + 1 if j == i + 1 else j, 0.95)
        R = np.eye(4)
        a = np.radians(0.4)
        R[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        ir = replace(e, transform=R @ e.transform, ir_corr=0.9,
                     ir_yaw={"decided": True, "correlation": 0.9, "margin": 0.5})
        still = replace(e, transform=np.eye(4), fitness=0.99, ir_corr=0.0)
        pg.add(replace(ir, alternatives=[still]))
    rep = pg.select_hypotheses(2.0, 10.0, 0.05, spread_deg=6.0, spread_mm=40.0)
    chosen = [p for p in pg.pairs if p.accepted]
    assert len(chosen) == 8 and all(p.ir_corr == 0.9 for p in chosen), rep
    assert len(rep["ir_vetoed"]) == 8 and not rep["changed"], rep


def test_the_closing_pair_of_a_scan_that_goes_round_is_a_successive_pair():
    # 8 views, the successive pair 3->4 failed: the closing pair 7->0 (last view, first) is the only
    # link between 0-3 and 4-7. Matched right, the cameras walk once round and it is trusted as the
    # successive pair it is (family: three fandisks flagged for it alone, all within the gate)
    edges = [(i, i + 1) for i in range(7) if i != 3] + [(0, 7)]
    pg = _walk_frame(_right_edges(8, edges), 8)
    rep = pg.select_hypotheses(2.0, 10.0, 0.05, path_max_ratio=3.0)
    assert rep["resolved"] and not rep.get("unverified") and not rep["reasons"], rep
    assert rep["closing_pair_walks"] == "00->07"
    res = pg.optimize(0.003)
    verdict = assess(pg.names, res.edges, res.consistency, {}, None, None)
    assert verdict["reliable"] and any("taken as the successive pair it is" in w for w in verdict["warnings"]), verdict
    # without the walk (the check switched off) nothing shows that it is right: flagged as before
    rep = _walk_frame(_right_edges(8, edges), 8).select_hypotheses(2.0, 10.0, 0.05)
    assert rep["unverified"] == ["00->07"] and any("between non-successive views" in r for r in rep["reasons"]), rep
    # matched turned over, it places views 4-7 on the far side: the cameras do not walk round
    P = _circle_poses(8)
    pg = PoseGraphBuilder(8, [f"{k:02d}" for k in range(8)])
    for i, j in edges:
        pg.add(_edge(P, i, j, flip=(i, j) == (0, 7)))
    rep = _walk_frame(pg, 8).select_hypotheses(2.0, 10.0, 0.05, path_max_ratio=3.0)
    assert rep["unverified"] == ["00->07"] and "closing_pair_walks" not in rep, rep


def test_the_tied_choices_are_kept_for_the_joint_fit_to_decide():
    # the indistinguishable flips: the selection keeps the tied choice's pairs, and its pose graph
    # places views 2-3 on the far side (turned half a turn about the object's axis)
    pg = _even_flips(6)
    pg.select_hypotheses(2.0, 10.0, 0.05)
    assert len(pg.tied) == 1 and "_tied_pairs" not in pg.selection
    chosen = pg.optimize(0.003).poses
    (other,) = pg.tied_poses(0.003)
    turned = [rotation_angle_deg(np.linalg.inv(a) @ b) for a, b in zip(chosen, other)]
    assert np.allclose(np.array(turned)[[0, 1, 4, 5]], 0.0, atol=1e-4) and min(turned[2], turned[3]) > 170.0, turned
    assert pg.tied_poses(0.003, limit=0) == []  # more tied choices than can be checked: none
