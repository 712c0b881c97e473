"""Depth calibration fit on analytic truth -> recover at distances never fitted.

The truths here are written for these tests (``conftest.py``), not taken from the simulator:
a range error in Z (1.5 m wiggle), a range error of the ray length (a 0.6 m wiggle and its
harmonic, which 300 mm station spacing cannot resolve on the optical axis alone), an off-centre
quartic deformation with a tilt-like term growing with range. No noise: what is left is model
error, so the budgets below are a fraction of a millimetre.
"""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.calibrate import (
    DepthFitConfig, DepthSample, JointSpec, StudyFitConfig, SurfaceSpec, apply_depth_calibration, fit_any,
    fit_depth_model, fit_surface, wall_reference, wall_sample,
)
from tofmetry.errors import EstimationError, InputError

from .conftest import render_wall, render_wall_ray

TRAIN = list(range(800, 3201, 200))
HELD = [900, 1500, 2100, 2700]


def _samples(intr, render, normals=None, frontal=True):
    out = []
    for i, d in enumerate(TRAIN):
        n = None if normals is None else normals[i % len(normals)]
        out.append(wall_sample(render(intr, d, n), d, intr, name=f"d{d}", frontal=frontal)[0])
    return out


def _detilt(e, z, rays):
    """Error with a tilt about the optical axis removed (``z x``, ``z y`` least squares)."""
    ok = np.isfinite(e)
    A = np.stack([(z * rays[..., 0])[ok], (z * rays[..., 1])[ok]], 1)
    c, *_ = np.linalg.lstsq(A, e[ok], rcond=None)
    return e - z * (rays[..., 0] * c[0] + rays[..., 1] * c[1])


@pytest.fixture(scope="module")
def ray_fit(small_intr):
    return fit_depth_model(_samples(small_intr, render_wall_ray, frontal=False), small_intr, sensor="test")


def test_ray_length_error_recovered_between_stations(small_intr, ray_fit):
    """The range error is a function of the ray length: one station samples it over 1-1.2 times
    its distance across the image, so all stations together sample it far more densely than
    their 300 mm spacing, and a 600 mm wiggle is recovered at distances never fitted."""
    cal = ray_fit.calibration
    assert cal.ray_knots is not None and ray_fit.spec.variable == "radial" and ray_fit.spec.gamma == 1.0
    rays = small_intr.ray_table()
    study = fit_any(_samples(small_intr, render_wall_ray, frontal=False), small_intr, StudyFitConfig()).calibration
    for d in HELD:
        z = wall_reference(small_intr, d)
        m = render_wall_ray(small_intr, d)
        after = _detilt(apply_depth_calibration(m, cal) - z, z, rays)
        before = _detilt(m - z - (m - z)[46:50, 62:66].mean(), z, rays)
        # model error only: cubic P-spline of the wiggle (40 mm knots on a 300 mm harmonic:
        # (h/L)^4 ~ 3e-4 of its 0.8 mm) and tensor-spline surfaces of a smooth quartic; the tilt-
        # like part of the deformation is not calibrated (a wall tilt), hence the detilt
        assert np.sqrt(np.mean(after ** 2)) < 0.25, d
        assert np.sqrt(np.mean(after ** 2)) < np.sqrt(np.mean(before ** 2)) / 4, d
        assert abs(after[43:53, 59:69].mean()) < 0.25, d
        old = _detilt(apply_depth_calibration(m, study) - z, z, rays)
        assert np.sqrt(np.mean(old ** 2)) > 2 * np.sqrt(np.mean(after ** 2)), d  # the study's method misses it


def test_z_error_chooses_a_z_model(small_intr):
    """A range error that is a function of Z (the simulator's default form): chosen as such."""
    res = fit_depth_model(_samples(small_intr, render_wall), small_intr)
    assert res.spec.variable == "z" or res.spec.gamma == 0.0, res.spec.label
    for d in HELD:
        z = np.full(small_intr.shape, float(d))
        after = apply_depth_calibration(render_wall(small_intr, d), res.calibration) - z
        # stations 300 mm apart on a 1.5 m wiggle: cubic interpolation error (h/L)^4 x 3 mm
        # ~ 5e-3 x 3 mm, plus the surfaces; the frontal walls let the tilt-like term be fitted
        assert np.sqrt(np.mean(after ** 2)) < 0.3, d


def test_prediction_support_and_fallback_recorded(small_intr, ray_fit):
    cal = ray_fit.calibration
    pred = cal.prediction
    interp = pred["interpolation"]
    assert interp["rms_mm"]["n"] == len(TRAIN) - 2  # every interior station left out once
    for key in ("central_abs_mm", "rms_mm", "rms_systematic_mm", "p95_mm"):
        v = interp[key]
        assert v["p5"] <= v["median"] <= v["p95"], key
    assert {r["fallback"] for r in pred["extrapolation"]} == {"hold", "trend"}
    assert cal.fallback in ("hold", "trend") and pred["fallback_chosen"] == cal.fallback
    assert pred["tilt_calibrated"] is False  # free wall tilts: a tilt-like deformation is not calibrated
    lo, hi = cal.support.range_mm
    # the support is the span of the measured depths (0.1 mm: float32 storage)
    meas = [render_wall_ray(small_intr, d) for d in (TRAIN[0], TRAIN[-1])]
    assert lo == pytest.approx(meas[0].min(), abs=0.1) and hi == pytest.approx(meas[1].max(), abs=0.1)
    assert cal.support.covered_fraction == 1.0
    # the offset is the mean correction on the optical axis over the fitted range: the truth's
    # error at the principal point there (ray term + deformation); 0.3 mm: the 0.1-0.2 mm model
    # error plus measured vs true depth as the abscissa
    from .conftest import deformation_mm, ray_error_mm

    v, u = int(round(small_intr.cy)), int(round(small_intr.cx))
    zz = np.linspace(lo, hi, 200)
    truth = [ray_error_mm(small_intr, np.full(small_intr.shape, z))[v, u] + deformation_mm(small_intr, z)[v, u]
             for z in zz]
    assert cal.offset_mm == pytest.approx(np.mean(truth), abs=0.3)


def test_outside_the_support_falls_back_and_is_counted(small_intr, ray_fit):
    from tofmetry.calibrate import count_outside_range

    cal = ray_fit.calibration
    d = np.full(small_intr.shape, 4500, np.uint16)
    assert count_outside_range(d, cal) == d.size
    corr, inside = cal.correction(d)
    assert not inside.any()
    lo, hi = cal.support_range_mm
    if cal.fallback == "hold":  # evaluated at the farthest fitted depth: no extrapolated curve
        ref, _ = cal.correction(np.full(small_intr.shape, hi))
        np.testing.assert_allclose(corr, ref)
    else:
        a, b = cal.trend_mm
        np.testing.assert_allclose(corr, a + b * 4500.0)


def test_tilted_walls_absorbed(small_intr):
    t = np.deg2rad(3.0)
    normals = [np.array([np.sin(t), 0, np.cos(t)]), np.array([0, -np.sin(t), np.cos(t)]), np.array([0, 0, 1.0])]
    res = fit_depth_model(_samples(small_intr, render_wall_ray, normals, frontal=False), small_intr)
    rays = small_intr.ray_table()
    for d in HELD:
        ref = wall_reference(small_intr, d, normals[0])
        after = _detilt(apply_depth_calibration(render_wall_ray(small_intr, d, normals[0]), res.calibration) - ref,
                        ref, rays)
        assert np.sqrt(np.mean(after ** 2)) < 0.3, d
        assert abs(after[43:53, 59:69].mean()) < 0.3, d


def test_partial_coverage_samples(small_intr):
    """Board-like samples with a known reference plane (no free tilt), each covering a different
    part of the image; cells never covered get no surface term (range terms only)."""
    rng = np.random.default_rng(0)
    h, w = small_intr.shape
    v, u = np.mgrid[0:h, 0:w]
    samples = []
    for d in TRAIN:
        for _ in range(3):
            u0, v0 = rng.integers(0, w - 60), rng.integers(0, h - 45)
            mask = (u >= u0) & (u < u0 + 60) & (v >= v0) & (v < v0 + 45)
            samples.append(DepthSample(render_wall_ray(small_intr, d), np.where(mask, float(d), np.nan),
                                       name=f"{d}-{u0}-{v0}"))
    res = fit_depth_model(samples, small_intr)
    cal = res.calibration
    assert 0.5 < cal.support.covered_fraction <= 1.0
    m = render_wall_ray(small_intr, 2150)
    seen = cal.support.hi_mm > 0
    before = np.sqrt(np.mean((m - 2150)[seen] ** 2))
    after = np.sqrt(np.mean((apply_depth_calibration(m, cal) - 2150)[seen] ** 2))
    assert after < before / 4


def test_fixed_spec_and_errors(small_intr):
    s = _samples(small_intr, render_wall_ray)
    res = fit_depth_model(s, small_intr, DepthFitConfig(spec=JointSpec(n_nodes=2), predict=False))
    assert res.tried == [] and res.prediction == {} and len(res.calibration.node_mm) == 2
    with pytest.raises(InputError, match="at least 2"):
        fit_depth_model(s[:1], small_intr)
    bad = DepthSample(np.full((10, 10), 1000.0), np.full((10, 10), 1000.0), name="tiny")
    with pytest.raises(InputError, match="tiny"):
        fit_depth_model([bad, bad], small_intr)
    with pytest.raises(InputError, match="fallback"):
        DepthFitConfig(fallback="linear")


def test_surface_fit_handles_masks(small_intr):
    """The study baseline's surface fit (tensor spline / polynomial) on masked data."""
    h, w = small_intr.shape
    v, u = np.mgrid[0:h, 0:w]
    truth = 1e-3 * ((u - 64.0) ** 2 - (v - 48.0) ** 2)
    wts = ((u < 90) & (v > 20)).astype(float)
    for spec in (SurfaceSpec("spline", block=2), SurfaceSpec("poly", degree=2, block=2)):
        s = fit_surface(np.where(wts > 0, truth, 1e3), wts, spec, 64.0, 48.0)
        assert np.abs(s - truth)[wts > 0].max() < 0.05, spec.model


def test_cross_validation_compares_methods(small_intr):
    from tofmetry.calibrate import METHODS, cross_validate, summarize

    dists = list(range(800, 2401, 200))
    samples = [wall_sample(render_wall_ray(small_intr, d), d, small_intr, name=f"d{d}", frontal=False)[0]
               for d in dists]
    ours = cross_validate(samples, dists, small_intr, METHODS["tofmetry"](), frontal=False)
    study = cross_validate(samples, dists, small_intr, METHODS["study"](), frontal=False)
    assert [r.name for r in ours] == [f"d{d}" for d in dists[1:-1]]
    # A held-out station z needs the ray lengths z .. 1.35 z; its neighbours z -+ 200 cover them
    # without a gap only when 1.35 (z - 200) >= z + 200, i.e. z >= 1343 mm; from 1600 mm the gap
    # edge is more than the wiggle's harmonic half-period away. There the wiggle is interpolated
    # (0.3 mm budget); nearer, the leave-one-out gap is bridged by the roughness
    # penalty only (1.5 mm budget: the wiggle's 2.5 mm amplitude over a 100-300 mm gap).
    far = [r for r in ours if r.distance_mm >= 1600]
    assert far and max(abs(r.dev_after_mm) for r in far) < 0.3
    assert summarize(ours)["max_abs_dev_after_mm"] < 1.5
    # the study's range spline through stations 200 mm apart cannot follow a 600 mm wiggle
    far_study = [r for r in study if r.distance_mm >= 1600]
    assert max(abs(r.dev_after_mm) for r in far_study) > 2 * max(abs(r.dev_after_mm) for r in far)


def test_a_sample_without_usable_cells_is_left_out_with_its_reason(small_intr):
    """A station whose pixels all drop out in some frames (beyond the sensor's range) gets weight 0
    everywhere: it is left out of the fit and named, the others are fitted."""
    s = _samples(small_intr, render_wall_ray)
    dead = DepthSample(s[-1].measured_mm, s[-1].reference_mm, np.zeros(small_intr.shape), name="dead", free_tilt=True)
    res = fit_depth_model(s[:-1] + [dead], small_intr, DepthFitConfig(spec=JointSpec(), predict=False))
    assert [n for n, _ in res.skipped] == ["dead"] and "usable image cells" in res.skipped[0][1]
    assert "dead" not in [r["name"] for r in res.samples]
    assert res.calibration.diagnostics["skipped_samples"][0][0] == "dead"
    with pytest.raises(EstimationError, match="fewer than 2 usable"):
        fit_depth_model([s[0], dead], small_intr, DepthFitConfig(spec=JointSpec(), predict=False))
