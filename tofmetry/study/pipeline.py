"""The study pipeline: owns the loop over stages, progress, error isolation and output.

Each stage (``tofmetry.study.stages``) is a function ``stage(ctx) -> StageOutcome`` that calls the
library (assess, calibrate, reconstruct, evaluate) exactly as a user's recordings would be
processed. A stage that fails is recorded with its error and the others still run; a stage whose
input folder is absent is recorded as skipped with the reason.
"""

from __future__ import annotations

import platform
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from tofmetry.errors import InputError
from tofmetry.study.config import StudyConfig


class Skip(Exception):
    """Raised by a stage whose input is absent: the message says what was skipped and why."""


@dataclass
class StageOutcome:
    """What one stage produced (all plain data, JSON-serialisable except figure paths)."""

    key: str
    title: str
    status: str = "ok"  # ok | skipped | failed
    seconds: float = 0.0
    data: dict = field(default_factory=dict)
    figures: list[tuple[str, Path]] = field(default_factory=list)
    tables: list[tuple[str, list[str], list[list]]] = field(default_factory=list)
    paragraphs: list[str] = field(default_factory=list)
    note: str = ""

    def to_dict(self) -> dict:
        return {"key": self.key, "title": self.title, "status": self.status, "seconds": round(self.seconds, 2),
                "note": self.note, "figures": [str(p) for _, p in self.figures], "results": self.data}


@dataclass
class StudyContext:
    """Shared state between stages (what a later stage needs from an earlier one)."""

    data_dir: Path
    out_dir: Path
    config: StudyConfig
    simulated: bool
    intrinsics: object | None = None  # CameraIntrinsics from the intrinsics stage
    intrinsics_source: str = "sensor profile (typical values, not calibrated)"
    calibration_path: Path | None = None
    outcomes: dict[str, StageOutcome] = field(default_factory=dict)

    def stage_dir(self, key: str) -> Path:
        d = self.out_dir / key
        d.mkdir(parents=True, exist_ok=True)
        return d

    def input(self, name: str, what: str) -> Path:
        """Path of an input sub-folder, or :class:`Skip` naming what is missing."""
        p = self.data_dir / name
        if not p.exists():
            raise Skip(f"no {name}/ folder in {self.data_dir} ({what}); stage skipped")
        return p

    def capture_dir(self, name: str, what: str) -> Path:
        """The capture of input ``name``: the folder itself, or its ``capture/`` sub-folder
        (the simulator's layout, which keeps ``truth.json`` beside the capture)."""
        p = self.input(name, what)
        if (p / "depth").is_dir():
            return p
        if (p / "capture" / "depth").is_dir():
            return p / "capture"
        return p  # Capture() then names what is missing


class StudyPipeline:
    """Run every stage of the study and collect the outcomes.

    Parameters
    ----------
    data_dir : folder laid out as ``warmup/ noise/ materials/ outdoor/ checkerboard/ wall/ scan/``
        (each optional) plus optional ``reference.ply``; None simulates everything first.
    out_dir : output folder
    config : StudyConfig
    on_event : callable(kind, text) for progress display (``kind`` in start/done/skip/fail/info)
    """

    def __init__(self, data_dir: Path | None, out_dir: Path, config: StudyConfig,
                 on_event: Callable[[str, str], None] | None = None):
        self.data_dir = None if data_dir is None else Path(data_dir)
        self.out_dir = Path(out_dir)
        self.config = config
        self.on_event = on_event or (lambda kind, text: None)
        if self.data_dir is not None and not self.data_dir.is_dir():
            raise InputError(f"DATA_DIR {self.data_dir} is not a folder")

    def run(self) -> StudyContext:
        from tofmetry.study import stages

        t_start = time.perf_counter()
        self.out_dir.mkdir(parents=True, exist_ok=True)
        simulated = self.data_dir is None
        data_dir = self.data_dir
        sim_seconds = 0.0
        if simulated:
            from tofmetry.study.inputs import simulate_study_inputs

            data_dir = self.out_dir / "data"
            self.on_event("start", "simulating the study's inputs on the virtual Kinect v2")
            t0 = time.perf_counter()
            simulate_study_inputs(data_dir, self.config.simulation, on_step=lambda s: self.on_event("info", s))
            sim_seconds = time.perf_counter() - t0
            self.on_event("done", f"inputs simulated in {sim_seconds:.0f} s")
        ctx = StudyContext(data_dir=data_dir, out_dir=self.out_dir, config=self.config, simulated=simulated)
        for key, title, fn in stages.STAGES:
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
