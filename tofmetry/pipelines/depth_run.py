"""The result of a depth calibration run (:class:`DepthRun`) and its report writer."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.calibrate import DepthCalibration
from tofmetry.calibrate import figures as F
from tofmetry.io import atomic_write_json, write_intrinsics
from tofmetry._shared.figures import save_png
from tofmetry.sensor import CameraIntrinsics


@dataclass(eq=False)
class DepthRun:
    """Depth calibration of a dataset.

    Attributes
    ----------
    kind : "wall" or "board"
    calibration : DepthCalibration (save with ``tofmetry.io.calibration_file.save_calibration``)
    intrinsics, intrinsics_source : the IR/depth intrinsics used and where they came from
    sensor : sensor name
    rows : per station (wall) / per pose (board) table rows (list of dict)
    fit : fit diagnostics (wall: summary, history; board: held-out cases none / iai_shift /
        constant_refit / model, squares used, intrinsics fit)
    seconds : wall-clock time
    notes : list of str (e.g. "no intrinsics given: typical profile used", skipped stations)
    """

    kind: str
    calibration: DepthCalibration
    intrinsics: CameraIntrinsics
    intrinsics_source: str
    sensor: str
    rows: list
    fit: dict
    seconds: float
    notes: list = field(default_factory=list)
    path: str = ""
    # figure material (not serialised)
    range_points: np.ndarray | None = None
    frame_points: list | None = None
    board_result: object = None
    intrinsics_run: object = None

    @property
    def stations(self) -> list:
        """Alias of ``rows`` (per station / per pose table rows)."""
        return self.rows

    @property
    def plausibility(self) -> dict:
        """The plausibility gate's record ``{"checked", "accepted", "findings"}`` (empty if not checked)."""
        return self.fit.get("plausibility") or {}

    def to_dict(self) -> dict:
        return {"plausibility": self.plausibility, "kind": self.kind, "dataset": self.path, "sensor": self.sensor,
                "intrinsics": self.intrinsics.to_dict(),
                "intrinsics_source": self.intrinsics_source, "summary": self.calibration.summary(), "rows": self.rows,
                "fit": self.fit, "seconds": self.seconds, "notes": self.notes}


def write_depth_report(run: DepthRun, folder: Path) -> list[Path]:
    """``fit.json`` + wall: ``range_curve.png`` (Fig. 7a), ``std_vs_range.png`` (Fig. 7b);
    board: ``board_calibration.png`` and ``intrinsics.json`` (the intrinsics used)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = [atomic_write_json(folder / "fit.json", run.to_dict())]
    if run.kind == "wall":
        out.append(save_png(F.fig_range_curve(run.calibration, run.range_points, run.frame_points),
                             folder / "range_curve.png"))
        out.append(save_png(F.fig_std_vs_range([r["distance_mm"] for r in run.rows], [r["center_std_mm"] for r in run.rows],
                                                [r["pixel_std_median_mm"] for r in run.rows]), folder / "std_vs_range.png"))
    else:
        out.append(save_png(F.fig_board_calibration(run.board_result), folder / "board_calibration.png"))
        out.append(write_intrinsics(folder / "intrinsics.json", run.intrinsics, sensor=run.sensor,
                                    source=run.intrinsics_source))
    return out

