"""Reliability verdicts (edges, views, run), the scale report and the support-plane world frame (issue 16)."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry._shared.geometry import transform_points
from tofmetry.reconstruct._calibration_support import (
    calibration_gain_sigma,
    extrapolated_points,
    extrapolation_error_mm,
    extrapolation_scale_sigma,
    extrapolation_warning,
    local_prediction,
)
from tofmetry.reconstruct._scale_report import curve_residual_mm, scale_report
from tofmetry.reconstruct._verdict import assess
from tofmetry.reconstruct._world import support_plane_frame, transform_plane


def _edge(a, b, kept=True, accepted=True, yaw=1.0, method="plane-yaw+icp"):
    return {"source": a, "target": b, "accepted": accepted, "kept": kept, "method": method,
            "conditioning": {"yaw_ratio": yaw}}


def _names(n):
    return [f"{k:02d}" for k in range(n)]


def test_loop_edges_verified_and_a_dangling_view_unverified():
    # circle 00-01-02-03-00 plus 04 hanging on 03 only
    e = [_edge("00", "01"), _edge("01", "02"), _edge("02", "03"), _edge("00", "03"), _edge("03", "04")]
    v = assess(_names(5), e, {"reasons": [], "loops": []}, calibration_prediction={})
    assert [x["verdict"] for x in e] == ["verified"] * 4 + ["unverified"]
    assert v["views"]["04"]["verdict"] == "unverified" and v["views"]["00"]["verdict"] == "verified"
    assert v["reliable"] and any("04" in w for w in v["warnings"])


def test_yaw_free_edge_makes_the_run_unreliable():
    e = [_edge("00", "01", yaw=0.03), _edge("01", "02"), _edge("00", "02")]
    v = assess(_names(3), e, {"reasons": [], "loops": []}, calibration_prediction={})
    assert not v["reliable"] and e[0]["verdict"] == "yaw free" and "rotation about the vertical" in v["reasons"][0]


def test_rejected_dropped_left_out_and_calibration_warnings():
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02"),
         _edge("02", "03", accepted=False, kept=False) | {"reason": "rejected: overlap 0.10 < 0.35"},
         _edge("00", "02", accepted=False, kept=False, method="fpfh+icp (dropped: contradicts the other views)")]
    pred = {"interpolation": {"central_abs_mm": {"predicted": 4.2}}, "warnings": ["stations too far apart"]}
    v = assess(_names(3), e, {"reasons": [], "loops": []}, left_out={"03": "no accepted registration"},
               calibration_prediction=pred)
    assert e[3]["verdict"] == "rejected" and "overlap" in e[3]["reason"] and e[4]["verdict"] == "dropped"
    assert v["views"]["03"]["verdict"] == "left out"
    # a calibration's predicted error is a warning: the views' own checks judge the poses
    assert v["reliable"] and not v["reasons"]
    assert any("4.2 mm" in w and "stations too far apart" in w for w in v["warnings"])


def test_spread_loops_beyond_the_pose_gate_are_flagged():
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]
    cons = {"reasons": [], "selection": {"spread": True},
            "loops": [{"closure_deg": 2.4, "closure_mm": 30.0, "closure_object_mm": 9.0}]}
    v = assess(_names(3), e, cons, calibration_prediction={})
    assert not v["reliable"] and v["loop_pose_bound"] == {"deg": 1.2, "mm": 4.5}


def test_scale_report_from_the_calibration_and_the_gain():
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.3}},
            "folds": [{"center_mm": 1000.0 + 250 * k} for k in range(5)]}
    r = scale_report({"depth_gain": 0.001, "gain_estimated": True, "gain_sigma_data": 0.0004}, pred, 1000.0)
    assert np.isclose(r["predicted_scale_sigma_pct"], 100 * np.hypot(0.3 / 1000, 0.0002))
    r = scale_report({"gain_estimated": False}, pred, 1000.0)
    assert np.isclose(r["gain_sigma"], 0.3 / 125) and r["station_spacing_mm"] == 250
    assert scale_report(None, None, 1000.0)["predicted_scale_sigma_pct"] is None


def test_a_range_curve_larger_than_predicted_widens_the_scale_uncertainty():
    """The joint fit's range curve is the views' own measure of the range error left over the
    object's depths: above the calibration's predicted error, the gain it can leave follows it; a
    curve within the prediction, one not estimated, or a self-calibrated gain change nothing."""
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.3}},
            "folds": [{"center_mm": 1000.0 + 250 * k} for k in range(5)]}
    dz = [-2.4, -0.6, 0.0, 0.6, 1.8]  # [mm]: RMS 1.36 mm
    curve = {"range_curve": {"estimated": True, "dz_mm": dz}}
    assert curve_residual_mm(curve) == pytest.approx(np.sqrt(np.mean(np.square(dz))))
    assert curve_residual_mm({"range_curve": {"estimated": False, "dz_mm": dz}}) is None
    assert curve_residual_mm(None) is None
    e_c = curve_residual_mm(curve)
    r = scale_report({"gain_estimated": False} | curve, pred, 1000.0)
    assert r["gain_sigma"] == pytest.approx(e_c / 125) and r["curve_residual_mm"] == pytest.approx(e_c)
    assert r["predicted_offset_sigma_mm"] == 0.3 and "range curve" in r["source"]
    assert r["predicted_scale_sigma_pct"] == pytest.approx(100 * np.hypot(0.3 / 1000, e_c / 250))
    small = {"range_curve": {"estimated": True, "dz_mm": [-0.2, 0.0, 0.0, 0.1, 0.2]}}
    assert scale_report({"gain_estimated": False} | small, pred, 1000.0)["gain_sigma"] == pytest.approx(0.3 / 125)
    est = {"depth_gain": 0.001, "gain_estimated": True, "gain_sigma_data": 0.0004} | curve
    assert scale_report(est, pred, 1000.0)["gain_sigma"] == pytest.approx(0.0004)


def test_the_chains_own_scale_error_is_added_in_quadrature():
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.3}},
            "folds": [{"center_mm": 1000.0 + 250 * k} for k in range(5)]}
    adj = {"depth_gain": 0.001, "gain_estimated": True, "gain_sigma_data": 0.0004}
    r = scale_report(adj, pred, 1000.0, floor_pct=0.05)
    rule = 100 * np.hypot(0.3 / 1000, 0.0002)
    assert np.isclose(r["predicted_scale_sigma_pct"], np.hypot(rule, 0.05)) and np.isclose(r["rule_scale_sigma_pct"], rule)
    assert r["chain_floor_pct"] == 0.05 and "chain" in r["source"]
    assert scale_report(None, None, 1000.0, floor_pct=0.05)["predicted_scale_sigma_pct"] is None


def test_unrefined_placements_add_their_own_scale_in_quadrature():
    """Where the dot mat's placements stand as the poses, their scale 1-sigma joins the chain's
    prediction (after the larger of rule and budget) and is reported; none given, nothing changes."""
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.3}},
            "folds": [{"center_mm": 1000.0 + 250 * k} for k in range(5)]}
    adj = {"depth_gain": 0.001, "gain_estimated": True, "gain_sigma_data": 0.0004}
    base = scale_report(adj, pred, 1000.0, floor_pct=0.05)
    r = scale_report(adj, pred, 1000.0, floor_pct=0.05, placements_sigma_pct=0.12)
    assert np.isclose(r["predicted_scale_sigma_pct"], np.hypot(base["predicted_scale_sigma_pct"], 0.12))
    assert r["placements_scale_sigma_pct"] == 0.12 and "placements" in r["source"]
    for none in (None, float("nan"), 0.0):
        r = scale_report(adj, pred, 1000.0, floor_pct=0.05, placements_sigma_pct=none)
        assert r["predicted_scale_sigma_pct"] == base["predicted_scale_sigma_pct"]
        assert "placements_scale_sigma_pct" not in r


def test_scale_report_takes_the_larger_of_the_rule_and_the_budget():
    """The budget is handed the calibration's offset [m] and the gain's sigma; the prediction is
    the larger of the two propagations, and the report keeps both."""
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.3}},
            "folds": [{"center_mm": 1000.0 + 250 * k} for k in range(5)]}
    adj = {"depth_gain": 0.001, "gain_estimated": True, "gain_sigma_data": 0.0004}
    rule = 100 * np.hypot(0.3 / 1000, 0.0002)
    seen = []

    def budget(sigma):
        def f(offset_sigma_m, gain_sigma):
            seen.append((offset_sigma_m, gain_sigma))
            return {"sigma": sigma}
        return f
    r = scale_report(adj, pred, 1000.0, budget(0.01))
    assert seen[-1] == (0.3e-3, 0.0004)
    assert np.isclose(r["predicted_scale_sigma_pct"], 1.0) and np.isclose(r["rule_scale_sigma_pct"], rule)
    assert "geometry" in r["source"]
    r = scale_report(adj, pred, 1000.0, budget(1e-6))
    assert np.isclose(r["predicted_scale_sigma_pct"], rule) and np.isclose(r["budget_scale_sigma_pct"], 1e-4)
    r = scale_report(adj, pred, 1000.0, budget(float("nan")))  # scale and offset not separable on the shape
    assert np.isclose(r["predicted_scale_sigma_pct"], rule) and r["budget_scale_sigma_pct"] is None


def test_the_gain_inherits_the_amplitude_coefficients_uncertainty():
    """A gain that moves by 1e-4 per mm per ln unit of error in k, with k known to +-3: +-3e-4 more."""
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.3}},
            "folds": [{"center_mm": 1000.0 + 250 * k} for k in range(5)]}
    adj = {"depth_gain": 0.001, "gain_estimated": True, "gain_sigma_data": 0.0004,
           "amplitude_bias": {"gain_per_mm_per_ln": -1e-4}}
    r = scale_report(adj, pred, 1000.0, k_sigma_mm=3.0)
    assert np.isclose(r["gain_sigma_from_k"], 3e-4) and np.isclose(r["gain_sigma"], 5e-4)
    assert np.isclose(r["predicted_scale_sigma_pct"], 100 * np.hypot(0.3 / 1000, 2.5e-4))
    assert "k known to" in r["source"]
    assert np.isclose(scale_report(adj, pred, 1000.0)["gain_sigma"], 4e-4)  # no amplitude reference: not counted
    adj["gain_estimated"] = False  # the gain left at 0 does not trade with k
    assert "gain_sigma_from_k" not in scale_report(adj, pred, 1000.0, k_sigma_mm=3.0)


def test_support_plane_frame():
    rng = np.random.default_rng(0)
    n = np.array([0.1, -0.9, -0.3])
    n /= np.linalg.norm(n)
    plane = np.r_[n, 0.8]  # camera at the origin above it: height(origin) = 0.8 m
    ground = rng.normal(size=(200, 3))
    ground -= np.outer(ground @ n + 0.8, n)
    obj = ground[:50] + 0.1 * n
    cam0 = np.eye(4)
    W = support_plane_frame(plane, obj, cam0)
    g = transform_points(ground, W)
    assert np.abs(g[:, 2]).max() < 1e-12
    o = transform_points(obj, W)
    np.testing.assert_allclose(o[:, 2], 0.1, atol=1e-12)
    np.testing.assert_allclose(o[:, :2].mean(0), 0.0, atol=1e-12)  # origin under the object
    np.testing.assert_allclose(transform_plane(plane, W), [0, 0, 1, 0], atol=1e-12)
    c = W @ cam0
    assert c[2, 3] > 0 and c[:3, 2] @ [1, 0, 0] > 0  # camera above the plane, looking along +x
    np.testing.assert_allclose(W[:3, :3] @ W[:3, :3].T, np.eye(3), atol=1e-12)


def test_implausible_gain_makes_the_run_unreliable():
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]
    adj = {"gain_note": "implausible: the views ask for -5.12 % (+-0.04 %), beyond the +-1.06 % the depth calibration "
                        "can leave; kept at 0"}
    v = assess(_names(3), e, {"reasons": [], "loops": []}, adjustment=adj, calibration_prediction={})
    assert not v["reliable"] and "-5.12 %" in v["reasons"][0]
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.5}},
            "folds": [{"center_mm": 1000.0 + 250 * k} for k in range(5)]}
    assert np.isclose(calibration_gain_sigma(pred), 0.5 / 125)
    assert calibration_gain_sigma(None) is None and calibration_gain_sigma({"folds": []}) is None


def test_a_calibration_warning_within_the_error_limit_is_named_as_a_warning():
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.5}}, "warnings": ["242 mm of the range unseen"]}
    v = assess(_names(3), e, {"reasons": [], "loops": []}, calibration_prediction=pred)
    assert v["reliable"] and any("warns" in w and "242 mm" in w for w in v["warnings"])


def test_most_views_left_out_make_the_run_unreliable():
    e = [_edge("00", "01"), _edge("01", "02")]  # a chain: nothing closes, a warning
    v = assess(_names(3), e, {"reasons": [], "loops": []}, calibration_prediction={})
    assert v["reliable"] and any("no closed loop" in w for w in v["warnings"])
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]
    lo = {f"{k:02d}": "no accepted registration" for k in range(3, 5)}
    v = assess(_names(3), e, {"reasons": [], "loops": []}, left_out=lo, calibration_prediction={})
    assert not v["reliable"] and "2 of 5 views left out" in v["reasons"][0]
    v = assess(_names(3), e, {"reasons": [], "loops": []}, left_out={"03": "x"}, calibration_prediction={})
    assert v["reliable"] and any("left out" in w for w in v["warnings"])


def test_a_refused_gain_within_one_and_a_half_times_its_bound_is_a_warning():
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]
    note = "implausible: the views ask for -1.16 % (+-0.15 %), beyond the +-0.85 % the depth calibration can leave"
    v = assess(_names(3), e, {"reasons": [], "loops": []}, calibration_prediction={},
               adjustment={"gain_note": note, "gain_refused": -0.0116, "gain_max_abs": 0.0085})
    assert v["reliable"] and any("-1.16 %" in w for w in v["warnings"])
    v = assess(_names(3), e, {"reasons": [], "loops": []}, calibration_prediction={},
               adjustment={"gain_note": note, "gain_refused": -0.0512, "gain_max_abs": 0.0085})
    assert not v["reliable"]
    v = assess(_names(3), e, {"reasons": [], "loops": []}, calibration_prediction={},  # a family miss at 2 times
               adjustment={"gain_note": note, "gain_refused": -0.0069, "gain_max_abs": 0.0043})
    assert not v["reliable"]


def test_extrapolation_error_and_warning():
    """The error where the calibration extrapolates: the worst |central| + p95 of its extrapolation
    folds under the fallback it chose; a run whose object lies mostly there is warned."""
    pred = {"fallback_chosen": "hold", "extrapolation": [
        {"fallback": "hold", "central_mm": -3.5, "p95_mm": 3.1}, {"fallback": "trend", "central_mm": -4.4, "p95_mm": 4.0},
        {"fallback": "hold", "central_mm": 0.5, "p95_mm": 6.5}]}
    assert np.isclose(extrapolation_error_mm(pred), 7.0)
    assert extrapolation_error_mm({}) == 0.0
    stats = {"00": {"object_points": 1000, "object_points_extrapolated": 300}, "01": {"object_points": 1000}}
    w = extrapolation_warning(stats, pred, (767.0, 4491.0))
    assert w.startswith("15 %") and "(767-4491 mm)" in w and "7.0 mm" in w
    # the scale's 1-sigma it adds: 15 % of the points, where the correction drifts by 7 mm over one 250 mm spacing
    xs = extrapolation_scale_sigma(stats, pred)
    assert xs["share"] == 0.15 and xs["spacing_mm"] == 250.0 and np.isclose(xs["sigma_pct"], 100 * 0.15 * 7.0 / 250.0)
    assert "+-0.42 % (1 sigma)" in w
    assert extrapolation_scale_sigma({"00": {"object_points": 1000, "object_points_extrapolated": 0}}, pred) is None
    base = scale_report({"gain_estimated": False}, {"interpolation": {"central_abs_mm": {"predicted": 0.5}}}, 1000.0)
    more = scale_report({"gain_estimated": False}, {"interpolation": {"central_abs_mm": {"predicted": 0.5}}}, 1000.0,
                        extrapolation=xs)
    assert np.isclose(more["predicted_scale_sigma_pct"], np.hypot(base["predicted_scale_sigma_pct"], xs["sigma_pct"]))
    assert "beyond the calibration's stations" in more["source"]
    assert extrapolation_warning({"00": {"object_points": 1000, "object_points_extrapolated": 50}}, pred, (767, 4491)) is None


def test_extrapolated_points_get_the_extrapolation_error_as_tolerance():
    """Points nearer or farther than the stations' span get ``extrapolation_error_mm``; no
    calibration (or one without a support map) gives none."""
    from types import SimpleNamespace

    pred = {"fallback_chosen": "hold", "extrapolation": [{"fallback": "hold", "central_mm": -3.5, "p95_mm": 3.1}]}
    cal = SimpleNamespace(support=SimpleNamespace(range_mm=(767.0, 4491.0)), prediction=pred)
    pts = np.array([[0.0, 0.0, 0.5], [0.1, 0.0, 1.0], [0.0, 0.2, 4.6]])
    outside, tol = extrapolated_points(pts, cal)
    assert outside.tolist() == [True, False, True]
    assert np.allclose(tol, [6.6e-3, 0.0, 6.6e-3])
    assert extrapolated_points(pts, None) == (None, None)
    assert extrapolated_points(pts, SimpleNamespace(support=None, prediction=pred)) == (None, None)


def test_the_calibrations_error_is_taken_where_the_object_lies():
    # a range error that wiggles faster than the stations beyond 1 m: its folds there miss by ~3 mm,
    # its near folds by < 0.4 mm; the global prediction (median) says ~3 mm for every scan
    folds = [{"center_mm": c, "central_mm": e} for c, e in
             ((600, 0.01), (700, 0.05), (800, 0.36), (1000, -2.9), (1250, 1.0), (1500, 2.1), (2000, 4.2))]
    pred = {"interpolation": {"central_abs_mm": {"predicted": 2.9}}, "folds": folds, "warnings": []}
    near = local_prediction(pred, (610.0, 790.0))   # only 700 inside: its two neighbours join it
    assert near["local"]["stations_mm"] == [600.0, 700.0, 800.0]
    assert near["interpolation"]["central_abs_mm"]["predicted"] == pytest.approx(0.36)
    assert local_prediction(pred, (590.0, 810.0))["local"]["stations_mm"] == [600.0, 700.0, 800.0]
    assert near["interpolation"]["central_abs_mm"]["global_predicted"] == 2.9
    assert pred["interpolation"]["central_abs_mm"]["predicted"] == 2.9                  # input untouched
    assert assess(_names(2), [_edge("00", "01")], {"reasons": [], "loops": []},
                  calibration_prediction=near)["reliable"]
    # a narrow object between two stations gets the two bracketing them; beyond the folds, the nearest two
    mid = local_prediction(pred, (1050.0, 1200.0))
    assert mid["local"]["stations_mm"] == [1000.0, 1250.0]
    assert mid["interpolation"]["central_abs_mm"]["predicted"] == pytest.approx(2.9)
    v = assess(_names(2), [_edge("00", "01")], {"reasons": [], "loops": []}, calibration_prediction=mid)
    assert v["reliable"] and any("1050-1200 mm" in w and "2.9 mm" in w for w in v["warnings"])
    assert local_prediction(pred, (2500.0, 2700.0))["local"]["stations_mm"] == [1500.0, 2000.0]
    assert near["local"]["spacing_mm"] == 100.0 and mid["local"]["spacing_mm"] == 250.0
    assert local_prediction(None, (0, 1)) is None and local_prediction({"folds": []}, (0, 1)) == {"folds": []}


def test_a_joint_fit_far_from_the_pairwise_poses_makes_the_run_unreliable():
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]
    adj = {"moved_deg": {"00": 0.0, "01": 0.3, "02": 0.71}, "gain_note": "estimated"}
    v = assess(_names(3), e, {"reasons": [], "loops": []}, adjustment=adj, calibration_prediction={})
    assert not v["reliable"] and "moved view 02 by 0.71 deg" in v["reasons"][0]
    adj["moved_deg"]["02"] = 0.45
    assert assess(_names(3), e, {"reasons": [], "loops": []}, adjustment=adj, calibration_prediction={})["reliable"]


def test_a_move_the_support_planes_asked_for_is_judged_about_the_vertical_only():
    """A move of 0.8 deg, 0.2 of it about the vertical, that put the views' support planes within
    0.05 deg of one plane: the tilt part is the planes' measurement, the rest within the gate (a
    warning says so). Planes that end apart, or a view off the plane, leave the whole move judged."""
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]
    planes = {"used": True, "sigma_deg": 0.1, "end": {"n_views": 3, "spread_deg": 0.05, "off_plane": []}}
    adj = {"moved_deg": {"00": 0.0, "01": 0.3, "02": 0.8}, "moved_turn_deg": {"00": 0.0, "01": 0.1, "02": 0.2},
           "support_plane": planes, "gain_note": "not asked for"}
    v = assess(_names(3), e, {"reasons": [], "loops": []}, adjustment=adj, calibration_prediction={})
    assert v["reliable"] and any("tilted the views onto one support plane" in w for w in v["warnings"]), v
    adj["moved_turn_deg"]["02"] = 0.6
    v = assess(_names(3), e, {"reasons": [], "loops": []}, adjustment=adj, calibration_prediction={})
    assert not v["reliable"] and "0.60 deg of it about the vertical" in v["reasons"][0]
    adj["moved_turn_deg"]["02"] = 0.2
    for end in ({"n_views": 3, "spread_deg": 0.25, "off_plane": []}, {"n_views": 2, "spread_deg": 0.05, "off_plane": [2]}):
        adj["support_plane"] = dict(planes, end=end)
        v = assess(_names(3), e, {"reasons": [], "loops": []}, adjustment=adj, calibration_prediction={})
        assert not v["reliable"] and "moved view 02 by 0.80 deg from" in v["reasons"][0]


def test_a_loop_with_one_free_yaw_pins_it():
    # a box seen from 8 views: one pair overlaps on the flat top only (yaw free); the other 7 edges
    # fix their yaw, so a wrong yaw on the free one would show in the loop's closure
    names = _names(8)
    e = [_edge(names[i], names[i + 1], yaw=0.05 if i == 4 else 1.0) for i in range(7)] + [_edge("00", "07")]
    members = [["00", "07"]] + [[names[i + 1], names[i]] for i in range(7)]
    loop = {"edge": ["00", "07"], "n_edges": 8, "closure_deg": 0.1, "closure_mm": 5.0, "closure_object_mm": 3.1,
            "members": members}
    v = assess(names, e, {"reasons": [], "loops": [loop]}, calibration_prediction={})
    assert v["reliable"] and e[4]["verdict"] == "verified by its loop" and "04->05" not in " ".join(v["reasons"])
    # closing to more than twice the gate at the object: the loop cannot vouch for it
    bad = dict(loop, closure_object_mm=6.2)
    e = [_edge(names[i], names[i + 1], yaw=0.05 if i == 4 else 1.0) for i in range(7)] + [_edge("00", "07")]
    assert not assess(names, e, {"reasons": [], "loops": [bad]}, calibration_prediction={})["reliable"]
    # two free yaws on one loop: their errors can cancel in the closure (a vase): still yaw free
    e = [_edge(names[i], names[i + 1], yaw=0.05 if i in (2, 4) else 1.0) for i in range(7)] + [_edge("00", "07")]
    v = assess(names, e, {"reasons": [], "loops": [loop]}, calibration_prediction={})
    assert not v["reliable"] and e[2]["verdict"] == e[4]["verdict"] == "yaw free"


def test_a_declared_turntable_places_the_views_within_its_accuracy():
    # the pairwise graph's yaw-free edge and its consistency reason no longer bear on poses the
    # turntable places (accuracy within the pose gate): warnings; an edge given by the step alone
    # is a warning there and a reason for a manual table (1 deg)
    def edges():
        return [_edge("00", "01", yaw=0.03), _edge("01", "02", method="turntable-step"), _edge("00", "02")]

    cons = {"reasons": ["registration ambiguous: ..."], "loops": []}
    e = edges()
    v = assess(_names(3), e, cons, calibration_prediction={}, turntable_accuracy_deg=0.1, turntable_placed=True)
    assert v["reliable"], v["reasons"]
    assert e[1]["verdict"] == "turntable step" and "0.1 deg" in e[1]["reason"]
    assert sum("declared turntable places the views" in w for w in v["warnings"]) == 2, v["warnings"]
    v = assess(_names(3), edges(), cons, calibration_prediction={}, turntable_accuracy_deg=1.0, turntable_placed=True)
    assert not v["reliable"] and any("turntable step" in r and "beyond the pose gate" in r for r in v["reasons"])
    assert any(r.startswith("registration ambiguous") for r in v["reasons"])
    # the joint fit may move the views by up to twice the turntable's accuracy from its poses
    adj = {"moved_deg": {"00": 0.0, "01": 0.8, "02": 0.3}, "restart": {"view": 1, "start_deg": 0.8, "deg": 0.05,
                                                                       "mm": 0.3}}
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]
    v = assess(_names(3), e, {"reasons": [], "loops": []}, adjustment=adj, calibration_prediction={},
               turntable_accuracy_deg=0.5, turntable_placed=True)
    assert v["reliable"], v["reasons"]
    v = assess(_names(3), e, {"reasons": [], "loops": []}, adjustment=adj, calibration_prediction={})
    assert not v["reliable"] and "from where the pairwise registrations put it" in v["reasons"][0]


def test_a_determined_joint_fit_within_the_gate_settles_loops_that_fail_at_the_cameras_only():
    """A ring of 13 views whose pairwise loop closes to 3.3 deg / 47 mm at the cameras (0.9 deg / 13 mm
    per edge: the rotation within the 2 deg per edge, the cameras' displacement beyond 10 mm), as a
    dome of the family did while its poses ended 0.2 deg from the truth: the joint fit, which moved
    no view beyond the pose gate and whose restart came back, places the views. Without a restart,
    with a restart that did not come back, with a move beyond the gate or with a loop whose rotation
    fails too, the loops stay reasons."""
    from tofmetry.reconstruct import consistency_gate

    names = _names(13)
    e = [_edge(names[k], names[k + 1]) for k in range(12)] + [_edge("00", "12")]
    loop = {"edge": ["00", "12"], "n_edges": 13, "closure_deg": 3.29, "closure_mm": 47.0, "closure_object_mm": 2.8,
            "per_edge_deg": 3.29 / 13 ** 0.5, "per_edge_mm": 47.0 / 13 ** 0.5}

    def run(restart, move=0.4, loop=loop):
        cons = consistency_gate([], (loop["closure_deg"], loop["closure_mm"], 13), 2.0, 10.0, [loop],
                                {"spread": True, "reasons": []})
        adj = {"moved_deg": {n: (move if n == "06" else 0.1) for n in names}, "restart": restart,
               "gain_note": "not asked for"}
        return cons, assess(names, [dict(x) for x in e], cons, adjustment=adj, calibration_prediction={})

    back = {"view": 6, "start_deg": 0.5, "deg": 0.02, "mm": 0.1, "per_view_deg": [0.0] * 13}
    cons, v = run(back)
    assert len(cons["loop_reasons"]) == 2 and not cons["reliable"]
    assert v["reliable"], v["reasons"]
    assert sum("not the pairwise loops, which say" in w for w in v["warnings"]) == 3  # two loop tests + the spread
    for restart, move in ((None, 0.4), (dict(back, deg=0.7, mm=3.5), 0.4), (back, 0.7)):
        assert not run(restart, move)[1]["reliable"]
    wide = dict(loop, closure_deg=9.0, per_edge_deg=9.0 / 13 ** 0.5)
    v = run(back, loop=wide)[1]
    assert not v["reliable"] and any("does not close" in r for r in v["reasons"])


def test_an_ambiguity_the_joint_fit_decides_is_a_warning():
    """Choices of pairwise hypotheses tied with the chosen one: where the joint fit from each ends
    within half the pose gate of its solution, the points decide and the run is not flagged for it;
    one that ends farther, or a tied choice not fitted, keeps the reason."""
    names = _names(3)
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]
    amb = "registration ambiguous: 1 other choice(s) ..."

    def run(tied, n_tied=1):
        sel = {"ambiguous_reason": amb, "ambiguous_with": [{"edges": ["01->02"]}] * n_tied, "reasons": [amb]}
        adj = {"moved_deg": {"00": 0.0, "01": 0.1, "02": 0.1}, "gain_note": "not asked for", "tied": tied}
        return assess(names, [dict(x) for x in e], {"reasons": [amb], "loops": [], "selection": sel}, adjustment=adj,
                      calibration_prediction={})

    near = {"deg": 0.08, "mm": 0.6, "view": 2, "per_view_deg": [0.0, 0.02, 0.08]}
    v = run([near])
    assert v["reliable"] and any(w.startswith(amb) and "the points of all views decide" in w for w in v["warnings"])
    assert not run([dict(near, deg=0.3)])["reliable"]  # beyond half the gate (0.25 deg)
    assert not run([dict(near, mm=1.6)])["reliable"]
    assert not run([near], n_tied=2)["reliable"]  # a tied choice not fitted
    assert not run(None)["reliable"] and not run([{"failed": "too few correspondences"}])["reliable"]


def test_unchecked_views_with_a_loose_restart_make_the_run_unreliable():
    """Views on no closed loop are trusted to their chain of pairs (a warning) while the joint fit's
    restart comes back within half the pose gate; beyond half of it (within the gate), nothing holds
    them within the gate: a reason, as on a held-out bar whose 10 of 13 views hung on the closing
    pair (restart 0.16 deg / 1.7 mm, the views 0.40 deg / 4.1 mm off). Views all on a loop are judged
    by it, whatever the restart."""
    names = _names(5)
    chain = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02"), _edge("02", "03"), _edge("03", "04")]
    ring = chain[:3] + [_edge("02", "03"), _edge("03", "04"), _edge("02", "04")]

    def run(edges, deg, mm):
        restart = {"view": 4, "start_deg": 0.5, "deg": deg, "mm": mm, "per_view_deg": [0.0] * 5}
        adj = {"moved_deg": {n: 0.1 for n in names}, "restart": restart, "gain_note": "not asked for"}
        return assess(names, [dict(x) for x in edges], {"reasons": [], "loops": []}, adjustment=adj,
                      calibration_prediction={})

    v = run(chain, 0.05, 0.4)  # came back within half the gate (0.25 deg / 1.5 mm)
    assert v["reliable"], v["reasons"]
    assert any("03, 04 are on no closed loop" in w for w in v["warnings"])
    for deg, mm in ((0.16, 1.7), (0.3, 0.4)):  # beyond half the gate in displacement, in rotation
        v = run(chain, deg, mm)
        assert not v["reliable"] and any("neither a loop nor the points of all views" in r for r in v["reasons"])
    assert run(ring, 0.16, 1.7)["reliable"]


def test_a_predicted_pose_error_beyond_the_gate_is_a_warning():
    """The joint fit's own predicted pose error (calibration residual and noise) at p90 beyond the pose
    gate is a warning, not a reason (it is pessimistic where the calibration's stations are sparse);
    within the gate, or without a prediction, nothing is said."""
    e = [_edge("00", "01"), _edge("01", "02"), _edge("00", "02")]

    def run(p90, with_noise=True):
        rot = {"rot_deg": {"p50": p90 / 2, "p90": p90}, "object_mm": {"p50": 0.5, "p90": 1.0}}
        cp = dict(rot, with_noise=rot) if with_noise else rot
        adj = {"moved_deg": {"00": 0.0, "01": 0.1, "02": 0.1}, "gain_note": "not asked for", "calibration_pose": cp}
        return assess(_names(3), [dict(x) for x in e], {"reasons": [], "loops": []}, adjustment=adj,
                      calibration_prediction={})

    def said(v):
        return [w for w in v["warnings"] if "own predicted pose error" in w]

    assert run(0.45)["reliable"] and not said(run(0.45))
    v = run(0.61)
    assert v["reliable"] and len(said(v)) == 1 and "0.30 / 0.61 deg" in said(v)[0] and "views' noise" in said(v)[0]
    v = run(0.61, with_noise=False)
    assert v["reliable"] and "views' noise" not in said(v)[0]
    v = assess(_names(3), [dict(x) for x in e], {"reasons": [], "loops": []},
               adjustment={"moved_deg": {"00": 0.0}, "gain_note": "not asked for"}, calibration_prediction={})
    assert v["reliable"] and not said(v)


def test_the_gain_a_calibration_can_leave_is_read_fold_by_fold():
    """Evenly spaced folds: each fold's |central| over half the spacing, in quadratic mean, is the
    predicted central error (their quadratic mean) over half the spacing. Stations every 50 mm at
    0.6-1.2 m (|central| 0.1 mm) and every 250 mm at 1.5-3.5 m (3 mm): the predicted central error
    (1.9 mm, set by the far folds) over half the median spacing (50 mm) would read 7.7 %; fold by fold
    the near folds show 0.4 % and the far ones 2.4 % (1.5 % in quadratic mean)."""
    even = [{"center_mm": 1000.0 + 250 * k, "central_mm": c} for k, c in enumerate([0.2, -0.4, 0.1, 0.3, -0.2])]
    e = float(np.sqrt(np.mean(np.square([f["central_mm"] for f in even]))))
    pred = {"interpolation": {"central_abs_mm": {"predicted": e}}, "folds": even}
    assert np.isclose(calibration_gain_sigma(pred), e / 125)
    near = [{"center_mm": 600.0 + 50 * k, "central_mm": 0.1} for k in range(13)]
    far = [{"center_mm": 1500.0 + 250 * k, "central_mm": 3.0} for k in range(9)]
    folds = near + far
    e = float(np.sqrt(np.mean(np.square([f["central_mm"] for f in folds]))))
    pred = {"interpolation": {"central_abs_mm": {"predicted": e}}, "folds": folds}
    c = np.array([f["center_mm"] for f in folds])
    g = np.array([abs(f["central_mm"]) for f in folds]) / (np.gradient(c) / 2)
    assert np.isclose(calibration_gain_sigma(pred), np.sqrt(np.mean(g ** 2)))
    assert calibration_gain_sigma(pred) < 0.25 * e / 25
    r = scale_report({"gain_estimated": False}, pred, 900.0)
    assert np.isclose(r["gain_sigma"], calibration_gain_sigma(pred))
    two_at_one = [{"center_mm": 1000.0, "central_mm": 0.2}, {"center_mm": 1000.0, "central_mm": 0.3}]
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.25}}, "folds": two_at_one}
    assert np.isfinite(calibration_gain_sigma(pred))  # no spacing to read: the median spacing's fallback


def test_with_the_support_curve_removed_the_gain_left_is_its_own_and_the_unseen_linear_part():
    """Folds every 250 mm with a 2 mm central error leave 1.6 % between stations; once the support's curve
    is removed what stays is the curve's own uncertainty over the object (0.02 %) and the part a plane cannot
    show: sqrt(2) e over the support's 1500 mm span (0.19 %)."""
    folds = [{"center_mm": 750.0 + 250 * k, "central_mm": 2.0} for k in range(6)]
    pred = {"interpolation": {"central_abs_mm": {"predicted": 2.0}}, "folds": folds}
    before = scale_report({"gain_estimated": False}, pred, 900.0)
    assert np.isclose(before["gain_sigma"], 2.0 / 125)
    support = {"applied": True, "span_mm": [500.0, 2000.0], "object_gain_sigma_pct": 0.02}
    after = scale_report({"gain_estimated": False}, pred, 900.0, support=support)
    expect = np.hypot(np.sqrt(2) * 2.0 / 1500.0, 0.0002)
    assert np.isclose(after["gain_sigma"], expect) and np.isclose(after["gain_sigma_support"], expect)
    assert after["predicted_scale_sigma_pct"] < before["predicted_scale_sigma_pct"] / 3
    assert "flat support" in after["source"]
    not_applied = scale_report({"gain_estimated": False}, pred, 900.0, support={"applied": False, "why": "x"})
    assert np.isclose(not_applied["gain_sigma"], before["gain_sigma"])


def test_a_support_curve_anchored_on_the_mats_planes_leaves_its_own_gain_and_the_offset_as_measured():
    """Anchored on the dot mat's planes, the curve's gain is measured whole: only its jackknife sigma is
    left (not the sqrt(2) e / span a plane cannot show). Levelled on the object ('gain'), the offset stays
    the calibration's e; applied whole, it is the curve's own sigma at the object and 0.6 mm for the
    object's own offset from the support."""
    from tofmetry.reconstruct._scale_report import OBJECT_SUPPORT_OFFSET_MM

    folds = [{"center_mm": 750.0 + 250 * k, "central_mm": 2.0} for k in range(6)]
    pred = {"interpolation": {"central_abs_mm": {"predicted": 2.0}}, "folds": folds}
    base = {"applied": True, "span_mm": [500.0, 2000.0], "object_gain_sigma_pct": 0.05, "anchored": True,
            "n_anchors": 8, "object_offset_sigma_mm": 0.2}
    gain = scale_report({"gain_estimated": False}, pred, 900.0, support=base | {"levelled": True})
    assert np.isclose(gain["gain_sigma"], 0.0005) and gain["predicted_offset_sigma_mm"] == 2.0
    assert "anchored on 8 views" in gain["source"]
    whole = scale_report({"gain_estimated": False}, pred, 900.0, support=base | {"levelled": False})
    assert np.isclose(whole["predicted_offset_sigma_mm"], np.hypot(0.2, OBJECT_SUPPORT_OFFSET_MM))
    assert whole["predicted_scale_sigma_pct"] < gain["predicted_scale_sigma_pct"]


def test_with_stations_close_together_the_gain_left_is_levered_by_the_objects_depth_span():
    """A residual within +-|central| over an object's depth span L tilts it by at most 3 |central| / L:
    stations every 50 mm whose folds read the residual itself must not divide it by 25 mm. For wiggles of
    any wavelength and phase (the folds' centrals the residual at their stations), the RMS least-squares
    slope over the span stays within the figure; the figure is 6 x (L / 3 over 25 mm) below the spacing's."""
    z = np.arange(600.0, 1601.0, 50.0)
    lo, hi = 900.0, 1100.0  # L = 200 mm
    zs = np.linspace(lo, hi, 201)
    for lam in (100.0, 200.0, 400.0, 800.0, 1600.0):
        phases = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        slopes = [np.polyfit(zs, 0.3 * np.sin(2 * np.pi * zs / lam + ph), 1)[0] for ph in phases]
        sig = [calibration_gain_sigma({"interpolation": {"central_abs_mm": {"predicted": 0.3}},
                                       "folds": [{"center_mm": c, "central_mm": 0.3 * np.sin(2 * np.pi * c / lam + ph)}
                                                 for c in z]}, (lo, hi)) for ph in phases]
        assert np.sqrt(np.mean(np.square(slopes))) <= np.sqrt(np.mean(np.square(sig))), lam
    folds = [{"center_mm": c, "central_mm": 0.3} for c in z]
    pred = {"interpolation": {"central_abs_mm": {"predicted": 0.3}}, "folds": folds}
    assert np.isclose(calibration_gain_sigma(pred, (lo, hi)), 0.3 / (200 / 3))
    assert np.isclose(calibration_gain_sigma(pred), 0.3 / 25)
    sparse = {"interpolation": {"central_abs_mm": {"predicted": 0.3}},
              "folds": [{"center_mm": 1000.0 + 250 * k, "central_mm": 0.3} for k in range(5)]}
    assert np.isclose(calibration_gain_sigma(sparse, (lo, hi)), calibration_gain_sigma(sparse))  # 125 > 67 mm
