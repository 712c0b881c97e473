"""The range error a flat support shows (tofmetry.calibrate.flat_support_curve): geometry -> render -> recover.

Views of a floor from cameras at several heights and pitches; each pixel's depth Z along the
optical axis is moved by a range error e(Z) and noise. The curve must come back as e's part that a
plane cannot absorb (orthogonal to 1, Z and Z^2 over the span); a range error in those must give no curve.
"""

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from tofmetry.calibrate import flat_support_curve
from tofmetry.errors import EstimationError, InputError

# a Kinect-v2-like pixel grid of normalised rays (every 4th pixel)
_X, _Y = np.meshgrid((np.arange(0, 512, 4) - 256) / 365.0, (np.arange(0, 424, 4) - 212) / 365.0)
RAYS = np.column_stack([_X.ravel(), _Y.ravel()])


def floor_depths(height_m: float, pitch_deg: float, roll_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """True Z [mm] of a floor ``height_m`` below a camera pitched down by ``pitch_deg`` and rolled by
    ``roll_deg``, and the rays that hit it within 0.5-2.5 m."""
    t, r = np.radians(pitch_deg), np.radians(roll_deg)
    up = np.array([0.0, -np.cos(t), -np.sin(t)])  # world up in the camera frame (x right, y down, z forward)
    c, s = np.cos(r), np.sin(r)
    up = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ up
    den = -(np.column_stack([RAYS, np.ones(len(RAYS))]) @ up)
    z = np.where(den > 1e-6, height_m / np.maximum(den, 1e-6), np.inf)
    keep = (z > 0.5) & (z < 2.5)
    return z[keep] * 1e3, RAYS[keep]


def wiggle_mm(z_mm: np.ndarray) -> np.ndarray:
    return 2.5 * np.sin(2 * np.pi * z_mm / 470.0 + 0.7) + 1.0 * np.sin(2 * np.pi * z_mm / 900.0 + 2.0)


def views_of_floor(error, noise_mm: float, seed: int = 1):
    rng = np.random.default_rng(seed)
    Z, XY = [], []
    for h, p, r in [(0.30, 20, 0), (0.40, 28, 3), (0.50, 35, -2), (0.35, 45, 1), (0.60, 60, 0), (0.45, 25, -4)]:
        z, xy = floor_depths(h, p, r)
        Z.append(z + error(z) + rng.normal(0, noise_mm, len(z)))
        XY.append(xy)
    return Z, XY


def nonlinear_part(error, lo: float, hi: float, z: np.ndarray) -> np.ndarray:
    """``error`` less its least-squares parabola over [lo, hi] (uniform in Z): what the curve can show,
    at measured depths ``z`` [mm] (the true depth is ``z - error``, to first order)."""
    g = np.linspace(lo, hi, 2000)
    line = np.polyfit(g - 1000.0, error(g), 2)
    return error(z - error(z)) - np.polyval(line, z - 1000.0)  # at the measured depth z


def test_the_wiggle_between_stations_comes_back_from_a_flat_floor():
    Z, XY = views_of_floor(wiggle_mm, noise_mm=1.0)
    c = flat_support_curve(Z, XY)
    lo, hi = c.span_mm
    z = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 50)
    truth = nonlinear_part(wiggle_mm, lo, hi, z)
    # the spline (60 mm knots) follows a 470 mm sine within ~0.02 mm; 1 mm noise over 10^4 points per knot adds less
    assert np.max(np.abs(c.error_mm(z) - truth)) < 0.1
    # the gain it reads where an object would lie: the sine's slope (up to 3.3 %) within 0.1 %
    zz = np.array([700.0, 800.0, 900.0])
    slope_true = (nonlinear_part(wiggle_mm, lo, hi, zz + 1) - nonlinear_part(wiggle_mm, lo, hi, zz - 1)) / 2
    g, s = c.gain(zz)
    assert np.max(np.abs(g - slope_true)) < 1e-3
    assert np.all(s < 1e-3)
    assert c.n_views == 6 and c.flatness_before_mm > 2 * c.residual_mm


def test_an_offset_a_gain_and_an_inverse_depth_shift_leave_no_curve():
    # each maps a plane onto a plane (nearly, the offset): the support cannot show them and must not invent a curve
    Z, XY = views_of_floor(lambda z: 4.0 + 0.01 * (z - 1000.0) + 2e-6 * z ** 2, noise_mm=1.0)
    c = flat_support_curve(Z, XY)
    z = np.linspace(*np.percentile(np.concatenate(Z), [5, 95]), 50)  # the span's ends hold few points
    assert np.max(np.abs(c.error_mm(z))) < 0.1


def test_the_curve_is_held_at_its_ends_beyond_the_span():
    Z, XY = views_of_floor(wiggle_mm, noise_mm=1.0)
    c = flat_support_curve(Z, XY)
    lo, hi = c.span_mm
    assert c.error_mm(np.array([lo - 300.0]))[0] == pytest.approx(c.error_mm(np.array([lo]))[0])
    assert c.gain(np.array([hi + 300.0]))[0][0] == 0.0


def test_too_few_views_or_a_short_span_say_why():
    Z, XY = views_of_floor(wiggle_mm, noise_mm=1.0)
    with pytest.raises(EstimationError, match="3 needed"):
        flat_support_curve(Z[:2], XY[:2])
    narrow = [z[(z > 900) & (z < 1000)] for z in Z]
    with pytest.raises(EstimationError, match="span"):
        flat_support_curve(narrow, [xy[(z > 900) & (z < 1000)] for z, xy in zip(Z, XY)])
    with pytest.raises(InputError, match="view 0"):
        flat_support_curve([Z[0]], [XY[0][:10]])


def test_levelled_on_an_objects_depths_keeps_the_slope_and_takes_the_mean():
    Z, XY = views_of_floor(wiggle_mm, noise_mm=1.0)
    c = flat_support_curve(Z, XY)
    z_obj = np.linspace(750.0, 950.0, 101)
    lv = c.levelled(z_obj)
    assert abs(np.mean(lv.error_mm(z_obj))) < 1e-9
    assert lv.level_mm == pytest.approx(np.mean(c.error_mm(z_obj)))
    np.testing.assert_allclose(lv.gain(z_obj)[0], c.gain(z_obj)[0])
    assert c.level_mm == 0.0  # the original is left as it was


def _floor_anchor(h: float, p: float, r: float, sigma_rel: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """The floor's true ``(a, b, c)`` (``1 / Z = a x + b y + c`` [1/m]) with a relative error drawn at
    ``sigma_rel`` of its distance, and that covariance: what a printed pattern's perspective fit gives."""
    t, q = np.radians(p), np.radians(r)
    up = np.array([0.0, -np.cos(t), -np.sin(t)])
    c, s = np.cos(q), np.sin(q)
    up = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ up
    abc = -up / h  # n . p + h = 0 with n = up: 1 / Z = -(n . ray) / h
    # its distance off by sigma_rel (the pattern's scale), its tilt by 0.02 deg
    cov = sigma_rel ** 2 * np.outer(abc, abc) + (np.radians(0.02) / h) ** 2 * np.diag([1.0, 1.0, 0.0])
    return rng.multivariate_normal(abc, cov), cov


def test_anchored_planes_give_the_whole_curve_offset_gain_and_curvature_included():
    """With each view's floor known without the depth, its distance to 0.1 % and its tilt to 0.02 deg
    (a dot mat's perspective fit, 40-55 dots), an offset + gain + curvature that a plane alone cannot
    show comes back with the wiggle over the depths an object stands at."""
    def error(z):
        return wiggle_mm(z) + 1.5 + 0.004 * (z - 1000.0) - 3e-6 * (z - 1000.0) ** 2

    rng = np.random.default_rng(4)
    Z, XY = views_of_floor(error, noise_mm=1.0)
    poses = [(0.30, 20, 0), (0.40, 28, 3), (0.50, 35, -2), (0.35, 45, 1), (0.60, 60, 0), (0.45, 25, -4)]
    anchors = [_floor_anchor(h, p, r, 1e-3, rng) for h, p, r in poses]
    c = flat_support_curve(Z, XY, anchors=anchors)
    assert c.anchored and c.n_anchors == 6
    z = np.linspace(600.0, 1400.0, 50)
    truth = error(z - error(z))
    # a plane's distance off by 0.1 % moves its depths by 0.1 % (0.6-1.4 mm here); six views: about
    # 0.04 % of Z, 0.25-0.6 mm; twice that, and the jackknife's 1-sigma covers it
    diff = c.error_mm(z) - truth
    assert np.all(np.abs(diff) < 1e-3 * z)
    _, sig = c.mean_gain(z)
    g_err = np.polyfit(z, diff, 1)[0]
    assert abs(g_err) < 3 * sig + 2e-4
    # unanchored, the same views give the curve's part orthogonal to 1, Z and Z^2 only
    u = flat_support_curve(Z, XY)
    assert not u.anchored and np.max(np.abs(u.error_mm(z) - truth)) > 1.0


def test_tied_to_the_calibrations_stations_the_curve_gives_the_whole_gain():
    """A calibration's residual is about nought at its stations and wiggles between them; the support
    shows the wiggle less its 1, Z and Z^2 over the span. Tied to nought at the stations, the curve's
    slope over an object's depths is the residual's, the parts a plane absorbs included."""
    stations = np.arange(600.0, 2700.0, 400.0)  # a calibration's stations, 400 mm apart
    through = CubicSpline(stations, wiggle_mm(stations))  # a smooth calibration through its stations

    def residual(z):
        return wiggle_mm(z) - through(z)

    Z, XY = views_of_floor(residual, noise_mm=1.0)
    untied = flat_support_curve(Z, XY)
    tied = flat_support_curve(Z, XY, stations_mm=stations)
    lo, hi = tied.span_mm
    assert tied.stations_mm == tuple(stations[(stations >= lo) & (stations <= hi)])
    zz = np.linspace(650.0, 1450.0, 40)  # where objects stand

    def true_slope(z):
        return (residual(z - residual(z) + 1) - residual(z - residual(z) - 1)) / 2

    err_tied = np.max(np.abs(tied.gain(zz)[0] - true_slope(zz)))
    err_untied = np.max(np.abs(untied.gain(zz)[0] - true_slope(zz)))
    # the residual's slope spans +-5 %; the spline (60 mm knots, its smoothness prior) follows it within
    # 0.25 %; untied, the curve misses the slope of the residual's parabola over the span besides (0.4 %)
    assert err_tied < 2.5e-3 and err_tied < 0.6 * err_untied
    # its level at an object's depths is what the tie adds there: levelling keeps the slope
    z_obj = np.linspace(900.0, 1000.0, 20)
    assert tied.tie_mean_mm(z_obj) != 0.0 and untied.tie_mean_mm(z_obj) == 0.0
    np.testing.assert_allclose(tied.levelled(z_obj).gain(z_obj)[0], tied.gain(z_obj)[0])
    # with that taken off (the reconstruction's unlevelled curve), its level there is the untied curve's
    tied.level_mm = tied.tie_mean_mm(z_obj)
    assert np.mean(tied.error_mm(z_obj)) == pytest.approx(np.mean(untied.error_mm(z_obj)), abs=1e-9)
    # fewer than two stations within the span: untied
    one = flat_support_curve(Z, XY, stations_mm=[1000.0])
    assert one.tie_coef_mm is None and one.stations_mm == ()
    np.testing.assert_allclose(one.coef_mm, untied.coef_mm)


def test_a_curve_that_changes_across_the_image_comes_back_at_the_centre():
    """A residual that differs between the image's sides and its centre (``x^2 h(Z)``: a per-pixel
    deformation interpolated between stations) biases a single curve, which averages the sides in; with
    the ``x2`` term the curve on the optical axis is the centre's, and ``h`` comes back whole."""
    def side(z):  # h at x = 0.5 [mm]
        return 1.5 * np.sin(2 * np.pi * z / 700.0 + 1.0)

    rng = np.random.default_rng(3)
    Z, XY = [], []
    for h, p, r in [(0.30, 20, 0), (0.40, 28, 3), (0.50, 35, -2), (0.35, 45, 1), (0.60, 60, 0), (0.45, 25, -4)]:
        z, xy = floor_depths(h, p, r)
        Z.append(z + wiggle_mm(z) + xy[:, 0] ** 2 / 0.25 * side(z) + rng.normal(0, 1.0, len(z)))
        XY.append(xy)
    single = flat_support_curve(Z, XY)
    lat = flat_support_curve(Z, XY, lateral=("x2",))
    lo, hi = lat.span_mm
    z = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 50)
    axis = np.zeros((len(z), 2))
    truth = nonlinear_part(wiggle_mm, lo, hi, z)
    # the sides' 1.5 mm (at x = 0.5; the floor reaches x = 0.7) pull the single curve by up to a millimetre;
    # the x^2 term takes them: the spline then follows the centre's wiggle as it does without them (0.1 mm)
    assert np.max(np.abs(single.error_mm(z) - truth)) > 0.5
    assert np.max(np.abs(lat.error_mm(z, axis) - truth)) < 0.15
    h_fit = lat.error_mm(z, np.column_stack([np.full(len(z), 0.5), np.zeros(len(z))])) - lat.error_mm(z, axis)
    assert np.max(np.abs(h_fit - side(z))) < 0.3
    # its gain at the centre, with its jackknife, and the report names the terms
    g, s = lat.mean_gain(z, axis)
    assert np.all(np.isfinite([g, s])) and s > 0
    d = lat.to_dict()
    assert d["lateral"] == ["x2"] and "x2" in d["lateral_mm"]
    with pytest.raises(InputError, match="rays xy"):
        lat.error_mm(z)
    with pytest.raises(InputError, match="unknown"):
        flat_support_curve(Z, XY, lateral=("x3",))
