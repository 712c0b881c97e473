"""The virtual device streams in real time; a live capture survives a cut at any frame."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

from tofmetry.devices.virtual import VirtualDevice
from tofmetry.io import Capture
from tofmetry.io.live_capture import LiveCaptureWriter, recover_capture
from tofmetry.simulate import scenes

REPO = Path(__file__).resolve().parents[2]


def test_virtual_device_streams_in_real_time():
    with VirtualDevice(scenes.wall(1.2), fps=30.0, realtime=True) as dev:
        t0 = time.monotonic()
        frames = [dev.read() for _ in range(10)]
        wall = time.monotonic() - t0
    assert wall >= 9 / 30 - 1e-3                                   # paced: not faster than 30 fps
    ts = np.array([f.timestamp_s for f in frames])
    assert np.allclose(np.diff(ts), 1 / 30)
    d = frames[0].depth
    assert d.dtype == np.uint16 and d.shape == (424, 512) and abs(np.median(d[d > 0]) - 1200) < 20
    assert "sensor" in frames[0].temperature_c


def test_cut_mid_recording_loses_at_most_the_frame_in_flight(tmp_path):
    out = tmp_path / "cap"
    script = textwrap.dedent(f"""
        import os, numpy as np
        from tofmetry.io import CaptureMeta
        from tofmetry.io.live_capture import LiveCaptureWriter
        import tofmetry.io.live_capture as lc
        w = LiveCaptureWriter({str(out)!r}, CaptureMeta(sensor="kinect_v2"))
        real = lc.durable_write
        def cut(path, data):                      # the power goes off while frame 5's depth is written
            if path.parent.name == "depth" and path.name == "000005.png":
                os._exit(9)
            real(path, data)
        lc.durable_write = cut
        for i in range(10):
            d = np.full((424, 512), 1000 + i, np.uint16)
            w.add(d, 0.5 * i, ir=d, temperature_c={{"sensor": 30.0 + i}})
    """)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    p = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
    assert p.returncode == 9, p.stderr
    # the folder reads as a capture of the frames before the cut ... (IR of frame 5 is orphaned)
    rec = recover_capture(out)
    assert rec["frames"] == 5 and "ir/000005.png" in rec["removed"]
    cap = Capture(out)
    assert len(cap) == 5 and list(cap.timestamps_s) == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert cap.depth(4)[0, 0] == 1004 and cap.meta.extra["temperature_c"]["sensor"][-1] == 34.0


def test_live_writer_refuses_a_non_empty_folder(tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "keep.txt").write_text("mine")
    import pytest

    from tofmetry.errors import InputError

    with pytest.raises(InputError, match="never replaces"):
        LiveCaptureWriter(tmp_path / "x")
    assert (tmp_path / "x" / "keep.txt").read_text() == "mine"
