"""What every stage of the study works with: its context, its outcome, and how it skips.

A stage is a function ``stage(ctx: StudyContext, out: StageOutcome) -> None`` (see
:mod:`tofmetry.study.stages`); the stages import this module, and :mod:`tofmetry.study.pipeline`
runs them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from tofmetry.sensor import CameraIntrinsics
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
    intrinsics: CameraIntrinsics | None = None  # from the intrinsics stage
    intrinsics_source: str = "sensor profile (typical values, not calibrated)"
    calibration_path: Path | None = None
    outcomes: dict[str, StageOutcome] = field(default_factory=dict)
    total_seconds: float = 0.0  # filled by the pipeline at the end
    simulation_seconds: float = 0.0
    machine: str = ""
    #: ``--accept-implausible``: results failing a plausibility gate are kept (and recorded) instead of failing
    accept_implausible: bool = False

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
