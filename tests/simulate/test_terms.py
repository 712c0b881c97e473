"""The generalised error terms: defaults bit-identical, each new term measured back from renders."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.sensor import KINECT_V2
from tofmetry.simulate import ErrorModel, VirtualKinect, scenes
from tofmetry.simulate import errors as E
from tofmetry.simulate.range_error import range_error_curve_mm

XY = np.asarray(KINECT_V2.depth.ray_table())
C = (slice(202, 212), slice(251, 261))


# ------------------------------------------------------------------ defaults unchanged
def _old_wiggling(z_mm, em):  # the single-sensor formula before the family (verbatim)
    z = np.asarray(z_mm, dtype=np.float64) * 1e-3
    w = em.wiggle_offset_mm + em.wiggle_slope_mm_per_m * (z - 0.8)
    for k, (a, p) in enumerate(zip(em.wiggle_amps_mm, em.wiggle_phases), start=1):
        w = w + a * np.sin(2 * np.pi * k * z / E.HALF_WAVELENGTH_M + p)
    return w + em.wiggle_steep_mm * np.maximum(z - em.wiggle_steep_start_m, 0.0) ** 1.5


def _old_deformation(xy, z_mm, em):  # verbatim as well
    x = xy[..., 0] - em.deform_centre_shift[0]
    y = xy[..., 1] - em.deform_centre_shift[1]
    q = ((x * em.deform_aspect) ** 2 + y ** 2) / em.deform_radius ** 2
    a = em.deform_sharpness
    span = em.deform_corner_mm_1m - em.deform_centre_mm_1m
    bowl = em.deform_centre_mm_1m + span * (np.exp(a * q) - 1.0) / (math.exp(a) - 1.0)
    shape = bowl + em.deform_skew_mm_1m * np.tanh(2.0 * x * y / 0.4)
    z = np.asarray(z_mm, dtype=np.float64) * 1e-3
    return shape * ((1.0 - em.deform_range_gain) + em.deform_range_gain * z)


#: the simulator's Kinect v2 before the sensor family (range error of Z, added to Z)
LEGACY = ErrorModel(range_variable="z", range_apply="z")


def test_default_terms_bit_identical_to_the_single_sensor_formulas():
    em = LEGACY
    z = np.linspace(500.0, 5500.0, XY.shape[0] * XY.shape[1]).reshape(XY.shape[:2])
    np.testing.assert_array_equal(E.wiggling_mm(z, em), _old_wiggling(z, em))
    np.testing.assert_array_equal(E.wiggling_mm(z, em, XY), _old_wiggling(z, em))  # rays ignored in Z mode
    np.testing.assert_array_equal(E.deformation_mm(XY, z, em), _old_deformation(XY, z, em))
    # the tests/calibrate use of the flat harmonic amplitudes still works
    em1 = em.with_(wiggle_amps_mm=(4.5, 0.0, 0.0))
    np.testing.assert_array_equal(E.wiggling_mm(z, em1), _old_wiggling(z, em1))


def _sha(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def test_default_captures_bit_identical_golden():
    """uint16 frames of the legacy sensor, hashed before the family was added.

    The wall (never supersampled) keeps its hash from then. The material board's edges are
    supersampled: its hash was renewed when the sub-rays became an n-rooks pattern of the pixel
    footprint with the lens's point spread (``render._sub_offsets``), which changes edge pixels only.
    """
    fr = VirtualKinect(LEGACY, seed=3).capture(scenes.wall(0.8, (2.0, -1.0)), n_frames=3)
    assert _sha(fr.depth, fr.ir, fr.flying) == "e99f328c4933ef34"
    fr = VirtualKinect(LEGACY, seed=2).capture(scenes.material_board(1.0), n_frames=2)
    assert _sha(fr.depth, fr.ir, fr.flying) == "0806191a3a2fe65e"


def test_validation_names_the_parameter():
    with pytest.raises(InputError, match="range_variable"):
        ErrorModel(range_variable="ray")
    with pytest.raises(InputError, match="range_apply"):
        ErrorModel(range_apply="radial")
    with pytest.raises(InputError, match="deform_range_kind"):
        ErrorModel(deform_range_kind="cubic")
    with pytest.raises(InputError, match="wiggle_harmonics"):
        ErrorModel(wiggle_periods_m=(1.0, 0.5))  # two periods need harmonic counts
    with pytest.raises(InputError, match="wiggle_harmonics"):
        ErrorModel(wiggle_periods_m=(1.0, 0.5), wiggle_harmonics=(2, 2))  # 4 != 3 amplitudes
    with pytest.raises(InputError, match="deform_sharpness"):
        ErrorModel(deform_sharpness=0.0)
    with pytest.raises(InputError, match="xy"):
        E.wiggling_mm(1000.0, ErrorModel(range_variable="radial"))
    with pytest.raises(InputError, match="unknown field"):
        ErrorModel.from_dict({"wiggle_colour": 1})


# ------------------------------------------------------------------ range error
def _true_z(scene, xy):
    """Z of the scene's plane along each ray, from the geometry alone: n . (Z (x, y, 1)) = d."""
    n = np.asarray(scene.info["plane_normal"])
    return 1e3 * scene.info["plane_d_m"] / (xy[..., 0] * n[0] + xy[..., 1] * n[1] + n[2])


RANGE_EM = dict(wiggle_offset_mm=-4.0, wiggle_slope_mm_per_m=2.0, wiggle_quad_mm_per_m2=0.7, wiggle_gain=0.003,
                wiggle_periods_m=(0.61, 2.3), wiggle_harmonics=(1, 2), wiggle_amps_mm=(3.0, 4.0, 1.2),
                wiggle_phases=(0.3, 2.0, 5.0), wiggle_steep_start_m=1.9, wiggle_steep_mm=8.0, wiggle_steep_power=1.7)


@pytest.mark.parametrize("variable,apply", [("radial", "ray"), ("radial", "z"), ("z", "ray"), ("z", "z")])
def test_range_error_recovered_from_a_tilted_wall(variable, apply):
    em = ErrorModel.only("wiggling", quantize=False, range_variable=variable, range_apply=apply, **RANGE_EM)
    sc = scenes.wall(1.8, (6.0, -9.0))
    fr = VirtualKinect(em).capture(sc, n_frames=1)
    z_true = _true_z(sc, XY)
    np.testing.assert_allclose(fr.true_depth, z_true, rtol=1e-12)
    rho = np.sqrt(1 + XY[..., 0] ** 2 + XY[..., 1] ** 2)
    d_true = z_true * rho if variable == "radial" else z_true
    # what the sensor got wrong, in the quantity it measured (radial range or Z)
    err = (fr.depth[0] - z_true) * (rho if apply == "ray" else 1.0)
    np.testing.assert_allclose(err, range_error_curve_mm(d_true, em), atol=1e-8)
    # a radial range error reaches the corners earlier: the map is not a function of Z alone
    if variable == "radial":
        assert np.ptp(err[C]) < 0.5 < abs(err[0, 0] - range_error_curve_mm(z_true[0, 0], em))


def test_gain_error_along_the_ray_is_a_pure_scale():
    em = ErrorModel.only("wiggling", quantize=False, range_variable="radial", range_apply="ray",
                         wiggle_offset_mm=0.0, wiggle_slope_mm_per_m=0.0, wiggle_amps_mm=(0.0,), wiggle_phases=(0.0,),
                         wiggle_steep_mm=0.0, wiggle_gain=-0.004)
    fr = VirtualKinect(em).capture(scenes.wall(2.5, (3.0, 2.0)), n_frames=1)
    np.testing.assert_allclose(fr.depth[0] / fr.true_depth, 1 - 0.004, rtol=1e-12)


def test_periodic_component_fitted_back_from_stations():
    """A component of arbitrary period: amplitude and phase recovered by least squares from centre readings."""
    period, amp, phase = 0.83, 3.5, 1.1
    em = ErrorModel.only("wiggling", quantize=False, wiggle_offset_mm=0.0, wiggle_slope_mm_per_m=0.0,
                         wiggle_steep_mm=0.0, wiggle_periods_m=(period,), wiggle_amps_mm=(amp,), wiggle_phases=(phase,),
                         range_variable="z", range_apply="z")  # the centre patch then reads the curve exactly
    vk = VirtualKinect(em)
    z = np.arange(800.0, 4000.0, 100.0)
    bias = np.array([(lambda f: (f.depth[0] - f.true_depth)[C].mean())(vk.capture(scenes.wall(d / 1e3), 1)) for d in z])
    arg = 2 * np.pi * z * 1e-3 / period
    coef, *_ = np.linalg.lstsq(np.column_stack([np.sin(arg), np.cos(arg), np.ones_like(z)]), bias, rcond=None)
    assert math.hypot(coef[0], coef[1]) == pytest.approx(amp, abs=1e-6)
    assert math.atan2(coef[1], coef[0]) == pytest.approx(phase, abs=1e-6)


# ------------------------------------------------------------------ deformation
def test_tilt_term_recovered_by_a_plane_fit():
    em = ErrorModel.only("deformation", quantize=False, deform_corner_mm_1m=0.0, deform_centre_mm_1m=0.0,
                         deform_skew_mm_1m=0.0, deform_tilt_mm_1m=(4.0, -6.0), deform_range_kind="constant")
    fr = VirtualKinect(em).capture(scenes.wall(2.0), n_frames=1)
    b = (fr.depth[0] - fr.true_depth).ravel()
    A = np.column_stack([XY[..., 0].ravel(), XY[..., 1].ravel(), np.ones(b.size)])
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    np.testing.assert_allclose(coef, [4.0, -6.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("kind,params,f", [
    ("constant", {}, lambda z: 1.0),
    ("linear", {"deform_range_gain": -0.2}, lambda z: 1.2 - 0.2 * z),
    ("decay", {"deform_range_decay_m": 2.5}, lambda z: math.exp(-(z - 1) / 2.5)),
    ("quadratic", {"deform_range_gain": 0.3}, lambda z: 0.7 + 0.3 * z * z),
])
def test_deformation_range_dependence(kind, params, f):
    em = ErrorModel.only("deformation", quantize=False, deform_range_kind=kind,
                         deform_modes=((2.0, 1.0, 2.0, 0.4),), deform_bumps=((-3.0, 0.2, -0.1, 0.2),), **params)
    vk = VirtualKinect(em)
    b1, b3 = ((lambda fr: fr.depth[0] - fr.true_depth)(vk.capture(scenes.wall(d), 1)) for d in (1.0, 3.2))
    # the shape at 1 m is the documented sum: bowl + skew + Fourier mode + Gaussian bump
    xc, yc = em.deform_corner_xy
    x, y = XY[..., 0], XY[..., 1]
    extra = 2.0 * np.cos(np.pi * (x / xc + 2 * y / yc) + 0.4) - 3.0 * np.exp(-((x - 0.2) ** 2 + (y + 0.1) ** 2) / 0.08)
    bowl = E.deformation_shape(XY, em.with_(deform_modes=(), deform_bumps=()))
    np.testing.assert_allclose(b1, (bowl + extra) * f(1.0), atol=1e-9)
    np.testing.assert_allclose(b3, (bowl + extra) * f(3.2), atol=1e-9)


def test_corner_falloff_only_in_the_corners():
    em = ErrorModel.only("deformation", quantize=False, deform_corner_mm_1m=0.0, deform_centre_mm_1m=0.0,
                         deform_skew_mm_1m=0.0, deform_corner_falloff_mm_1m=9.0, deform_corner_start=0.8,
                         deform_corner_power=2.5, deform_corner_range_gain=0.4, deform_corner_range_power=2.0)
    vk = VirtualKinect(em)
    b1, b2 = ((lambda fr: fr.depth[0] - fr.true_depth)(vk.capture(scenes.wall(d), 1)) for d in (1.0, 2.0))
    H, W = b1.shape
    assert np.all(b1[C] == 0) and b1[0, W // 2] == 0 and b1[H // 2, 0] == 0  # centre and mid-edges untouched
    corner = np.array([b1[0, 0], b1[0, -1], b1[-1, 0], b1[-1, -1]])
    assert np.all(corner > 3.0) and np.all(corner < 20.0)
    xc, yc = em.deform_corner_xy
    s = np.hypot(XY[0, 0, 0] / xc, XY[0, 0, 1] / yc) / math.sqrt(2)
    assert b1[0, 0] == pytest.approx(9.0 * ((s - 0.8) / 0.2) ** 2.5, rel=1e-12)
    np.testing.assert_allclose(b2, b1 * (0.6 + 0.4 * 4.0), atol=1e-12)  # (1 - g) + g Z^2 at 2 m


# ------------------------------------------------------------------ amplitude bias
def test_absolute_amplitude_bias_on_a_white_wall():
    em = ErrorModel.only("amplitude_bias", quantize=False, amp_bias_mm_per_ln=0.0, amp_bias_abs_mm_per_ln=2.0)
    vk = VirtualKinect(em)
    for d in (1.0, 3.0):
        fr = vk.capture(scenes.wall(d), n_frames=1)
        b = fr.depth[0] - fr.true_depth
        np.testing.assert_allclose(b, 2.0 * np.log(12000.0 / fr.amplitude), atol=1e-9)  # relative term off
        # on the axis A = A_white,1m / r^2: 2 k_abs ln(r / 1 m); larger toward the vignetted corners
        assert b[207, 256] == pytest.approx(2 * 2.0 * math.log(d), abs=0.01)
        assert b[0, 0] > b[207, 256] + 1.0


def test_relative_and_absolute_amplitude_bias_add_on_a_grey_board():
    em = ErrorModel.only("amplitude_bias", quantize=False, amp_bias_mm_per_ln=5.0, amp_bias_abs_mm_per_ln=2.5)
    sc = scenes.grey_board(1.0)
    fr = VirtualKinect(em).capture(sc, n_frames=1)
    b = fr.depth[0] - fr.true_depth
    from scipy.ndimage import binary_erosion

    def mean_bias(albedo):
        m = np.zeros(fr.labels.shape, bool)
        for s in sc.info["samples"]:
            if s["albedo"] == albedo:
                m |= binary_erosion(fr.labels == s["label"], iterations=2)
        return b[m].mean()

    d = mean_bias(scenes.GREY_LEVELS[-1]) - mean_bias(scenes.GREY_LEVELS[0])
    assert d == pytest.approx((5.0 + 2.5) * math.log(0.8 / 0.133), abs=0.3)


def test_noise_sigma0_of_a_quiet_sensor():
    em = ErrorModel.only("noise", quantize=False, noise_sigma_mm=0.6)
    fr = VirtualKinect(em, seed=4).capture(scenes.wall(1.0), n_frames=40)
    std = fr.depth[:, C[0], C[1]].std(axis=0, ddof=1).mean()
    assert std == pytest.approx(0.6 * E.noise_sigma_mm(fr.amplitude[C], 1000.0, em).mean() / 0.6, rel=0.06)
    assert 0.55 < std < 0.7
