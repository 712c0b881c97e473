"""Correction kernels vs the numpy reference; the calibration file round trip and its checks."""

from __future__ import annotations

import dataclasses
import io
import json

import numba
import numpy as np
import pytest

from tofmetry.calibrate import (
    DepthCalibration,
    apply_depth_calibration,
    apply_depth_calibration_reference,
    correct_and_backproject,
    count_outside_range,
    fit_range_curve,
)
from tofmetry.pipelines import load_calibration, save_calibration
from tofmetry.calibrate._backproject import FrameCorrector, _run_kernel
from tofmetry.errors import FormatError, InputError, SensorMismatchError
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


def _numpy_points(d, cal, rays):
    """The straightforward numpy pipeline: reference correction, float32 metres, ray scaling."""
    z = apply_depth_calibration_reference(d, cal).astype(np.float32).ravel() * np.float32(1e-3)
    ok = d.ravel() != 0
    r = rays.reshape(-1, 2)[ok]
    return np.column_stack([r[:, 0] * z[ok], r[:, 1] * z[ok], z[ok]])


def test_linear_form_precision_on_steep_surfaces(small_intr):
    """The per-interval linear form a + b d in float32 stays within float32 rounding of the reference.

    Steep, large surfaces (+-40 mm, nodes 150 mm apart: slopes |b| up to ~0.5, |a| up to ~700 mm)
    are the worst case for rounding a and b. Each float32 rounding errs by <= 2**-24 of its value;
    the tables round d - R, a and b, the kernel rounds b*d + a (one FMA) and the final difference,
    so the error is below 2**-24 (2 |z| + 3 (|a| + |b| d)) -- and must stay < 1e-3 mm (the
    precision required of the fast path).
    """
    rng = np.random.default_rng(7)
    nodes = (900.0, 1050.0, 1200.0, 1350.0)
    cal = _cal(small_intr, nodes=nodes)
    cal = dataclasses.replace(cal, surfaces=rng.uniform(-40, 40, (4, *small_intr.shape)))
    d = _depth(small_intr, 11)
    fast = apply_depth_calibration(d, cal).astype(np.float64)
    ref = apply_depth_calibration_reference(d, cal)
    t = cal.tables
    q = t.lut_i[4 * d.ravel().astype(np.int64) + 1] + np.arange(d.size)
    b, a = t.coef[2 * q].astype(np.float64), t.coef[2 * q + 1].astype(np.float64)
    # roundings: d - R(d) and the result (each |result| + |S|), a and b, then b d + a (FMA)
    bound = 2.0**-24 * (2 * np.abs(ref.ravel()) + 3 * (np.abs(a) + np.abs(b) * d.ravel()))
    err = np.abs(fast - ref).ravel()
    assert np.all(err <= bound + 1e-12)
    assert err.max() < 1e-3 and bound.max() < 1e-3


@pytest.mark.parametrize("nodes", [(1500.0,), (900.0, 1500.0, 2400.0)])
def test_frame_corrector_matches_numpy(small_intr, nodes):
    cal = _cal(small_intr, nodes=nodes)
    rays = small_intr.ray_table().astype(np.float32)
    ref = _numpy_points(_depth(small_intr, 5), cal, rays)
    fc = FrameCorrector(cal)  # default rays: the calibration's intrinsics
    pts = fc(_depth(small_intr, 5))
    assert pts.dtype == np.float32 and pts.shape == ref.shape
    assert np.shares_memory(pts, fc.buffer)  # streaming: no allocation per frame
    # same float32 operations up to the order of two roundings of z: 2 ulp of 2.8 m = 5e-7 m
    np.testing.assert_allclose(pts, ref, rtol=0, atol=5e-7)
    np.testing.assert_array_equal(pts, correct_and_backproject(_depth(small_intr, 5), cal, rays))
    # a non-contiguous frame and an external buffer
    big = np.zeros((small_intr.height, 2 * small_intr.width), np.uint16)
    big[:, ::2] = _depth(small_intr, 5)
    ext = np.empty((small_intr.width * small_intr.height, 3), np.float32)
    np.testing.assert_array_equal(fc(big[:, ::2], out=ext), pts)
    with pytest.raises(InputError, match="uint16"):
        fc(_depth(small_intr).astype(np.float32))
    with pytest.raises(InputError, match="uint16"):
        fc(np.zeros((10, 10), np.uint16))
    with pytest.raises(InputError, match="out"):
        fc(_depth(small_intr), out=np.empty((10, 3), np.float32))


def test_backproject_blocks_and_buffers(small_intr):
    """The kernel splits the pixels in one block per thread: any split gives the same points."""
    cal = _cal(small_intr)
    rays = small_intr.ray_table().astype(np.float32)
    d = _depth(small_intr, 9)
    d.ravel()[[0, 6143, 6144, 6365, 6366, 6367, d.size - 1]] = 0  # invalid pixels at and near block edges
    ref = correct_and_backproject(d, cal, rays)
    t = cal.tables
    for nthreads in (1, 2, 3, 7, 10**9):  # 12288 pixels: 1, 2, 3, 4, 4 blocks
        out = np.full((d.size, 3), np.nan, np.float32)
        n = _run_kernel(d.ravel(), t, rays.ravel(), out.reshape(-1), nthreads)
        assert n == len(ref)
        np.testing.assert_array_equal(out[:n], ref)
        assert np.isnan(out[n:]).all()  # nothing written past the N points
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        np.testing.assert_array_equal(correct_and_backproject(d, cal, rays), ref)
    finally:
        numba.set_num_threads(old)
    # an exactly sized buffer (counting path), a too small one, no valid pixel, all valid
    n = len(ref)
    exact = np.empty((n, 3), np.float32)
    np.testing.assert_array_equal(correct_and_backproject(d, cal, rays, out=exact), ref)
    with pytest.raises(InputError, match=f">= {n}"):
        correct_and_backproject(d, cal, rays, out=np.empty((n - 1, 3), np.float32))
    with pytest.raises(InputError, match="float32"):
        correct_and_backproject(d, cal, rays, out=np.empty((d.size, 3), np.float64))
    assert correct_and_backproject(np.zeros_like(d), cal, rays).shape == (0, 3)
    full = np.full_like(d, 1234)
    assert correct_and_backproject(full, cal, rays).shape == (d.size, 3)


def test_backproject_stores_stay_inside_the_points(small_intr):
    """Points are written with 16-byte stores whose 4th lane is scratch: it must never land
    past the last point of a thread's block (another thread's points) or of the buffer; and
    depth jittering around a node switches the coefficient plane from pixel to pixel."""
    cal = _cal(small_intr)  # nodes at 900, 1500, 2400 mm
    rays = small_intr.ray_table().astype(np.float32)
    t = cal.tables
    rng = np.random.default_rng(4)
    base = np.maximum(_depth(small_intr, 3), 1)
    size, shape = base.size, base.shape

    def keep(mask):
        return np.where(mask.reshape(shape), base, 0).astype(np.uint16)

    jitter = np.where(rng.random(size) < 0.5, 1499, 1501).astype(np.uint16)  # a new plane at every other pixel
    jitter_some = np.where(np.arange(size) % 512 < 20, jitter, 1700)
    patterns = {"one valid pixel at the end": keep(np.arange(size) == size - 1),
                "one valid pixel at the start": keep(np.arange(size) == 0),
                "all valid": base, "1 % valid": keep(rng.random(size) < 0.01),
                "valid runs": keep(np.repeat(rng.random(size // 64) < 0.5, 64)),
                "jitter at a node": jitter.reshape(shape),
                "jitter in the first pixels of each row": jitter_some.reshape(shape).astype(np.uint16),
                "jitter with holes": np.where(rng.random(shape) < 0.2, 0, jitter.reshape(shape)).astype(np.uint16)}
    for name, d in patterns.items():
        n = int(np.count_nonzero(d))
        z = apply_depth_calibration_reference(d, cal)[d > 0] * 1e-3
        expect = np.column_stack([rays[d > 0] * z[:, None], z])
        for nthreads in (1, 2, 3, 4):
            guarded = np.full(3 * n + 8, np.nan, np.float32)  # exactly N points, then a guard zone
            got = _run_kernel(d.ravel(), t, rays.ravel(), guarded, nthreads)
            assert got == n, name
            assert np.isnan(guarded[3 * n:]).all(), f"{name}, {nthreads} threads: wrote past the last point"
            # float32 correction (< 2e-3 mm, see above) and float32 products: 1e-6 m
            np.testing.assert_allclose(guarded[:3 * n].reshape(n, 3), expect, atol=1e-6, err_msg=name)
            if nthreads == 1:
                first = guarded[:3 * n].copy()
            else:  # the same float32 operations whatever the split
                np.testing.assert_array_equal(guarded[:3 * n], first, err_msg=name)


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
