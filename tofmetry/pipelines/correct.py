"""Pipeline ``correct``: a capture + a depth calibration -> the corrected capture (same format).

Frames stream through :func:`~tofmetry.pipelines.frame_stream.stream_frames` (PNG decoding and
encoding in threads, the uint16 correction kernel of :class:`~tofmetry.pipelines.frame_path.FramePath`
in between), so the memory used does not depend on the number of frames; the output folder is
written by :class:`~tofmetry.io.CaptureWriter` and appears only when complete.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from tofmetry.calibrate import DepthCalibration
from tofmetry.io import Capture, CaptureMeta, CaptureWriter
from tofmetry.pipelines.paths import refuse_inside_inputs
from tofmetry.pipelines.calibration_files import load_calibration
from tofmetry.pipelines.frame_path import FramePath
from tofmetry.pipelines.frame_stream import stream_frames
from tofmetry.pipelines.plausibility import check_support, enforce


@dataclass
class CorrectRun:
    """Result of :func:`correct_capture`.

    Attributes
    ----------
    output : the corrected capture folder
    n_frames : frames corrected
    shape : (H, W) of the frames
    outside_range : valid depth samples outside the calibration's support (corrected by its
        fallback; left uncorrected by a calibration without a support map)
    valid_range_mm : (lo, hi) depths [mm] the calibration was fitted on (its support's span)
    calibration : the DepthCalibration applied
    float32 : frames written as float32 ``.npy`` (else uint16 PNG, rounded to 1 mm)
    seconds : wall time of the run [s]
    valid : valid depth samples of all frames
    plausibility : the plausibility gate's record (every valid sample outside the support fails it)
    """

    output: Path
    n_frames: int
    shape: tuple[int, int]
    outside_range: int
    valid_range_mm: tuple[float, float]
    float32: bool
    seconds: float
    calibration: object = None
    valid: int = 0
    plausibility: dict = field(default_factory=dict)

    @property
    def outside_share(self) -> float:
        """``outside_range`` as a share of all pixels of all frames."""
        return self.outside_range / max(1, self.n_frames * self.shape[0] * self.shape[1])

    def to_dict(self) -> dict:
        return {"output": str(self.output), "n_frames": self.n_frames, "shape": list(self.shape),
                "outside_range": self.outside_range, "outside_share": self.outside_share,
                "valid_range_mm": list(self.valid_range_mm), "float32": self.float32, "seconds": self.seconds,
                "valid": self.valid, "plausibility": self.plausibility}


def correct_capture(capture: str | os.PathLike | Capture, calibration: str | os.PathLike | DepthCalibration,
                    output: str | os.PathLike, *, float32: bool = False, force: bool = False,
                    workers: int | None = None, advance: Callable[[], None] | None = None,
                    accept_implausible: bool = False) -> CorrectRun:
    """Apply a depth calibration to every frame of a capture and write the corrected capture.

    Parameters
    ----------
    capture : capture folder (or an open :class:`~tofmetry.io.Capture`); never modified
    calibration : calibration file (``.npz``) or a :class:`~tofmetry.calibrate.DepthCalibration`
    output : new capture folder; IR and colour frames are copied unchanged, ``capture.json``
        gets the calibration's intrinsics and the provenance
    float32 : write float32 ``.npy`` depth frames [mm] (unrounded) instead of uint16 PNG
    force : replace an existing output folder
    workers : decoding/encoding threads (default: one per core, at least 2)
    advance : optional progress callable, called once per frame
    accept_implausible : write the output even when every valid depth sample lies outside the
        calibration's support (recorded in the output's ``capture.json``)

    Returns
    -------
    CorrectRun

    Raises
    ------
    InputError
        ``output`` is the input capture or lies inside it, or exists without ``force``.
    ImplausibleResultError
        Every valid depth sample lies outside the calibration's support (nothing is written).
    SensorMismatchError
        The calibration was made for another sensor or frame size.
    """
    t0 = time.perf_counter()
    cap = capture if isinstance(capture, Capture) else Capture(capture)
    output = Path(output)
    refuse_inside_inputs(output, cap.path)
    cal = calibration if isinstance(calibration, DepthCalibration) else load_calibration(calibration)
    cal.check_compatible(sensor=cap.sensor, shape=cap.shape)
    path = FramePath(cal.intrinsics, cal)
    source = "in-memory calibration" if isinstance(calibration, DepthCalibration) else str(calibration)
    meta = CaptureMeta(sensor=cap.sensor, depth_unit_mm=1.0, intrinsics=cal.intrinsics,
                       timestamps_s=cap.meta.timestamps_s,
                       extra={**(cap.meta.extra or {}), "depth_calibration": source, "corrected_from": str(cap.path)})
    outside = valid = 0

    def process(i: int, depth: np.ndarray) -> np.ndarray:
        nonlocal outside, valid
        outside += path.outside_range(depth)
        valid += int(np.count_nonzero(depth))
        if float32:
            return np.where(depth > 0, path.correct(depth), 0).astype(np.float32)
        return path.correct_u16(depth)

    with CaptureWriter(output, meta, force=force) as writer:
        stream_frames(len(cap), cap.depth, process, writer.put, workers=workers, advance=advance)
        writer.copy_frames("ir", cap.ir_files)
        writer.copy_frames("color", cap.color_files)
        lo, hi = cal.support_range_mm
        gate = enforce(check_support(outside, valid, (lo, hi), str(cap.path)), f"correcting {cap.path}",
                       accept_implausible)
        if gate["accepted"]:
            meta.extra["plausibility"] = gate
    return CorrectRun(output=output, n_frames=len(cap), shape=cap.shape, outside_range=outside,
                      valid_range_mm=(float(lo), float(hi)), float32=float32, seconds=time.perf_counter() - t0,
                      calibration=cal, valid=valid, plausibility=gate)
