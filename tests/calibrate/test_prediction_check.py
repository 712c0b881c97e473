"""Checking a calibration's predicted error against held-out measurements (``check_prediction``)."""

from __future__ import annotations

import numpy as np

from tofmetry.calibrate import check_prediction


def _prediction(value: float) -> dict:
    return {"interpolation": {"rms_systematic_mm": {"predicted": value, "median": value, "p5": 0.0,
                                                    "p95": value, "max": value, "n": 10}}}


def test_a_prediction_of_zero_met_by_zero_holds():
    """A systematic RMS at the noise floor is 0 predicted and 0 measured: the prediction holds, and
    its ratio is 1, not 0 / 0 (seed 2048700159 of the depth family, a CI failure of 2026-12-01)."""
    c = check_prediction(_prediction(0.0), [{"rms_systematic_mm": 0.0}, {"rms_systematic_mm": 0.0}])
    assert c["rms_systematic_mm"]["ratio"] == 1.0
    assert c["verdict"] == "holds"


def test_a_prediction_of_zero_with_an_error_measured_fails():
    c = check_prediction(_prediction(0.0), [{"rms_systematic_mm": 0.3}])
    assert np.isinf(c["rms_systematic_mm"]["ratio"])
    assert c["verdict"] == "fails"


def test_a_prediction_is_judged_by_the_quadratic_mean_of_the_rows():
    rows = [{"rms_systematic_mm": 0.3}, {"rms_systematic_mm": 0.4}]
    c = check_prediction(_prediction(0.25), rows)
    assert np.isclose(c["rms_systematic_mm"]["measured"], np.sqrt((0.09 + 0.16) / 2))
    assert c["verdict"] == "holds"  # 0.354 / 0.25 = 1.41, within 1.5
