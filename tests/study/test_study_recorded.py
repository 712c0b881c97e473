"""``tofmetry record`` → ``tofmetry study`` on the virtual device: the board and warm-up protocols."""

from __future__ import annotations

import pytest

from tofmetry.devices.virtual import VirtualDevice
from tofmetry.io.board_dataset import BoardSpec
from tofmetry.record import BoardSession, WarmupSession, run_recording
from tofmetry.record.virtual_operator import VirtualOperator
from tofmetry.simulate import scenes
from tofmetry.study import load_config
from tofmetry.study.pipeline import StudyPipeline


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    rec = tmp_path_factory.mktemp("rec")
    board = BoardSpec(7, 5, 40.0)
    dev = VirtualDevice(realtime=False)
    res = run_recording(dev, BoardSession(rec / "board", board, grid=(2, 2), range_edges_mm=(600, 900, 1300)),
                        VirtualOperator(dev, board=board), max_frames=300)
    assert res.ended == "done"
    cold = VirtualDevice(scenes.wall(1.36, (1.5, -2.0)), fps=1 / 30, realtime=False, t0_s=0.0)
    run_recording(cold, WarmupSession(rec / "warmup", interval_s=30), lambda r: None, max_frames=400)
    ctx = StudyPipeline(rec, tmp_path_factory.mktemp("study") / "out", load_config(None)).run()
    return rec, res.summary, ctx


def test_board_stage_on_a_recorded_board_dataset(recorded):
    rec, summary, ctx = recorded
    o = ctx.outcomes["board"]
    assert o.status == "ok", o.note
    b = o.data
    assert b["source"] == str(rec / "board") and b["poses"] == summary["poses"] >= 8
    assert b["board"] == {"cols": 7, "rows": 5, "square_mm": 40.0}          # from the dataset's board.json
    n_judge = round(b["poses"] * 2 / 7)
    assert b["judged_poses"][1] == f"{b['poses'] - 1:04d}" and b["train_poses"][1] == f"{b['poses'] - 1 - n_judge:04d}"
    j = b["judged"]
    # the virtual sensor's depth error on poses no fit saw: tens of mm raw, a few mm corrected
    assert j["none"]["rms_mm"] > 20 and j["tofmetry"]["rms_mm"] < 0.25 * j["none"]["rms_mm"]
    assert j["tofmetry"]["rms_mm"] < j["constant"]["rms_mm"]
    assert (ctx.out_dir / "board" / "calibration.npz").is_file()


def test_warmup_stage_reports_the_drift_per_degree(recorded):
    _, _, ctx = recorded
    o = ctx.outcomes["warmup"]
    assert o.status == "ok", o.note
    fit = o.data["temperature"]["fit"]
    assert 0.40 < fit["slope_mm_per_c"] < 0.50 and fit["slope_se_mm_per_c"] < 0.02
    rows = {r[0]: r[1] for title, _, rs in o.tables for r in rs}
    assert any(k.startswith("drift per degree") and "mm/°C" in v for k, v in rows.items())
    for key in ("noise", "materials", "outdoor", "intrinsics", "depth", "model", "mkv"):
        assert ctx.outcomes[key].status == "skipped"
