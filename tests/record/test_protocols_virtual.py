"""Each protocol end to end on the virtual device, a simulated operator answering the requests."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tofmetry.devices.virtual import VirtualDevice
from tofmetry.io import Capture, WallDataset
from tofmetry.io.board_dataset import BoardDataset, BoardSpec
from tofmetry.record import BoardSession, ObjectSession, WallSession, WarmupSession, run_recording
from tofmetry.record.virtual_operator import VirtualOperator
from tofmetry.simulate import scenes


def test_warmup_stops_by_itself_when_stable(tmp_path):
    # a cold sensor: the simulator drifts ~5 mm and settles after the fan starts (20 min)
    dev = VirtualDevice(scenes.wall(1.36, (1.5, -2.0)), fps=1 / 30, realtime=False, t0_s=0.0)
    res = run_recording(dev, WarmupSession(tmp_path / "cold", interval_s=30), lambda r: None, max_frames=400)
    s = res.summary
    assert res.ended == "done" and s["stable"]
    assert 20 * 60 <= s["elapsed_s"] <= 40 * 60 and abs(s["drift_mm"]) > 3
    cap = Capture(tmp_path / "cold")
    assert len(cap) == s["frames"] and cap.timestamps_s is not None
    temps = cap.meta.extra["temperature_c"]["sensor"]
    assert len(temps) == len(cap) and temps[-1] > temps[0] + 5        # the sensor warmed up
    assert (tmp_path / "cold" / "preview.png").is_file()
    # an already warm sensor stops after the confirmation window alone
    warm = VirtualDevice(scenes.wall(1.36), fps=1 / 30, realtime=False, t0_s=7200.0)
    r2 = run_recording(warm, WarmupSession(tmp_path / "warm", interval_s=30), lambda r: None, max_frames=400)
    assert r2.summary["stable"] and r2.summary["elapsed_s"] == pytest.approx(600.0)


def test_wall_guides_squares_up_and_asks_the_distance(tmp_path):
    dev = VirtualDevice(realtime=False)
    op = VirtualOperator(dev, clumsy=True)               # places the first station tilted by 4°
    res = run_recording(dev, WallSession(tmp_path / "wall", [1000, 2000], frames=4), op, max_frames=300)
    kinds = [(r.kind, r.text) for r in op.requests]
    assert res.ended == "done"
    assert any("not square about the vertical axis" in t for _, t in kinds)       # the tilt was caught
    assert [k for k, _ in kinds].count("distance") == 2
    ds = WallDataset(tmp_path / "wall")
    assert [s.distance_mm for s in ds.stations] == [1000.0, 2000.0]
    assert all(abs(c["yaw_deg"]) <= 1.0 for c in res.summary["checks"])


def test_board_asks_for_missing_coverage_until_full(tmp_path):
    board = BoardSpec(7, 5, 40.0)
    dev = VirtualDevice(realtime=False)
    op = VirtualOperator(dev, board=board)
    sess = BoardSession(tmp_path / "board", board, grid=(2, 2), range_edges_mm=(600, 900, 1300))
    res = run_recording(dev, sess, op, max_frames=300)
    assert res.ended == "done" and res.summary["cells_covered"] == 8
    asked = [r.target["cells"] for r in op.requests]
    assert len(asked[0]) == 8                                   # at first everything is missing ...
    assert all(len(b) < len(a) for a, b in zip(asked, asked[1:]))   # ... and each request asks for less
    ds = BoardDataset(tmp_path / "board")
    assert len(ds) == res.summary["poses"] >= 8 and ds.corners(0) is not None


def test_object_checks_overlap_and_predicts_completeness(tmp_path):
    dev = VirtualDevice(scenes.balustrade(), realtime=False)
    op = VirtualOperator(dev, clumsy=True)                     # looks away from the object once
    sess = ObjectSession(tmp_path / "scan", (0.4, 0.2, 0.2), n_views=6, distance_m=0.9, frames=2, min_overlap=0.2)
    res = run_recording(dev, sess, op, max_frames=300)
    s = res.summary
    assert res.ended == "done" and s["views"] == 6
    assert any(r.text == "the object is not in view" for r in op.requests)
    comp = s["predicted_completeness"]
    assert np.all(np.diff(comp) >= 0) and comp[-1] > 0.8
    assert min(s["overlaps"][1:]) >= 0.2
    meta = json.loads((tmp_path / "scan" / "views" / "01" / "capture.json").read_text())
    assert meta["recording"]["complete"] and "camera_to_world_estimate" in meta
