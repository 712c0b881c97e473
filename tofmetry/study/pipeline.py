"""The study pipeline: owns the loop over stages, progress, error isolation and output.

Each stage of :data:`tofmetry.study.stages.STAGES` is a function ``stage(ctx, out)`` (the
protocol is in :mod:`tofmetry.study.stage`) that calls the pipelines and the library exactly as
a user's recordings would be processed. A stage that fails is recorded with its error and the
others still run; a stage whose input folder is absent is recorded as skipped with the reason.
"""

from __future__ import annotations

import platform
import time
import traceback
from pathlib import Path
from typing import Callable

from tofmetry.errors import InputError
from tofmetry.study.config import StudyConfig
from tofmetry.study.inputs import simulate_study_inputs
from tofmetry.study.stage import Skip, StageOutcome, StudyContext
from tofmetry.study.stages import STAGES


class StudyPipeline:
    """Run every stage of the study and collect the outcomes.

    Parameters
    ----------
    data_dir : folder laid out as ``warmup/ noise/ materials/ outdoor/ checkerboard/ wall/ scan/``
        (each optional) plus optional ``reference.ply``; None simulates everything first.
    out_dir : output folder
    config : StudyConfig
    on_event : callable(kind, text) for progress display (``kind`` in start/done/skip/fail/info)
    accept_implausible : keep results that fail a plausibility gate (recorded in the report) instead
        of failing their stage
    """

    def __init__(self, data_dir: Path | None, out_dir: Path, config: StudyConfig,
                 on_event: Callable[[str, str], None] | None = None, accept_implausible: bool = False):
        self.data_dir = None if data_dir is None else Path(data_dir)
        self.out_dir = Path(out_dir)
        self.config = config
        self.on_event = on_event or (lambda kind, text: None)
        self.accept_implausible = accept_implausible
        if self.data_dir is not None and not self.data_dir.is_dir():
            raise InputError(f"DATA_DIR {self.data_dir} is not a folder")

    def run(self) -> StudyContext:
        t_start = time.perf_counter()
        self.out_dir.mkdir(parents=True, exist_ok=True)
        simulated = self.data_dir is None
        data_dir = self.data_dir
        sim_seconds = 0.0
        if simulated:
            data_dir = self.out_dir / "data"
            self.on_event("start", "simulating the study's inputs on the virtual Kinect v2")
            t0 = time.perf_counter()
            simulate_study_inputs(data_dir, self.config.simulation, on_step=lambda s: self.on_event("info", s))
            sim_seconds = time.perf_counter() - t0
            self.on_event("done", f"inputs simulated in {sim_seconds:.0f} s")
        ctx = StudyContext(data_dir=data_dir, out_dir=self.out_dir, config=self.config, simulated=simulated,
                           accept_implausible=self.accept_implausible)
        for key, title, fn in STAGES:
            self.on_event("start", title)
            t0 = time.perf_counter()
            out = StageOutcome(key, title)
            try:
                fn(ctx, out)
                out.status = "ok"
            except Skip as s:
                out.status, out.note = "skipped", str(s)
            except Exception as exc:  # noqa: BLE001 - a failed stage is reported, the others run
                out.status = "failed"
                out.note = f"{type(exc).__name__}: {exc}"
                out.data["traceback"] = traceback.format_exc(limit=6)
            out.seconds = time.perf_counter() - t0
            ctx.outcomes[key] = out
            kind = {"ok": "done", "skipped": "skip", "failed": "fail"}[out.status]
            self.on_event(kind, f"{title} ({out.seconds:.1f} s)" + (f": {out.note}" if out.note else ""))
        ctx.total_seconds = time.perf_counter() - t_start
        ctx.simulation_seconds = sim_seconds
        ctx.machine = f"{platform.machine()}, {platform.system()} {platform.release()}, Python {platform.python_version()}"
        return ctx
