"""The study end to end: partial DATA_DIR (skips with reasons) and a small full run checked in a browser."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.simulate import datasets
from tofmetry.study import load_config
from tofmetry.study.pipeline import StudyPipeline

SMALL = """
[simulation]
warmup_duration_s = 2400.0
warmup_interval_s = 60.0
noise_frames = 30
material_frames = 4
outdoor_frames = 2
checkerboard_images = 8
wall_distances_mm = [800.0, 1000.0, 1500.0, 2000.0, 2500.0]
wall_frames = 4
validation_distances_mm = [1250.0, 2250.0]
validation_frames = 3
scan_views = 8
scan_frames = 3
[assess]
noise_subsets = [10, 25]
"""


def test_partial_data_dir_runs_what_is_present_and_says_what_was_skipped(tmp_path):
    data = tmp_path / "data"
    datasets.checkerboard_images(data / "checkerboard", n_images=8, seed=3)
    datasets.wall_dataset(data / "wall", distances_mm=[800, 1200, 1600, 2000], n_frames=3, seed=1)
    cfg = load_config(None)
    ctx = StudyPipeline(data, tmp_path / "out", cfg).run()
    status = {k: o.status for k, o in ctx.outcomes.items()}
    assert status["intrinsics"] == "ok" and status["depth"] == "ok"
    for key, folder in (("warmup", "warmup/"), ("noise", "noise/"), ("outdoor", "outdoor/"), ("model", "scan/")):
        assert status[key] == "skipped", (key, ctx.outcomes[key].note)
        assert folder in ctx.outcomes[key].note  # the reason names the missing input
    assert status["materials"] == "skipped"
    # the calibration used the intrinsics calibrated in the same run
    assert "checkerboard" in ctx.outcomes["depth"].data["intrinsics_source"]
    assert (tmp_path / "out" / "depth" / "calibration.npz").is_file()


def test_a_failing_stage_is_reported_and_the_others_run(tmp_path):
    data = tmp_path / "data"
    datasets.noise(data / "noise", n_frames=12, seed=2)
    (data / "warmup").mkdir()  # present but empty: that stage fails with the reader's message
    ctx = StudyPipeline(data, tmp_path / "out", load_config(None)).run()
    assert ctx.outcomes["warmup"].status == "failed"
    assert "no depth frames" in ctx.outcomes["warmup"].note
    assert ctx.outcomes["noise"].status == "ok"


@pytest.mark.slow
@pytest.mark.browser
def test_small_full_study_writes_a_report_that_renders(tmp_path, inspect):
    cfg = tmp_path / "study.toml"
    cfg.write_text(SMALL)
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["study", "-o", str(out), "--config", str(cfg)])
    assert r.exit_code == 0, r.output
    rep = json.loads((out / "report.json").read_text())
    # every simulated stage runs; the stages of real recordings say why they were skipped
    assert {k: v["status"] for k, v in rep["stages"].items()} == {
        **{k: "ok" for k in ("sensor", "warmup", "noise", "materials", "outdoor", "intrinsics", "depth", "model")},
        "board": "skipped", "mkv": "skipped"}
    assert (out / "study.toml").is_file() and load_config(out / "study.toml").simulation.wall_frames == 4
    assert len(rep["comparison"]) >= 10
    # the depth tilt the walls cannot show is fitted on the simulated checkerboard captures with depth
    # and judged on the captures kept out of its fit (folded in, or bounded, or contradicted: said)
    tilt = rep["stages"]["depth"]["results"]["tilt"]
    assert tilt["tilt"]["n_views"] >= 10 and tilt["tilt"]["held_out"]["reason"]
    page = inspect(out / "report.html", out / "report.png")
    assert page.console_errors == []
    assert page.broken_images == 0 and page.images >= 15
    assert page.viewer_points > 1000 and page.canvas_nonblank
    for key in ("sensor", "warmup", "noise", "materials", "outdoor", "intrinsics", "depth", "model", "comparison"):
        assert page.sections.get(key) == "ok", key
