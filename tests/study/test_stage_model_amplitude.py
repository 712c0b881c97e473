"""The study's model stage hands the amplitude-bias coefficient its materials stage measured, with
that measurement's uncertainty, to the reconstruction: the uncertainty bounds the scan's own
correction ``dk`` (with the default +-3 mm per ln unit, ``dk`` walked to -2.5 and moved every
surface of the study's model by 1.4 mm)."""

from __future__ import annotations

import math

from tofmetry.study import stages_model
from tofmetry.study.config import StudyConfig
from tofmetry.study.stage import StageOutcome, StudyContext


def _ctx(tmp_path, materials: bool):
    ctx = StudyContext(tmp_path / "data", tmp_path / "out", StudyConfig(), simulated=True)
    if materials:
        out = StageOutcome("materials", "materials")
        out.data["materials"] = {"fit": {"slope_mm_per_ln": 6.5, "slope_se_mm_per_ln": 0.08}}
        ctx.outcomes["materials"] = out
    return ctx


def test_measured_k_comes_with_its_uncertainty(tmp_path):
    k, sigma, src = stages_model._amplitude_slope(_ctx(tmp_path, True))
    assert k == 6.5 and "measured" in src
    assert math.isclose(sigma, math.hypot(0.08, 0.15))  # the fit's standard error and the model's own


def test_the_studys_figure_has_no_measured_uncertainty(tmp_path):
    k, sigma, src = stages_model._amplitude_slope(_ctx(tmp_path, False))
    assert sigma is None and "§3.3.1" in src and k > 6
