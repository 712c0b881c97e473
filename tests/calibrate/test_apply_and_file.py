"""Correction kernels vs the numpy reference; the calibration file round trip and its checks."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from tofmetry.calibrate import (
    DepthCalibration, apply_depth_calibration, apply_depth_calibration_reference, correct_and_backproject,
    count_outside_range, fit_range_curve, load_calibration, save_calibration,
)
from tofmetry.errors import FormatError, SensorMismatchError
from tofmetry.pointcloud import depth_to_points


def _cal(intr, nodes=(900.0, 1500.0, 2400.0), sensor="kinect_v2"):
    rng = np.random.default_rng(1)
    x = np.linspace(850, 2500, 12)
    sp = fit_range_curve(x, -10 + 4 * np.sin(x / 300.0))
    surf = rng.normal(0, 3, (len(nodes), *intr.shape)).astype(np.float32)
    return DepthCalibration(sensor=sensor, intrinsics=intr, range_knots=sp.t, range_coeffs=sp.c, range_degree=sp.k,
                            range_data_mm=np.array([850.0, 2500.0]), valid_range_mm=np.array([800.0, 2550.0]),
                            node_mm=np.array(nodes), surfaces=surf, offset_mm=-10.0, surface_model="test",
                            provenance={"test": True})


def _depth(intr, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.integers(600, 2800, intr.shape).astype(np.uint16)  # includes out-of-range values
    d[rng.random(intr.shape) < 0.1] = 0
    return d


def test_u16_kernel_matches_reference(small_intr):
    cal = _cal(small_intr)
    d = _depth(small_intr)
    fast = apply_depth_calibration(d, cal)
    ref = apply_depth_calibration_reference(d, cal)
    assert fast.dtype == np.float32
    # float32 arithmetic on values ~3000 mm: relative 6e-8 -> < 1e-3 mm
    np.testing.assert_allclose(fast, ref, atol=2e-3)
    assert np.all(fast[d == 0] == 0)
    lo, hi = cal.valid_range_mm
    out = (d > 0) & ((d < lo) | (d > hi))
    assert out.any() and np.all(fast[out] == d[out])  # outside the range: unchanged
    assert count_outside_range(d, cal) == int(out.sum())


def test_float_kernel_matches_reference(small_intr):
    cal = _cal(small_intr)
    rng = np.random.default_rng(3)
    d = rng.uniform(600, 2800, small_intr.shape)
    d[:3] = np.nan
    d[3:5] = 0.0
    fast = apply_depth_calibration(d, cal)
    ref = apply_depth_calibration_reference(np.nan_to_num(d), cal)
    fin = np.isfinite(d)
    # the float path interpolates the range table linearly between integer mm: error
    # < R'' / 8 mm^2 ~ 4/300^2/8 = 6e-6 mm
    np.testing.assert_allclose(fast[fin], ref[fin], atol=1e-4)
    assert np.isnan(fast[:3]).all() and np.all(fast[3:5] == 0)


def test_correct_and_backproject(small_intr):
    cal = _cal(small_intr)
    d = _depth(small_intr, 5)
    pts = correct_and_backproject(d, cal, small_intr.ray_table().astype(np.float32))
    ref = depth_to_points(apply_depth_calibration_reference(d, cal), small_intr, min_mm=1, max_mm=65535)
    assert pts.dtype == np.float32 and pts.shape == ref.shape
    np.testing.assert_allclose(pts, ref, atol=2e-6)  # float32 [m]: ~1e-7 relative


def test_file_round_trip(tmp_path, small_intr):
    cal = _cal(small_intr)
    p = save_calibration(tmp_path / "cal.npz", cal)
    back = load_calibration(p, sensor="kinect_v2", shape=small_intr.shape)
    assert back.intrinsics == cal.intrinsics and back.sensor == cal.sensor
    np.testing.assert_array_equal(back.surfaces, cal.surfaces)
    np.testing.assert_array_equal(back.range_coeffs, cal.range_coeffs)
    assert back.provenance["test"] is True and back.offset_mm == cal.offset_mm
    d = _depth(small_intr)
    np.testing.assert_array_equal(apply_depth_calibration(d, back), apply_depth_calibration(d, cal))
    # no pickle inside
    with np.load(p, allow_pickle=False) as z:
        assert set(z.files) == {"header", "range_knots", "range_coeffs", "node_mm", "surfaces"}


def test_file_mismatches(tmp_path, small_intr):
    cal = _cal(small_intr)
    p = save_calibration(tmp_path / "cal.npz", cal)
    with pytest.raises(SensorMismatchError, match="96"):
        load_calibration(p, shape=(424, 512))
    with pytest.raises(SensorMismatchError, match="azure"):
        load_calibration(p, sensor="azure_kinect")
    with pytest.raises(SensorMismatchError):
        apply_depth_calibration(np.zeros((10, 10), np.uint16), cal)
    # a future version
    with np.load(p, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    h = json.loads(str(arrays["header"][()]))
    h["version"] = 99
    arrays["header"] = np.array(json.dumps(h))
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    (tmp_path / "v99.npz").write_bytes(buf.getvalue())
    with pytest.raises(FormatError, match="version 99"):
        load_calibration(tmp_path / "v99.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(FormatError, match="junk"):
        load_calibration(tmp_path / "junk.npz")
