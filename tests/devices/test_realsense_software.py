"""A RealSense ``software_device`` stream (the real pyrealsense2 library, synthetic frames) through ``record``."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from tofmetry.devices.realsense import RealSenseDevice
from tofmetry.io import Capture, WallDataset
from tofmetry.record import WallSession, run_recording

rs = pytest.importorskip("pyrealsense2")
W, H = 320, 240


def _software_wall(n_frames: int, distance_mm: float, temperature_c: float):
    """A software device streaming a flat wall at ``distance_mm`` in 0.1 mm units (not mm: converted)."""
    dev = rs.software_device()
    s = dev.add_sensor("Depth")
    intr = rs.intrinsics()
    intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy = W, H, 260.0, 260.0, 160.0, 120.0
    intr.model, intr.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid, vs.width, vs.height, vs.fps, vs.bpp, vs.fmt = (
        rs.stream.depth, 0, 0, W, H, 30, 2, rs.format.z16)
    vs.intrinsics = intr
    prof = s.add_video_stream(vs)
    s.add_read_only_option(rs.option.depth_units, 0.0001)
    s.add_read_only_option(rs.option.asic_temperature, temperature_c)
    sync = rs.syncer()
    s.open(prof)
    s.start(sync)
    counts = np.full((H, W), int(distance_mm * 10), np.uint16)
    frames = []

    def push(k: int) -> None:
        f = rs.software_video_frame()
        f.pixels, f.bpp, f.stride = counts, 2, W * 2
        f.timestamp, f.domain, f.frame_number = k * 1000 / 30, rs.timestamp_domain.hardware_clock, k
        f.profile = prof.as_video_stream_profile()
        s.on_video_frame(f)
        frames.append(k)

    return dev, s, sync, push


def test_software_device_stream_through_record(tmp_path):
    dev, sensor, sync, push = _software_wall(12, 1234.5, 41.5)
    device = RealSenseDevice(queue=sync, sensor=sensor, timeout_s=2.0)
    n = {"k": 0}

    class Feeder:
        """Pushes one synthetic frame before each read, as a camera would deliver it."""

        def wait_for_frames(self, ms):
            if n["k"] >= 12:
                raise RuntimeError("end of the synthetic stream")
            push(n["k"])
            n["k"] += 1
            return sync.wait_for_frames(ms)

    device._queue = Feeder()
    sess = WallSession(tmp_path / "wall", [1200.0], frames=5, steady=2, patience=100)
    res = run_recording(device, sess, lambda req: "1234.5" if req.kind == "distance" else None)
    assert res.ended == "done"
    cap = Capture(tmp_path / "wall" / "01")
    assert len(cap) == 5 and cap.shape == (H, W) and cap.sensor == "realsense"
    np.testing.assert_array_equal(cap.depth(0), np.full((H, W), 1234, np.uint16))  # 12345 x 0.1 mm = 1234.5 -> 1234 (half to even)
    intr, src = cap.intrinsics()
    assert src == "capture.json" and intr.fx == 260.0 and intr.cx == 160.0
    assert cap.meta.extra["temperature_c"]["asic_temperature"] == [41.5] * 5
    ts = cap.timestamps_s
    assert np.allclose(np.diff(ts), 1 / 30, atol=1e-3)
    assert WallDataset(tmp_path / "wall").stations[0].distance_mm == 1234.5


def test_missing_bag_is_a_clear_error(tmp_path):
    from tofmetry.devices.base import DeviceError

    with pytest.raises(DeviceError, match="file not found"):
        RealSenseDevice(tmp_path / "nope.bag").open()
