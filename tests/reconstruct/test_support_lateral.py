"""The support curve that changes across the image (tofmetry.reconstruct._support_curve.correct_by_support, ``lateral``).

Six views of a floor from cameras at several heights and pitches, a box standing in the image's middle; every
pixel's depth is off by a range wiggle plus ``x^2 / 0.25 h(Z)`` (the image's sides 1.5 mm apart from its centre at
x = 0.5, changing with depth). The object's gain is the wiggle's at the centre: a single curve, which averages
the sides in, reads it off; with the ``x2`` term it comes back.
"""

from __future__ import annotations

import numpy as np

from tests.reconstruct.floor_scenes import INTR, POSES, floor_and_box, wiggle_mm
from tofmetry.reconstruct._support_curve import correct_by_support


def side_mm(z):  # h(Z) at x = 0.5 [mm]
    return 1.5 * np.sin(2 * np.pi * z / 700.0 + 1.0)


def error_mm(z, xy):
    return wiggle_mm(z) + xy[:, 0] ** 2 / 0.25 * side_mm(z)


def view_of(h: float, pitch_deg: float, rng):
    """A floor ``h`` below the camera pitched down ``pitch_deg``, a box face in the middle at 0.95 of the floor's
    depth there; every depth moved by :func:`error_mm` and 0.5 mm of noise."""
    box_z = 0.95 * h / np.sin(np.radians(pitch_deg))  # the floor's depth on the optical axis
    return floor_and_box(h, pitch_deg, 0.1, (-0.08, 0.08), box_z, 0.45, error_mm=error_mm, noise_mm=0.5, rng=rng,
                         name=f"{pitch_deg:02d}")


def object_gain_truth(report: dict, z_obj: np.ndarray) -> float:
    """The centre's wiggle less its parabola over the curve's span (what a support can show), its mean slope over
    the object's depths ``z_obj`` [mm]."""
    lo, hi = report["span_mm"]
    g = np.linspace(lo, hi, 2000)
    para = np.polyfit(g - 1000.0, wiggle_mm(g), 2)
    return float(np.mean(np.gradient(wiggle_mm(g) - np.polyval(para, g - 1000.0), g)[
        np.searchsorted(g, np.clip(z_obj, lo, hi - 1e-6))]))


def corrected(lateral: tuple) -> tuple[dict, np.ndarray]:
    rng = np.random.default_rng(5)
    pairs = [view_of(h, p, rng) for h, p in POSES]
    views, segs = [v for v, _ in pairs], [s for _, s in pairs]
    z_obj = np.concatenate([v.points[s.object_mask, 2] for v, s in pairs]) * 1e3
    rep = correct_by_support(views, segs, INTR, 0.015, 12.0, 0.01, 60.0, 5.0, lateral=lateral)
    return rep, z_obj


def test_the_x2_term_gives_the_objects_gain_at_the_image_centre():
    single, z_obj = corrected(())
    lat, _ = corrected(("x2",))
    assert single["applied"] and lat["applied"] and lat["lateral"] == ["x2"]
    truth = 100 * object_gain_truth(lat, z_obj)
    # the wiggle's slope over the box's depths (several per cent); the sides' 1.5 mm pull a single curve's gain
    # there by tenths of a per cent, the x^2 term leaves what the spline's smoothing does (hundredths)
    err_single = abs(single["object_gain_pct"] - truth)
    err_lat = abs(lat["object_gain_pct"] - truth)
    assert err_lat < 0.1 and err_lat < 0.5 * err_single, (truth, single["object_gain_pct"], lat["object_gain_pct"])
    assert abs(err_lat) < 3 * lat["object_gain_sigma_pct"] + 0.05
