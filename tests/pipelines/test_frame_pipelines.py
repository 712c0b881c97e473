"""The frame pipelines (correct, cloud, filter) and the one frame path they share."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from tofmetry.calibrate import DepthCalibration, apply_depth_calibration
from tofmetry.errors import InputError
from tofmetry.io import Capture, CaptureMeta, read_ply, write_capture
from tofmetry.pipelines import save_calibration
from tofmetry.pipelines.cloud import capture_cloud
from tofmetry.pipelines.correct import correct_capture
from tofmetry.pipelines.flying import filter_capture
from tofmetry.pipelines.frame_path import FramePath, identity_calibration
from tofmetry.pipelines.frame_stream import stream_frames
from tofmetry.pointcloud import depth_to_points, robust_mean_depth
from tofmetry.sensor import CameraIntrinsics

INTR = CameraIntrinsics(64, 48, 50.0, 50.0, 31.7, 23.4, (0.1, -0.2, 0.001, -0.002, 0.05))


def _calibration(intr: CameraIntrinsics = INTR) -> DepthCalibration:
    """A calibration with a curved range error and per-pixel surfaces (no fit needed)."""
    h, w = intr.shape
    v, u = np.mgrid[0:h, 0:w]
    bowl = ((u - w / 2) / w) ** 2 + ((v - h / 2) / h) ** 2
    nodes = np.array([800.0, 1500.0, 2500.0])
    surf = np.stack([(k + 1) * 4.0 * bowl - 1.0 for k in range(len(nodes))]).astype(np.float32)
    knots = np.r_[[500.0] * 4, 1500.0, 2500.0, [4000.0] * 4]
    return DepthCalibration(sensor="unknown", intrinsics=intr, range_knots=knots,
                            range_coeffs=np.array([5.0, -3.0, 4.0, -2.0, 6.0, -1.0]), range_degree=3,
                            range_data_mm=np.array([800.0, 3000.0]), valid_range_mm=np.array([500.0, 4000.0]),
                            node_mm=nodes, surfaces=surf, offset_mm=0.0)


def _frames(n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    h, w = INTR.shape
    base = 900 + 1800 * np.arange(w)[None, :] / w + np.zeros((h, 1))
    out = []
    for _ in range(n):
        d = np.rint(base + rng.normal(0, 2, (h, w)))
        d[rng.random((h, w)) < 0.05] = 0
        out.append(d.astype(np.uint16))
    return out


@pytest.fixture
def capture(tmp_path):
    rng = np.random.default_rng(1)
    frames = _frames(6)
    irs = [rng.integers(100, 4000, INTR.shape).astype(np.uint16) for _ in frames]
    return write_capture(tmp_path / "cap", frames, CaptureMeta(sensor="unknown", intrinsics=INTR), ir_frames=irs)


# ------------------------------------------------------------------ frame path
def test_identity_calibration_changes_nothing_and_points_match_numpy():
    d = _frames(1)[0]
    path = FramePath(INTR)
    assert identity_calibration(INTR).provenance == {"identity": True}
    np.testing.assert_array_equal(path.correct(d), d.astype(np.float32))
    pts = path.points(d)
    ref = depth_to_points(d, INTR)  # the numpy reference
    assert pts.dtype == np.float32 and pts.shape == ref.shape
    np.testing.assert_allclose(pts, ref, atol=2e-6)  # float32 rays and depth
    np.testing.assert_array_equal(path.index(d), np.flatnonzero(d))
    # the plain pinhole is the same kernel with the other ray table
    np.testing.assert_allclose(FramePath(INTR, undistort=False).points(d), depth_to_points(d, INTR, undistort=False),
                               atol=2e-6)


def test_calibrated_points_match_the_reference_and_reuse_a_buffer():
    cal = _calibration()
    d = _frames(1)[0]
    path = FramePath(INTR, cal)
    ref = depth_to_points(apply_depth_calibration(d.astype(np.float64), cal), INTR)
    np.testing.assert_allclose(path.points(d), ref, atol=5e-6)
    buf = np.empty((d.size, 3), np.float32)
    view = path.points(d, out=buf)
    assert np.shares_memory(view, buf)
    with pytest.raises(InputError, match="uint16"):
        path.points(d.astype(np.float32))


# ------------------------------------------------------------------ streaming
def test_stream_frames_keeps_order_bounds_the_reads_and_stops_on_errors():
    in_flight, peak, lock = [0], [0], threading.Lock()
    got, written = [], {}

    def read(i):
        with lock:
            in_flight[0] += 1
            peak[0] = max(peak[0], in_flight[0])
        return i

    def process(i, frame):
        with lock:
            in_flight[0] -= 1
        got.append((i, frame))
        return -frame

    stream_frames(50, read, process, lambda i, r: written.__setitem__(i, r), workers=3, ahead=4)
    assert got == [(i, i) for i in range(50)]
    assert written == {i: -i for i in range(50)}
    assert peak[0] <= 4 + 1  # ahead frames read ahead, plus the one being handed over

    def bad_write(i, r):
        if i == 7:
            raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        stream_frames(50, read, lambda i, f: f, bad_write, workers=2)


# ------------------------------------------------------------------ correct
@pytest.mark.parametrize("float32", [False, True])
def test_correct_capture_writes_the_kernel_result(capture, tmp_path, float32):
    cal = _calibration()
    save_calibration(tmp_path / "cal.npz", cal)
    ticks = []
    run = correct_capture(capture, tmp_path / "cal.npz", tmp_path / "out", float32=float32, advance=lambda: ticks.append(1))
    src, out = Capture(capture), Capture(tmp_path / "out")
    assert run.n_frames == len(out) == len(src) == len(ticks)
    assert out.meta.intrinsics == INTR and out.meta.extra["corrected_from"] == str(src.path)
    for i in range(len(src)):
        d = src.depth(i)
        c = apply_depth_calibration(d, cal)
        if float32:
            np.testing.assert_array_equal(out.depth(i, as_float=True), np.where(d > 0, c, 0).astype(np.float32))
        else:
            np.testing.assert_array_equal(out.depth(i), np.where(d > 0, np.clip(np.rint(c), 1, 65535), 0))
        np.testing.assert_array_equal(out.ir(i), src.ir(i))


def test_an_interrupted_correct_leaves_no_output(capture, tmp_path):
    (capture / "depth" / "000003.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)  # truncated frame
    with pytest.raises(InputError):
        correct_capture(capture, _calibration(), tmp_path / "out")
    assert not (tmp_path / "out").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]  # no staging folder left


def test_correct_refuses_its_input_and_an_existing_output(capture, tmp_path):
    with pytest.raises(InputError, match="is the input folder"):
        correct_capture(capture, _calibration(), capture)
    correct_capture(capture, _calibration(), tmp_path / "out")
    with pytest.raises(InputError, match="exists"):
        correct_capture(capture, _calibration(), tmp_path / "out")
    correct_capture(capture, _calibration(), tmp_path / "out", force=True)


# ------------------------------------------------------------------ cloud
def test_cloud_of_one_frame_and_of_the_average(capture, tmp_path):
    cal = _calibration()
    cap = Capture(capture)
    one = capture_cloud(cap, tmp_path / "one.ply", calibration=cal, frame=2)
    ref, idx = depth_to_points(apply_depth_calibration(cap.depth(2).astype(np.float64), cal), INTR, return_index=True)
    np.testing.assert_allclose(one.points, ref, atol=5e-6)
    np.testing.assert_array_equal(one.index, idx)
    ply = read_ply(tmp_path / "one.ply")
    assert len(ply["points"]) == len(ref) and ply["colors"].shape == (len(ref), 3)  # IR-coloured
    avg = capture_cloud(cap, average=True, calibration=cal)
    # every frame corrected, then averaged: the same as correcting the average, to rounding
    ref = depth_to_points(apply_depth_calibration(robust_mean_depth(cap.depth_stack()), cal), INTR)
    assert avg.averaged and avg.n_frames == len(cap) and avg.output is None
    np.testing.assert_allclose(avg.points, ref, atol=2e-5)
    raw = capture_cloud(cap, frame=0)
    np.testing.assert_allclose(raw.points, depth_to_points(cap.depth(0), INTR), atol=2e-6)
    with pytest.raises(InputError, match="frame 9"):
        capture_cloud(cap, frame=9)


# ------------------------------------------------------------------ filter
def test_filter_removes_flying_pixels_frame_by_frame(capture, tmp_path):
    src = Capture(capture)
    frames = [src.depth(i) for i in range(len(src))]
    for f in frames:
        f[20, 30] = 400  # a lone sample far in front of a smooth wall: flying
    write_capture(tmp_path / "fly", frames, CaptureMeta(sensor="unknown", intrinsics=INTR))
    run = filter_capture(tmp_path / "fly", tmp_path / "clean")
    out = Capture(tmp_path / "clean")
    assert run.n_frames == len(out) == len(frames)
    assert all(out.depth(i)[20, 30] == 0 for i in range(len(out)))
    assert run.removed >= len(frames) and "filtered" in out.meta.extra


# ------------------------------------------------------------------ the commands
def test_cloud_command_parses_calls_the_pipeline_and_prints(capture, tmp_path):
    from typer.testing import CliRunner

    from tofmetry.cli import app

    save_calibration(tmp_path / "cal.npz", _calibration())
    out = tmp_path / "c.ply"
    r = CliRunner().invoke(app, ["cloud", str(capture), "-o", str(out), "--average", "--calibration",
                                 str(tmp_path / "cal.npz")])
    assert r.exit_code == 0, r.output
    assert "points to" in r.output and out.is_file()
    r = CliRunner().invoke(app, ["cloud", str(capture), "-o", str(out)])
    assert r.exit_code != 0 and "exists" in str(r.exception or r.output)
