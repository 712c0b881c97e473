"""The stages of the study, in the order of the reference paper.

Each stage is ``fn(ctx: StudyContext, out: StageOutcome) -> None`` (:mod:`tofmetry.study.stage`):
it reads its input folder from ``ctx.data_dir``, runs the pipelines exactly as on a user's
recording, writes figures/JSON into ``ctx.out_dir/<key>/`` and fills ``out`` (numbers, tables,
figures, paragraphs). Raising :class:`~tofmetry.study.stage.Skip` marks it skipped; any other
exception marks it failed.

==========  =====================  ==========================================
section     stages                 module
==========  =====================  ==========================================
§3          sensor, warm-up,       :mod:`tofmetry.study.stages_assess`
            noise, materials,
            outdoor
§4          intrinsics, depth      :mod:`tofmetry.study.stages_cal`
§5, §5.3    model (+ accuracy)     :mod:`tofmetry.study.stages_model`
==========  =====================  ==========================================
"""

from __future__ import annotations

from typing import Callable

from tofmetry.study.stage import StageOutcome, StudyContext
from tofmetry.study.stages_assess import stage_materials, stage_noise, stage_outdoor, stage_sensor, stage_warmup
from tofmetry.study.stages_cal import stage_depth, stage_intrinsics
from tofmetry.study.stages_model import stage_model
from tofmetry.study.stages_real import stage_board, stage_mkv

#: (key, title, stage function) in the order they run
STAGES: list[tuple[str, str, Callable[[StudyContext, StageOutcome], None]]] = [
    ("sensor", "Sensor summary", stage_sensor),
    ("warmup", "Warm-up (pre-heating) drift", stage_warmup),
    ("noise", "Temporal noise and frame averaging", stage_noise),
    ("materials", "Materials and intensity", stage_materials),
    ("outdoor", "Strong light and flying pixels", stage_outdoor),
    ("intrinsics", "IR camera intrinsics (Brown model) and stability", stage_intrinsics),
    ("depth", "Depth calibration and validation on held-out stations", stage_depth),
    ("model", "3D model of the object and its accuracy", stage_model),
    ("board", "Board recording: intrinsics, board depth calibration, validation on poses no fit saw", stage_board),
    ("mkv", "Azure Kinect recordings: import and point clouds", stage_mkv),
]
