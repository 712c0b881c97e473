"""The support curve refused where it reads more range error at the object than the calibration can have left
(tofmetry.reconstruct._support_curve.correct_by_support, ``max_error_mm``; curve_beyond).

Six views of a floor from cameras at several heights and pitches, a box standing in the image's middle; every
pixel's depth is off by a range wiggle (up to 3.5 mm), and in the middle columns (``|x| < 0.2``, the box's and the
floor's below and beyond it) by another ``amp`` mm wave over depth: a support not flat there, or a residual there
alone. Read in the object's columns the curve takes that wave whole; from the whole support, a fraction of it.
"""

from __future__ import annotations

import numpy as np

from tests.reconstruct.floor_scenes import INTR, POSES, floor_and_box, wiggle_mm
from tofmetry.reconstruct._support_curve import correct_by_support


def scene(amp_mm: float):
    """The six views, every depth moved by the wiggle plus ``amp_mm`` of a 300 mm wave in the middle columns."""
    def error_mm(z, xy):
        return wiggle_mm(z) + amp_mm * (np.abs(xy[:, 0]) < 0.2) * np.sin(2 * np.pi * z / 300.0)

    rng = np.random.default_rng(5)
    pairs = [floor_and_box(h, p, 0.1, (-0.08, 0.08), 0.95 * h / np.sin(np.radians(p)), 0.45, error_mm=error_mm,
                           noise_mm=0.5, rng=rng, name=f"{p:02d}") for h, p in POSES]
    return [v for v, _ in pairs], [s for _, s in pairs]


def corrected(amp_mm: float, bound_mm: float | None, columns: float | None = None):
    views, segs = scene(amp_mm)
    before = [v.points.copy() for v in views]
    rep = correct_by_support(views, segs, INTR, 0.015, 12.0, 0.01, 60.0, 5.0, columns=columns, max_error_mm=bound_mm)
    return rep, max(float(np.max(np.abs(v.points - b))) for v, b in zip(views, before))


def test_a_curve_within_the_bound_is_applied_as_without_one():
    free, moved_free = corrected(0.0, None)
    bounded, moved = corrected(0.0, 6.0)
    assert bounded["applied"] and "refused" not in bounded
    assert bounded["object_gain_pct"] == free["object_gain_pct"] and moved == moved_free > 0.0


def test_a_curve_beyond_the_bound_is_not_applied_and_says_why():
    rep, moved = corrected(0.0, 1.0)  # the wiggle alone reads ~3 mm at the box's depths
    assert not rep["applied"] and moved == 0.0
    assert "more than the depth calibration can have left there (1.0 mm)" in rep["why"]
    assert rep["why"].endswith("not applied")
    assert rep["refused"] == [rep["why"]]


def test_the_objects_columns_give_way_to_the_whole_support_beyond_the_bound():
    cols_free, _ = corrected(8.0, None, columns=0.05)  # the columns take the 8 mm wave whole
    whole, _ = corrected(8.0, 6.0)
    cols, _ = corrected(8.0, 6.0, columns=0.05)
    assert cols_free["applied"] and cols_free["max_abs_mm"] > 10.0
    assert cols["applied"] and cols["refused"][0].startswith("the support curve from the object's image columns reads")
    assert cols["refused"][0].endswith("the whole support's is tried")
    # what was applied is the whole support's curve
    assert cols["object_gain_pct"] == whole["object_gain_pct"] and cols["max_abs_mm"] == whole["max_abs_mm"] < 6.0
