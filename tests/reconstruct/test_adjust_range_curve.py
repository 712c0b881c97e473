"""Global adjustment with a range-error curve shared by all views, on analytic clouds seen from
different ranges (the views observe the curve because each sees the object over its own depth span)."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.reconstruct import global_adjust
from tofmetry.reconstruct._range_curve import (
    apply_range_curve,
    range_basis,
    range_curve_m,
    range_curve_sigma_m,
)

from .test_adjust import _errors, _look_at, _perturb, _visible

Z_REF, HALF = 1.0, 0.35  # [m]: the views' depths span 0.65 .. 1.35 m
TRUE_C = np.array([1.5e-3, -1.0e-3])  # Legendre terms 2, 3 [m]: up to ~2.5 mm at the ends of the span


@pytest.fixture(scope="module")
def ring_ranges():
    """8 views round an ellipsoid on a disc, at 0.8 and 1.2 m alternately, 30 deg above the disc."""
    target = np.array([0.0, 0.0, 0.08])
    poses = []
    for k in range(8):
        a = 2 * np.pi * k / 8
        d = 0.8 if k % 2 == 0 else 1.2
        c = target + d * np.array([np.cos(a) * np.cos(np.radians(30)), np.sin(a) * np.cos(np.radians(30)),
                                   np.sin(np.radians(30))])
        poses.append(_look_at(c, target))
    return poses


def _views(poses, coeffs, rng, n=20000):
    """Each view's own samples of its visible surface, camera frame, depth distorted so that the
    correction ``z + dz(z)`` (measured z) restores it."""
    from tofmetry.reconstruct import AdjustView
    out = []
    for T in poses:
        pc, nc = _visible(T, rng, n)
        zt = pc[:, 2]
        zm = zt.copy()
        for _ in range(20):  # solve zm + dz(zm) = zt (dz is a few mm: a contraction)
            zm = zt - range_curve_m(zm, coeffs, Z_REF, HALF)
        pm = pc * (zm / zt)[:, None]
        out.append(AdjustView(pm[::4], nc[::4], pm, nc))
    return out


def test_basis_is_zero_at_z_ref_orthogonal_to_the_gain_and_flat_beyond_the_span():
    z = np.array([Z_REF, Z_REF + HALF, Z_REF + 2 * HALF])
    B = range_basis(z, Z_REF, HALF, 4)
    assert B.shape == (3, 3)
    np.testing.assert_allclose(B[0], 0.0, atol=1e-15)
    np.testing.assert_allclose(B[1], B[2])
    u = np.linspace(-1, 1, 20001)
    Bu = range_basis(Z_REF + HALF * u, Z_REF, HALF, 4)
    np.testing.assert_allclose(np.trapezoid(Bu * u[:, None], u, axis=0), 0.0, atol=1e-6)  # no linear part (the gain's; trapezoid error ~1e-8)
    p = np.array([[0.1, -0.2, 1.2], [0.0, 0.0, 0.8]])
    q = apply_range_curve(p, TRUE_C, Z_REF, HALF)
    np.testing.assert_allclose(q[:, 2] - p[:, 2], range_curve_m(p[:, 2], TRUE_C, Z_REF, HALF))
    np.testing.assert_allclose(np.cross(q, p), 0.0, atol=1e-15)  # along the rays


def test_recovers_the_range_curve_and_the_poses(ring_ranges):
    """Noise-free views at 0.8 and 1.2 m with a smooth range error (Legendre terms 2 and 3, up to
    2.5 mm over 0.65-1.35 m), poses started 0.3 deg / 2 mm off. With the curve the adjustment
    must find it within 3 of its reported standard errors (sampling of the curved surface is
    the only error: ~0.1 mm RMS residuals) and the poses within 0.06 deg / 1 mm, the limits of
    ``test_adjust``; with the gain alone the poses absorb the curve (guards against passing for
    the wrong reason). Measured: 1.5005 / -0.9966 mm (+-0.002 / 0.0015 mm), poses 0.018 deg /
    0.35 mm; gain alone 0.30 deg / 6.1 mm."""
    rng = np.random.default_rng(1)
    views = _views(ring_ranges, TRUE_C, rng)
    init = np.stack([ring_ranges[0]] + [_perturb(T, rng, 0.3, 2.0) for T in ring_ranges[1:]])
    kw = {"iters_per_radius": (2, 6), "curve_half_span_m": HALF, "curve_prior_m": 3e-3}
    with_curve = global_adjust(views, init, Z_REF, curve_degree=3, **kw)
    gain_only = global_adjust(views, init, Z_REF, curve_degree=0, **kw)
    assert with_curve.range_curve_estimated, with_curve.range_curve_note
    c, s = with_curve.range_curve_m, with_curve.range_curve_sigma_m
    assert np.all(s > 0) and np.all(s < 5e-4), s  # determined, far better than the 3 mm prior
    assert np.all(np.abs(c - TRUE_C) < 3 * s + 5e-5), (c, s)
    z = np.linspace(Z_REF - HALF, Z_REF + HALF, 9)
    dz_err = range_curve_m(z, c, Z_REF, HALF) + with_curve.depth_gain * (z - Z_REF) - range_curve_m(z, TRUE_C, Z_REF, HALF)
    assert np.all(np.abs(dz_err) < 3 * range_curve_sigma_m(z, with_curve.range_curve_cov_m2, Z_REF, HALF) + 1e-4), dz_err
    e_curve, e_gain = _errors(with_curve.poses, ring_ranges), _errors(gain_only.poses, ring_ranges)
    assert e_curve[:, 0].max() < 0.06 and e_curve[:, 1].max() < 1.0, e_curve
    assert e_gain[:, 1].max() > 2 * e_curve[:, 1].max(), (e_gain, e_curve)
    rep = with_curve.to_dict()["range_curve"]
    assert rep["estimated"] and len(rep["dz_mm"]) == len(rep["dz_sigma_mm"]) == 5
    assert gain_only.to_dict()["range_curve"] is None


def test_curve_not_estimated_when_views_do_not_observe_it(ring_ranges):
    """A prior far tighter than what the views can tell (1 um): the curve stays 0 and the note says why."""
    rng = np.random.default_rng(2)
    views = _views(ring_ranges[:3], np.zeros(2), rng, n=8000)
    res = global_adjust(views, np.stack(ring_ranges[:3]), Z_REF, iters_per_radius=(1, 2), curve_degree=3,
                        curve_prior_m=1e-6, curve_half_span_m=HALF)
    assert not res.range_curve_estimated and res.range_curve_note.startswith("not observable")
    np.testing.assert_array_equal(res.range_curve_m, 0.0)


def test_only_the_determined_low_terms_are_kept():
    """A design whose third curve term nearly repeats the first (two wiggle terms the views cannot
    tell apart, as over a shallow object): with all three in the fit neither of the pair is
    determined; with the third left out the first two are, to the precision of the reduced fit,
    which is what :func:`determined_terms` must return. When even the lowest term alone is not
    determined it keeps none."""
    from tofmetry.reconstruct._adjust_sigma import curve_sigmas, determined_terms

    rng = np.random.default_rng(3)
    n = 400
    J = rng.normal(size=(n, 6 + 3 + 1))  # 6 pose unknowns, 3 curve terms, the gain
    J[:, 8] = J[:, 6] + 1e-3 * rng.normal(size=n)  # term 3 ~ term 1
    H = J.T @ J
    full = curve_sigmas(H, 1.0, 1.0, 3, False)
    k, sd = determined_terms(H, 1.0, 1.0, 3, 0, 6, False, prior_m=0.2)
    keep = np.r_[0:8, 9]
    assert full[0] > 1.0 and full[2] > 1.0 and full[1] < 0.1, full  # the pair is undetermined together
    assert k == 2, (k, sd)
    np.testing.assert_allclose(sd, curve_sigmas(H[np.ix_(keep, keep)], 1.0, 1.0, 2, False))
    assert np.all(sd < 0.2)
    assert determined_terms(H, 1.0, 1.0, 3, 0, 6, False, prior_m=1e-6) == (0, None)


def test_the_curves_degree_follows_the_spread_of_the_views_distances():
    """Views at one distance (a turntable, the object on its axis) keep the base degree; a loop
    whose distances to the object vary by more than ``range_varied_min`` gets
    ``range_curve_degree_varied``; the reason names the spread either way."""
    from types import SimpleNamespace

    from tofmetry.reconstruct._adjust_stage import curve_degree_for, view_distance_spread
    from tofmetry.reconstruct._config import ReconstructionConfig

    world = np.random.default_rng(3).normal(0.0, 0.05, (500, 3))
    world -= world.mean(axis=0)  # the object round the origin [m]

    def views(distances):
        poses = [_look_at(d * np.array([np.cos(a), np.sin(a), 0.3]) / np.hypot(1.0, 0.3), np.zeros(3))
                 for a, d in zip(np.linspace(0, 2 * np.pi, len(distances), endpoint=False), distances)]
        regs = [SimpleNamespace(obj_points=world @ T[:3, :3] - T[:3, 3] @ T[:3, :3]) for T in poses]
        return regs, np.array(poses)

    cfg = ReconstructionConfig()
    flat = view_distance_spread(*views([1.0] * 8))
    assert flat < 1e-9
    degree, why = curve_degree_for(flat, cfg)
    assert degree == cfg.registration.range_curve_degree and "vary by 0.0 % only" in why
    varied = view_distance_spread(*views([0.9, 1.1] * 4))
    assert varied == pytest.approx(0.1, rel=1e-6)  # std 0.1 m over a median of 1.0 m
    degree, why = curve_degree_for(varied, cfg)
    assert degree == cfg.registration.range_curve_degree_varied and "10.0 %" in why
    assert curve_degree_for(float("nan"), cfg)[0] == cfg.registration.range_curve_degree
    off = ReconstructionConfig.model_validate({"registration": {"range_curve_degree": 0}})
    assert curve_degree_for(0.07, off) == (0, "")
