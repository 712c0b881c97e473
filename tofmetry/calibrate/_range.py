"""The study's range-error curve ``R(d)``: a cubic smoothing B-spline of the central deviations
of the wall stations against their measured distance (§4.2.2).

Used by the study's baseline method (:mod:`tofmetry.calibrate._fit_study`). Between stations
such a spline can only interpolate: a wiggling component whose period is not well above twice
the station spacing is missed at stations never fitted. tofmetry's own model
(:mod:`tofmetry.calibrate._joint`) samples the range error over every pixel's ray length instead.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline, make_smoothing_spline


def merge_close(x: np.ndarray, y: np.ndarray, merge_mm: float = 1.0):
    """Average points closer than ``merge_mm`` in ``x``; returns sorted ``x, y, w`` (w = count)."""
    order = np.argsort(x, kind="stable")
    x, y = np.asarray(x, float)[order], np.asarray(y, float)[order]
    gx, gy, gw = [x[0]], [y[0]], [1.0]
    for xi, yi in zip(x[1:], y[1:]):
        if xi - gx[-1] / gw[-1] < merge_mm:
            gx[-1] += xi
            gy[-1] += yi
            gw[-1] += 1.0
        else:
            gx.append(xi)
            gy.append(yi)
            gw.append(1.0)
    w = np.array(gw)
    return np.array(gx) / w, np.array(gy) / w, w


def smoothing_spline(x: np.ndarray, y: np.ndarray, w: np.ndarray, lam: float | None = None) -> BSpline:
    """Cubic smoothing spline (GCV smoothing unless ``lam``); interpolating for < 5 points."""
    if len(x) >= 5:
        return make_smoothing_spline(x, y, w=w / w.mean(), lam=lam)
    return make_interp_spline(x, y, k=min(3, len(x) - 1))


def fit_range_curve(x: np.ndarray, y: np.ndarray, lam: float | None = None, merge_mm: float = 1.0) -> BSpline:
    """Cubic smoothing B-spline of deviation ``y`` [mm] against measured distance ``x`` [mm].

    Points closer than ``merge_mm`` in ``x`` are averaged first (weight = their count).
    Fewer than 5 distinct distances: interpolating spline of degree ``min(3, n - 1)``.
    """
    xm, ym, wm = merge_close(x, y, merge_mm)
    return smoothing_spline(xm, ym, wm, lam)
