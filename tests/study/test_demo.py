"""``tofmetry demo``: simulated wall and object, their averaged clouds through the cloud pipeline."""

from __future__ import annotations

from tofmetry.io import read_json, read_ply
from tofmetry.study import run_demo


def test_demo_writes_the_clouds_and_a_summary(tmp_path):
    steps = []
    summary = run_demo(tmp_path, n_frames=2, on_step=steps.append)
    assert steps and read_json(tmp_path / "summary.json")["wall"]["points"] == summary["wall"]["points"]
    for name in ("wall", "object"):
        ply = read_ply(tmp_path / f"{name}.ply")
        assert len(ply["points"]) == summary[name]["points"] > 1000 and ply["colors"].shape[1] == 3
    lo, hi = summary["wall"]["depth_range_mm"]
    assert 1400 < lo <= hi < 1600  # the wall is simulated 1.5 m away
    assert abs(summary["wall"]["central_bias_mm"]) < 30 and summary["wall"]["plane_residual_std_mm"] > 0
