"""Calibrations with a ray-length term, a support map and a fallback: kernels vs the numpy
definition, the file round trip (versions 1 and 2), counting of extrapolated pixels."""

from __future__ import annotations

import dataclasses
import io
import json

import numpy as np
import pytest

from tofmetry.calibrate import (
    CalibrationSupport, DepthCalibration, FrameCorrector, apply_depth_calibration, apply_depth_calibration_reference,
    count_outside_range, fit_range_curve,
)
from tofmetry.errors import FormatError, InputError
from tofmetry.pipelines import load_calibration, save_calibration


def _ray_cal(intr, fallback="hold", seen_all=True):
    """Range constant, a wiggling ray term (0.45 m period), three surface nodes, a wall-like support."""
    rng = np.random.default_rng(2)
    q = np.linspace(700.0, 4000.0, 400)
    sp = fit_range_curve(q, -6.0 + 3.0 * np.sin(2 * np.pi * q / 450.0) + 1.5 * (q / 1000.0), lam=1e-3)
    h, w = intr.shape
    v, u = np.mgrid[0:h, 0:w]
    z = np.concatenate([np.full(h * w, d) + rng.normal(0, 5, h * w) for d in (900.0, 1800.0, 2700.0)])
    uu, vv = np.tile(u.ravel(), 3), np.tile(v.ravel(), 3)
    if not seen_all:  # a board-like support: the left third of the image never seen
        keep = uu > w // 3
        uu, vv, z = uu[keep], vv[keep], z[keep]
    sup = CalibrationSupport.from_samples(uu, vv, z, intr.shape, cell_px=8)
    surf = rng.normal(0, 2, (3, h, w)).astype(np.float32)
    return DepthCalibration(
        sensor="kinect_v2", intrinsics=intr, range_knots=np.array([800.0, 800.0, 2800.0, 2800.0]),
        range_coeffs=np.array([-2.0, -2.0]), range_degree=1, range_data_mm=np.array([800.0, 2800.0]),
        valid_range_mm=np.array([1.0, 65535.0]), node_mm=np.array([900.0, 1800.0, 2700.0]), surfaces=surf,
        offset_mm=-8.0, ray_knots=sp.t, ray_coeffs=sp.c, ray_gamma=1.0, ray_data_mm=np.array([700.0, 4000.0]),
        support=sup, fallback=fallback, trend_mm=(-7.0, 0.001), prediction={"interpolation": {"rms_mm": {"median": 0.4}}},
    )


def _depth(intr, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.integers(300, 4500, intr.shape).astype(np.uint16)  # far beyond the support on both sides
    d[rng.random(intr.shape) < 0.1] = 0
    return d


def _bound(cal, ref, d):
    """Rounding and interpolation budget of the uint16 kernel [mm], per pixel.

    float32 roundings (each <= 2**-24 of its value, as in test_apply_and_file): ``d - R`` and the
    result, the surface pair ``a``, ``b`` and ``b dh + a``; the table value of ``W`` and the ray
    length ``dh rho`` (an error ``eps q`` in ``q`` moves ``W`` by ``|W'| eps q``); plus the linear
    interpolation of ``W`` between whole mm of ray length, ``h^2/8 max|W''|`` with ``h = 1 mm``.
    """
    t = cal.tables
    dd = d.ravel().astype(np.int64)
    q = t.lut_i[4 * dd + 1] + np.arange(d.size)
    a, b = np.abs(t.coef[2 * q + 1].astype(float)), np.abs(t.coef[2 * q].astype(float))
    qq = np.linspace(cal.ray_data_mm[0], cal.ray_data_mm[1], 20001)
    w = cal.ray_error(qq)
    w1 = np.abs(np.gradient(w, qq)).max()
    w2 = np.abs(np.gradient(np.gradient(w, qq), qq)).max()
    eps = 2.0**-24
    bound = eps * (2 * np.abs(ref.ravel()) + 3 * (a + b * dd) + 2 * np.abs(w).max() + 2 * w1 * 1.5 * dd) + w2 / 8
    return bound.reshape(d.shape)


@pytest.mark.parametrize("fallback", ["hold", "trend", "unchanged"])
def test_kernels_match_the_definition(small_intr, fallback):
    cal = _ray_cal(small_intr, fallback)
    d = _depth(small_intr)
    ref = apply_depth_calibration_reference(d, cal)
    fast = apply_depth_calibration(d, cal).astype(np.float64)
    err = np.abs(fast - ref)
    assert np.all(err <= _bound(cal, ref, d)), err.max()
    # back-projection: the same z, times the rays
    rays = small_intr.ray_table().astype(np.float32)
    pts = FrameCorrector(cal)(d)
    z = fast.ravel()[d.ravel() > 0] * 1e-3
    np.testing.assert_allclose(pts[:, 2], z, atol=1e-6)
    np.testing.assert_allclose(pts[:, 0], rays[..., 0].ravel()[d.ravel() > 0] * z, atol=2e-6)
    # float input: the definition itself
    np.testing.assert_array_equal(apply_depth_calibration(d.astype(float), cal)[d > 0], ref[d > 0])


def test_fallback_semantics(small_intr):
    d = np.full(small_intr.shape, 4400, np.uint16)  # beyond the support's far end (~2700 + noise)
    hold = _ray_cal(small_intr, "hold")
    lo, hi = hold.support_range_mm
    at_hi, _ = hold.correction(np.full(small_intr.shape, hi))
    np.testing.assert_allclose(hold.correction(d)[0], at_hi)  # held at the farthest fitted depth
    trend = _ray_cal(small_intr, "trend")
    np.testing.assert_allclose(trend.correction(d)[0], -7.0 + 0.001 * 4400)
    unchanged = _ray_cal(small_intr, "unchanged")
    assert np.all(unchanged.correction(d)[0] == 0)
    assert count_outside_range(d, hold) == d.size
    inside = np.full(small_intr.shape, 1800, np.uint16)
    assert count_outside_range(inside, hold) == 0


def test_cells_never_seen_are_counted(small_intr):
    """A board-like support: the surfaces continue over cells never seen (as fitted), and those
    pixels count as outside the support."""
    cal = _ray_cal(small_intr, "hold", seen_all=False)
    d = np.full(small_intr.shape, 1800, np.uint16)
    corr, inside = cal.correction(d)
    left = cal.support.hi_mm == 0
    assert left.any() and not inside[left].any() and inside[~left].all()
    assert count_outside_range(d, cal) == int(left.sum())
    fast = apply_depth_calibration(d, cal)
    np.testing.assert_allclose(fast, apply_depth_calibration_reference(d, cal), atol=2e-3)


def test_file_round_trip_v2(tmp_path, small_intr):
    cal = _ray_cal(small_intr, "trend", seen_all=False)
    p = save_calibration(tmp_path / "cal.npz", cal)
    back = load_calibration(p)
    assert back.fallback == "trend" and back.trend_mm == cal.trend_mm and back.prediction == cal.prediction
    np.testing.assert_array_equal(back.ray_coeffs, cal.ray_coeffs)
    np.testing.assert_array_equal(back.support.lo_mm, cal.support.lo_mm)
    d = _depth(small_intr, 3)
    np.testing.assert_array_equal(apply_depth_calibration(d, back), apply_depth_calibration(d, cal))
    with np.load(p, allow_pickle=False) as z:
        assert json.loads(str(z["header"][()]))["version"] == 2


def test_version_1_files_still_read(tmp_path, small_intr):
    """A file written by tofmetry before the support map existed: depths outside its valid range
    are left unchanged, as they were then."""
    cal = _ray_cal(small_intr)
    p = save_calibration(tmp_path / "cal.npz", dataclasses.replace(cal, ray_knots=None, ray_coeffs=None, support=None,
                                                                   fallback="unchanged",
                                                                   valid_range_mm=np.array([800.0, 2800.0])))
    with np.load(p, allow_pickle=False) as z:
        arrays = {k: z[k] for k in ("range_knots", "range_coeffs", "node_mm", "surfaces")}
        h = json.loads(str(z["header"][()]))
    h = {k: v for k, v in h.items() if k not in ("fallback", "trend_mm", "prediction", "ray_gamma", "ray_data_mm")}
    h["version"] = 1
    buf = io.BytesIO()
    np.savez(buf, header=np.array(json.dumps(h)), **arrays)
    (tmp_path / "v1.npz").write_bytes(buf.getvalue())
    v1 = load_calibration(tmp_path / "v1.npz")
    assert v1.support is None and v1.fallback == "unchanged"
    d = _depth(small_intr)
    out = apply_depth_calibration(d, v1)
    far = (d > 2800)
    assert np.all(out[far] == d[far])


def test_bad_model_fields(small_intr):
    cal = _ray_cal(small_intr)
    with pytest.raises(InputError, match="fallback"):
        dataclasses.replace(cal, fallback="extrapolate")
    with pytest.raises(InputError, match="support map"):
        dataclasses.replace(cal, support=None)
    with pytest.raises(InputError, match="together"):
        dataclasses.replace(cal, ray_coeffs=None)


def test_not_a_calibration_is_a_format_error(tmp_path):
    np.save(tmp_path / "x.npy", np.arange(3))
    with pytest.raises(FormatError, match="not a tofmetry calibration"):
        load_calibration(tmp_path / "x.npy")
    obj = io.BytesIO()
    np.savez(obj, header=np.array([{"a": 1}], dtype=object))
    (tmp_path / "o.npz").write_bytes(obj.getvalue())
    with pytest.raises(FormatError):
        load_calibration(tmp_path / "o.npz")


def test_ray_kernel_stores_stay_inside_the_points(small_intr):
    """The ray-term kernel reads (x, y, rho) records (stride 3) and writes with the same 16-byte
    stores: nothing may land past the last point, whatever the split into thread blocks."""
    from tofmetry.calibrate._backproject import _run_kernel

    cal = _ray_cal(small_intr)
    t = cal.tables
    rays = small_intr.ray_table().astype(np.float32).ravel()
    rng = np.random.default_rng(5)
    base = _depth(small_intr, 8)
    for name, d in {"all valid": np.maximum(base, 1), "end only": np.where(np.arange(base.size).reshape(base.shape)
                                                                            == base.size - 1, 1800, 0).astype(np.uint16),
                    "sparse": np.where(rng.random(base.shape) < 0.05, base, 0).astype(np.uint16)}.items():
        n = int(np.count_nonzero(d))
        ref = apply_depth_calibration_reference(d, cal)[d > 0] * 1e-3
        for nthreads in (1, 2, 3):
            guarded = np.full(3 * n + 8, np.nan, np.float32)
            assert _run_kernel(d.ravel(), t, rays, guarded, nthreads) == n, name
            assert np.isnan(guarded[3 * n:]).all(), f"{name}, {nthreads} threads: wrote past the last point"
            np.testing.assert_allclose(guarded[2:3 * n:3], ref, atol=2e-6, err_msg=name)
