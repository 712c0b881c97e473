"""The depth error linear in the image position from a board dataset, folded into a wall calibration.

``tilt_from_boards(path, calibration)``: the board poses of a board dataset (``board.json`` +
``poses/``, e.g. the IR intrinsics captures) are corrected by ``calibration`` exactly as a user's
frames are, each board's plane is solved from its IR corners, and the depth error linear in the
image position that the walls could not show is fitted over the views
(:func:`tofmetry.calibrate.fit_depth_tilt`) and folded into the calibration
(:func:`tofmetry.calibrate.with_depth_tilt`, shrunk by its signal-to-noise) unless views kept out of
the fit contradict it (:attr:`tofmetry.calibrate.TiltFit.foldable`); then the calibration is
returned as it was, with the reason in the notes. Without a calibration it measures the raw
sensor's tilt (nothing is folded in).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tofmetry.calibrate import DepthCalibration, TiltFit, apply_depth_calibration, fit_depth_tilt, with_depth_tilt
from tofmetry.calibrate.board import BoardSamples, board_samples, collect_grids
from tofmetry.errors import EstimationError, InputError
from tofmetry.io.board_dataset import BoardDataset
from tofmetry.pipelines._common import _adv
from tofmetry.pipelines.board import resolve_board
from tofmetry.sensor import CameraIntrinsics


@dataclass
class TiltRun:
    """Result of :func:`tilt_from_boards`.

    Attributes
    ----------
    fit : TiltFit (tilt, its standard error, per-view tilts, model, skipped views)
    calibration : the calibration with the tilt folded in, or, when the held-out views contradict
        the tilt (or are too few to check it), the given one unchanged but for
        ``diagnostics["tilt_not_folded"]`` (the fit and the reason); None when none was given
    folded : whether the tilt was folded into ``calibration``
    n_poses : poses in the dataset; notes : what was skipped and why; seconds : run time
    """

    fit: TiltFit
    calibration: DepthCalibration | None
    n_poses: int
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0
    folded: bool = False

    def to_dict(self) -> dict:
        return {"tilt": self.fit.to_dict(), "folded": self.folded, "n_poses": self.n_poses, "notes": list(self.notes),
                "seconds": round(self.seconds, 2)}


def tilt_from_boards(path: Path, calibration: DepthCalibration | None = None,
                     intrinsics: CameraIntrinsics | None = None, board=None, advance=None) -> TiltRun:
    """Fit the tilt on the board dataset ``path`` (module docstring).

    Parameters
    ----------
    path : board dataset folder (``board.json`` + ``poses/``)
    calibration : the wall calibration to complete (its intrinsics are used), or None (raw depth)
    intrinsics : IR/depth intrinsics when there is no calibration (default: the dataset's intrinsics.json)
    board : None (``board.json``'s), or a ``BoardSpec`` / ``CharucoBoard`` used instead
    advance : optional progress callable, once per pose

    Raises
    ------
    InputError : no poses, no intrinsics, or intrinsics of another size than the depth
    EstimationError : fewer than 4 usable board views
    """
    t0 = time.perf_counter()
    adv = _adv(advance)
    path = Path(path)
    ds = BoardDataset(path)
    if len(ds) == 0:
        raise InputError(f"{path}: no poses/ in the board dataset")
    intr = calibration.intrinsics if calibration is not None else (intrinsics or ds.intrinsics())
    if intr is None:
        raise InputError(f"{path}: no intrinsics: give a calibration, --intrinsics, or an intrinsics.json in the dataset")
    brd, sq, _ = resolve_board(ds, board)
    names = list(ds.names)
    samples, used, notes = [], [], []
    for i, name in enumerate(names):
        pose = ds.load_poses([i])
        grids = collect_grids(pose, brd)[0][0]
        depth, ir, _ = pose[0]
        adv()
        if not grids:
            notes.append(f"pose {name}: no board found in the IR image")
            continue
        if depth.shape != intr.shape:
            raise InputError(f"{path / 'poses' / name}: depth {depth.shape} does not match the intrinsics {intr.shape}")
        d = apply_depth_calibration(depth, calibration) if calibration is not None else depth.astype(np.float64)
        parts = []
        for g in grids:
            try:
                parts.append(board_samples(d, ir, g, brd, sq, intr))
            except EstimationError as exc:
                notes.append(f"pose {name}: a board skipped ({exc})")
        if parts:
            samples.append(BoardSamples.concat(parts))
            used.append(name)
    fit = fit_depth_tilt(samples, intr, used)
    notes += [f"pose {n}: {why}" for n, why in fit.skipped]
    folded = calibration is not None and fit.foldable
    cal = calibration
    if folded:
        cal = with_depth_tilt(calibration, fit)
        if not fit.confirmed:
            w = fit.shrink
            notes.append(f"tilt folded in at ({w[0]:.2f}, {w[1]:.2f}) of its fit (its signal-to-noise), not confirmed "
                         f"by the views kept out: {fit.held_out['reason']}")
    elif calibration is not None:
        notes.append(f"tilt not folded in: {fit.held_out['reason']}")
        cal = replace(calibration, diagnostics={**(calibration.diagnostics or {}), "tilt_not_folded": fit.to_dict()})
    return TiltRun(fit, cal, len(names), notes, time.perf_counter() - t0, folded)
