"""The study's model stage reports the share of the model coloured (the HTML report prints the stage's
paragraphs), and says so when colour frames could not be used; nothing about colour without them."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.reconstruct import ReconstructionResult
from tofmetry.study import stages_model
from tofmetry.study.config import StudyConfig
from tofmetry.study.stage import StageOutcome, StudyContext


def _result(color):
    summary = {"points": 100, "colored": 97, "uncolored": 3, "share_colored": 0.97,
               "views_per_colored_point_median": 3.0}
    diag = {"reliable": True, "consistency": {}, "fusion": {}, "timings_s": {},
            "color": None if color is None else (color or {"views_with_color": 8, "points": summary,
                                                           "mesh": {**summary, "share_colored": 0.985}})}
    edge = {"source": "00", "target": "01", "method": "icp", "fitness": 0.9, "inlier_rmse_mm": 1.0, "kept": True,
            "accepted": True}
    return ReconstructionResult(["00", "01"], np.zeros((2, 4, 4)), [edge], np.zeros((5, 3)), np.zeros((1, 3), int),
                                np.zeros((5, 3)), np.zeros((100, 3)), np.zeros((100, 3)), None, None, diag)


@pytest.mark.parametrize("color", [None, {}, {"skipped": "no view has a usable colour frame", "views": {}}])
def test_model_stage_reports_colour(tmp_path, monkeypatch, color):
    (tmp_path / "data" / "scan").mkdir(parents=True)
    monkeypatch.setattr(stages_model, "reconstruct_scan", lambda *a, **k: _result(color))
    ctx = StudyContext(tmp_path / "data", tmp_path / "out", StudyConfig(), simulated=True)
    out = StageOutcome("model", "model")
    stages_model.stage_model(ctx, out)
    text = " ".join(out.paragraphs)
    if color is None:
        assert "colour" not in text and "color" not in out.data["uncalibrated"]
    elif color == {}:
        assert "98.5 % of the mesh vertices and 97.0 % of the cloud's points coloured" in text
        assert "the 3 vertices no colour camera sees have no colour" in text
        assert out.data["uncalibrated"]["color"]["mesh"]["share_colored"] == 0.985
    else:
        assert "not coloured (no view has a usable colour frame)" in text
