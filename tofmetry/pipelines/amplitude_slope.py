"""Pipeline: the sensor's amplitude-bias coefficient ``k`` from grey-level board captures.

Dark surfaces read long by ``k ln(A_white / A)`` (study §3.3.1: black, 1/6 of the white
amplitude, +12 mm, so k = 6.7 mm per ln unit on the study's sensor). ``k`` differs from unit to
unit; a model corrected with another sensor's ``k`` lies inside or outside its reference by the
difference times the object's ``ln(A_white / A)``, and its scale follows (the family's sensors,
with k + k_abs of 6.8-9.2, left bars and bunnies 1-2 mm inside with the study's 6.7).

Each board capture (a grey-level checkerboard seen frontally, depth + IR; ``tofmetry simulate
materials`` writes one) is corrected with the depth calibration frame by frame, then
:func:`tofmetry.assess.assess_materials` fits ``bias = k ln(A_ref / A) + c`` over its squares
against a plane through the white ones. Correcting first matters: on raw depth the calibration's
per-pixel deformation across the board is read as amplitude bias (measured on three family
sensors: raw 9.2-10.5 +- 1.2, corrected 9.05-9.25 +- 0.1, true 9.23 mm per ln unit).

Several boards (other distances, other places in the image) are combined by inverse-variance
weighting; their scatter beyond their standard errors inflates the uncertainty (Birge ratio). A
bias common to all boards is not seen by their scatter: the fit's model (a bias linear in
``ln(A_ref / A)``, a plane through the white squares, a ``cos^e`` amplitude fall-off) leaves one.
On 20 fresh family sensors (two boards each, 0.8 and 1.2 m) measured minus true ``k + k_abs`` had
an RMS of 0.11 and a worst of 0.24 mm per ln unit, while the boards' own sigma was 0.01-0.18: 6
of 20 were beyond 3 of those sigmas. ``model_sigma_mm_per_ln`` (0.15) is therefore added in
quadrature. It is a virtual sensor's figure; a real sensor whose bias is not linear in
``ln A`` leaves more, which boards at other distances (and ``dk`` in the scan) show.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.assess import assess_materials, regions_from_dict
from tofmetry.calibrate import DepthCalibration, apply_depth_calibration
from tofmetry.errors import EstimationError, InputError
from tofmetry.io import Capture, read_json


@dataclass
class AmplitudeSlope:
    """The amplitude-bias coefficient measured on grey-level boards.

    Attributes
    ----------
    k_mm_per_ln : combined coefficient k [mm per ln unit of A_white / A]
    sigma_mm_per_ln : its standard uncertainty (inflated by the boards' scatter when > 1 board)
    boards : per board: ``path``, ``distance_mm`` (median corrected depth of its squares),
        ``k_mm_per_ln``, ``se_mm_per_ln``, ``n_squares`` (used in the fit), ``ln_ratio_span``
    calibrated : whether the boards' depth was corrected with a depth calibration first
    notes : what the user should know (e.g. an uncorrected board)
    sigma_boards_mm_per_ln : the boards' own part of ``sigma`` (without the model's)
    """

    k_mm_per_ln: float
    sigma_mm_per_ln: float
    boards: list = field(default_factory=list)
    calibrated: bool = False
    notes: list = field(default_factory=list)
    sigma_boards_mm_per_ln: float = float("nan")

    def to_dict(self) -> dict:
        return {"k_mm_per_ln": round(self.k_mm_per_ln, 4), "sigma_mm_per_ln": round(self.sigma_mm_per_ln, 4),
                "sigma_boards_mm_per_ln": round(self.sigma_boards_mm_per_ln, 4),
                "boards": self.boards, "calibrated": self.calibrated, "notes": list(self.notes)}


def combine_slopes(k: np.ndarray, se: np.ndarray) -> tuple[float, float]:
    """Inverse-variance mean of per-board coefficients and its uncertainty.

    Parameters
    ----------
    k, se : (B,) coefficients and their standard errors [mm per ln unit], se > 0

    Returns
    -------
    (k, sigma) [mm per ln unit]: sigma is the weighted mean's standard error, times the Birge
    ratio ``sqrt(chi2 / (B - 1))`` when the boards scatter more than their errors say.
    """
    k, se = np.asarray(k, float), np.asarray(se, float)
    if k.size == 0 or k.shape != se.shape or not np.all(se > 0):
        raise InputError(f"combine_slopes: need as many positive standard errors as coefficients, found {k.size} "
                         f"coefficients and standard errors {se.tolist()}")
    w = 1.0 / se ** 2
    mean = float((w * k).sum() / w.sum())
    sigma = float(1.0 / math.sqrt(w.sum()))
    if k.size > 1:
        birge = math.sqrt(float((w * (k - mean) ** 2).sum()) / (k.size - 1))
        sigma *= max(1.0, birge)
    return mean, sigma


def _board_capture(path: Path) -> tuple[Capture, Path | None]:
    """The capture of a board folder (``<dir>/capture`` or ``<dir>`` itself) and its ``regions.json``."""
    if not path.is_dir():
        raise InputError(f"amplitude board {path}: not a folder (expected a capture of a grey-level board, depth + IR)")
    cap_dir = path / "capture" if (path / "capture").is_dir() else path
    regions = path / "regions.json"
    return Capture(cap_dir), (regions if regions.is_file() else None)


#: the amplitude-bias fit model's own bias common to all boards [mm per ln unit] (module docstring)
MODEL_SIGMA_MM_PER_LN = 0.15


def amplitude_slope_from_boards(boards: list[str | os.PathLike], calibration: DepthCalibration | None = None,
                                advance=None, model_sigma_mm_per_ln: float = MODEL_SIGMA_MM_PER_LN) -> AmplitudeSlope:
    """Measure the amplitude-bias coefficient ``k`` on grey-level board captures.

    Parameters
    ----------
    boards : board folders: a capture (depth + IR) of a grey-level checkerboard seen frontally,
        or a folder holding ``capture/`` and optionally ``regions.json`` (else the squares are
        found from the IR image)
    calibration : depth calibration applied to every frame first (strongly advised: without it
        the per-pixel deformation across the board biases ``k``)
    advance : optional ``advance()`` called once per board
    model_sigma_mm_per_ln : the fit model's bias common to all boards, added in quadrature to the
        boards' combined uncertainty [mm per ln unit] (see the module docstring)

    Returns
    -------
    AmplitudeSlope

    Raises
    ------
    InputError : a board folder is missing, has no IR, or its shape differs from the calibration's
    EstimationError : no board gave a fit (its reason named)
    """
    if not boards:
        raise InputError("amplitude boards: give at least one grey-level board capture")
    rows, ks, ses, failures = [], [], [], []
    for b in boards:
        path = Path(b)
        cap, regions_file = _board_capture(path)
        if not cap.has_ir:
            raise InputError(f"amplitude board {path}: the capture has no IR frames (the fit needs the amplitude)")
        intr, _ = cap.intrinsics(None if calibration is None else calibration.intrinsics)
        if calibration is not None and tuple(calibration.intrinsics.shape) != tuple(cap.shape):
            raise InputError(f"amplitude board {path}: frames are {cap.shape}, the depth calibration is for "
                             f"{calibration.intrinsics.shape}")
        frames = cap.depth_stack().astype(np.float64)
        if calibration is not None:
            frames = np.stack([apply_depth_calibration(f, calibration) for f in frames])
        regs = None if regions_file is None else regions_from_dict(read_json(regions_file, "regions"), cap.shape,
                                                                    str(regions_file))
        try:
            res = assess_materials(frames, regs, intr=intr, ir=cap.ir_mean(), auto_grey_board=regs is None)
        except EstimationError as exc:
            failures.append(f"{path}: {exc}")
            continue
        finally:
            if advance is not None:
                advance()
        if not (np.isfinite(res.slope_mm_per_ln) and res.slope_se_mm_per_ln > 0):
            failures.append(f"{path}: no amplitude-bias fit ({'; '.join(res.notes) or 'too few usable squares'})")
            continue
        ratio = [r.ln_amp_ratio for r in res.regions if not r.erratic]
        z = frames[frames > 0]
        rows.append({"path": str(path), "distance_mm": round(float(np.median(z)), 1) if z.size else None,
                     "k_mm_per_ln": round(float(res.slope_mm_per_ln), 4),
                     "se_mm_per_ln": round(float(res.slope_se_mm_per_ln), 4), "n_squares": int(res.n_fit),
                     "ln_ratio_span": round(float(np.ptp(ratio)), 3) if ratio else None})
        ks.append(res.slope_mm_per_ln)
        ses.append(res.slope_se_mm_per_ln)
    if not ks:
        raise EstimationError("amplitude boards: no board gave an amplitude-bias fit: " + "; ".join(failures))
    k, sigma_boards = combine_slopes(np.array(ks), np.array(ses))
    sigma = math.hypot(sigma_boards, model_sigma_mm_per_ln)
    notes = [f"left out {f}" for f in failures]
    if calibration is None:
        notes.append("boards not corrected by a depth calibration: the per-pixel deformation across a board "
                     "biases k (give the scan's calibration)")
    if len(ks) == 1:
        notes.append(f"one board: sigma is its fit's standard error and the fit model's {model_sigma_mm_per_ln:g}; "
                     "boards at two distances show whether k holds across the range")
    return AmplitudeSlope(k, sigma, rows, calibration is not None, notes, sigma_boards)
