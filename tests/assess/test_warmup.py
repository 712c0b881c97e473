"""Warm-up analysis against the simulator's true drift."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.assess import assess_warmup, local_linear_smooth, select_patch
from tofmetry.errors import InputError
from tofmetry.io import Capture, read_json


def _true_stabilisation(t, drift, tol, final_window_s):
    final = np.median(drift[t >= t[-1] - final_window_s])
    out = np.flatnonzero(np.abs(drift - final) > tol)
    return (t[out[-1] + 1] if out.size else 0.0), final - drift[0]


def test_recovers_simulated_warmup(warmup_ds):
    cap = Capture(warmup_ds / "capture")
    truth = read_json(warmup_ds / "truth.json", "truth")
    t = np.asarray(truth["timestamps_s"]) - truth["timestamps_s"][0]
    drift = np.asarray(truth["true_drift_mm"])
    # tolerance 1.5 mm: the simulated curve crosses it on its steep rise (~0.4 mm/min), so the
    # true time is well defined; at 1 mm the fan-start overshoot (~1.0 mm) makes it ill-posed.
    tol = 1.5
    res = assess_warmup(cap, tolerance_mm=tol)
    t_true, drift_true = _true_stabilisation(t, drift, tol, res.final_window_s)
    assert res.patch_source == "ir_max"
    assert res.stabilisation_time_s is not None
    assert abs(res.stabilisation_time_s - t_true) <= 180.0  # issue: within 3 min
    assert abs(res.total_drift_mm - drift_true) <= 0.5      # issue: drift within 0.5 mm
    d = res.to_dict()
    assert d["stable_confirmed"] and len(d["series"]["time_s"]) == len(cap)


def test_no_ir_falls_back_to_min_depth_and_says_so(warmup_ds):
    cap = Capture(warmup_ds / "capture")
    frames = [cap.depth(i) for i in range(len(cap))]
    res = assess_warmup(frames, cap.timestamps_s)
    assert res.patch_source == "depth_min"
    assert any("no IR" in n for n in res.notes)


def test_missing_timestamps_is_a_clear_error():
    frames = np.full((5, 20, 20), 1000, np.uint16)
    with pytest.raises(InputError, match="timestamps"):
        assess_warmup(frames)


def test_select_patch_prefers_brightest_valid_patch():
    depth = np.full((40, 50), 1000, np.uint16)
    ir = np.ones((40, 50))
    ir[5:15, 30:40] = 10.0
    (u0, v0, s), src = select_patch(depth, ir, 10)
    assert (u0, v0, s, src) == (30, 5, 10, "ir_max")
    depth[5:15, 30:40] = 0  # invalid there -> must move away
    (u0, v0, s), _ = select_patch(depth, ir, 10)
    assert not (5 <= v0 + 4 < 15 and 30 <= u0 + 4 < 40)


def test_local_linear_smooth_is_exact_on_lines():
    t = np.arange(0, 100.0, 3.0)
    y = 2.0 + 0.5 * t
    np.testing.assert_allclose(local_linear_smooth(t, y, 20.0), y, atol=1e-9)


def test_default_tolerance_truth_inside_reported_range(warmup_ds):
    """At the default 1 mm the simulated fan overshoot (~1.0 mm) sits on the tolerance: the
    point estimate may land before or after it, but the reported range (0.9-1.1 x tolerance)
    must bracket the truth within 3 min."""
    cap = Capture(warmup_ds / "capture")
    truth = read_json(warmup_ds / "truth.json", "truth")
    t = np.asarray(truth["timestamps_s"]) - truth["timestamps_s"][0]
    res = assess_warmup(cap)
    t_true, _ = _true_stabilisation(t, np.asarray(truth["true_drift_mm"]), 1.0, res.final_window_s)
    lo, hi = res.stabilisation_range_s
    assert lo is not None and hi is not None
    assert lo - 180.0 <= t_true <= hi + 180.0
