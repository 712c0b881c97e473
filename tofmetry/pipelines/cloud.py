"""Pipeline ``cloud``: a capture [+ averaging] [+ calibration] [+ colour] -> a point cloud (PLY).

One frame: the fused correct + undistort + back-project kernel of
:class:`~tofmetry.pipelines.frame_path.FramePath` (the identity calibration's without one).
Averaging: the frames are decoded in threads (:mod:`.frame_stream`), each is corrected by the same
path's uint16 kernel, and the robust temporal mean of the corrected frames is back-projected in
float (it holds sub-millimetre values).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from tofmetry.calibrate import DepthCalibration
from tofmetry.errors import InputError
from tofmetry.io import Capture, write_ply
from tofmetry.pipelines.paths import refuse_inside_inputs
from tofmetry.pipelines.calibration_files import load_calibration
from tofmetry.pipelines.frame_path import FramePath
from tofmetry.pipelines.frame_stream import stream_frames
from tofmetry.pipelines.plausibility import check_support, enforce
from tofmetry.io.colour_calibration import capture_colour_calibration
from tofmetry.pointcloud import amplitude_colors, colour_points, robust_mean_depth
from tofmetry.sensor import CameraIntrinsics


@dataclass
class CloudRun:
    """Result of :func:`capture_cloud`.

    Attributes
    ----------
    points : (N, 3) float32 [m], camera frame (x right, y down, z forward)
    colors : (N, 3) uint8 RGB or None (colour frames, else IR amplitude, else none)
    index : (N,) int64 flat pixel index of each point
    n_frames : frames used (1, or all when averaged)
    intrinsics : CameraIntrinsics used for the rays; intrinsics_source : where they came from
    calibrated : a depth calibration was applied; averaged : the frames were averaged
    output : the PLY written, or None
    seconds : wall time [s]
    outside_support : valid pixels (of the frame, or of the mean) outside the calibration's support,
        corrected by its fallback (0 without calibration)
    plausibility : the plausibility gate's record (every valid pixel outside the support fails it)
    colored : (N,) bool, the colour camera sees the point (colour frames only, else None): the
        others have *no colour* (RGB 0 and ``colored`` 0 in the PLY), not black
    color_summary : counts of the colouring (points, colored, out_of_view, occluded,
        share_colored) and where the colour camera's calibration came from; empty without colour
    """

    points: np.ndarray
    colors: np.ndarray | None
    index: np.ndarray
    n_frames: int
    intrinsics: CameraIntrinsics
    intrinsics_source: str
    calibrated: bool
    averaged: bool
    output: Path | None
    seconds: float
    outside_support: int = 0
    plausibility: dict = field(default_factory=dict)
    colored: np.ndarray | None = None
    color_summary: dict = field(default_factory=dict)

    @property
    def share_colored(self) -> float | None:
        """Share of the points the colour camera coloured (None without colour frames)."""
        return self.color_summary.get("share_colored")

    def to_dict(self) -> dict:
        return {"points": int(len(self.points)), "colored": self.colors is not None, "n_frames": self.n_frames,
                "intrinsics": self.intrinsics.to_dict(), "intrinsics_source": self.intrinsics_source,
                "calibrated": self.calibrated, "averaged": self.averaged,
                "output": None if self.output is None else str(self.output), "seconds": self.seconds,
                "outside_support": self.outside_support, "plausibility": self.plausibility,
                "color": self.color_summary}


def _mean_corrected_depth(cap: Capture, path: FramePath, workers: int | None,
                          advance: Callable[[], None] | None) -> np.ndarray:
    """Robust temporal mean [mm] of all frames (decoded in threads), each corrected by ``path`` first."""
    stack = np.empty((len(cap), *cap.shape), np.uint16)

    def keep(i: int, depth: np.ndarray) -> None:
        stack[i] = depth

    stream_frames(len(cap), cap.depth, keep, workers=workers, advance=advance)
    return robust_mean_depth(stack, correct=path.correct if path.calibrated else None)


def capture_cloud(capture: str | os.PathLike | Capture, output: str | os.PathLike | None = None, *,
                  average: bool = False, calibration: str | os.PathLike | DepthCalibration | None = None,
                  intrinsics: CameraIntrinsics | None = None, color: bool = False, frame: int = 0,
                  undistort: bool = True, force: bool = False, workers: int | None = None,
                  advance: Callable[[], None] | None = None, accept_implausible: bool = False) -> CloudRun:
    """The point cloud of a capture, optionally written as a binary PLY [m].

    Parameters
    ----------
    capture : capture folder (or an open :class:`~tofmetry.io.Capture`)
    output : PLY file to write (atomically), or None
    average : robust temporal mean of all frames (else one frame)
    calibration : calibration file or :class:`~tofmetry.calibrate.DepthCalibration` to apply
    intrinsics : intrinsics overriding the capture's (and the calibration's)
    color : colour from the colour frames (else IR amplitude, when the capture has IR)
    frame : frame index when not averaging (also the colour frame)
    undistort : undistorted rays (default) or the plain pinhole
    force : replace an existing output
    workers : decoding threads when averaging (default: one per core, at least 2)
    advance : optional progress callable, called once per frame read when averaging
    accept_implausible : write the cloud even when every valid pixel lies outside the calibration's
        support (the PLY's header then says so in a comment)

    Returns
    -------
    CloudRun

    Raises
    ------
    InputError
        ``frame`` outside the capture, ``output`` inside the capture folder, or ``output`` exists
        without ``force``.
    ImplausibleResultError
        Every valid pixel lies outside the calibration's support (nothing is written).
    SensorMismatchError
        The calibration was made for another sensor or frame size.
    """
    t0 = time.perf_counter()
    if output is not None and Path(output).exists() and not force:
        raise InputError(f"output {output} exists; pass --force to overwrite it")
    cap = capture if isinstance(capture, Capture) else Capture(capture)
    if output is not None:
        refuse_inside_inputs(output, cap.path)
    intr, source = cap.intrinsics(intrinsics)
    cal = None
    if calibration is not None:
        cal = calibration if isinstance(calibration, DepthCalibration) else load_calibration(calibration)
        cal.check_compatible(sensor=cap.sensor, shape=cap.shape)
        if intrinsics is None:
            intr, source = cal.intrinsics, "calibration"
    path = FramePath(intr, cal, undistort)
    if not average and not 0 <= frame < len(cap):
        raise InputError(f"frame {frame} outside 0..{len(cap) - 1} of {cap.path}")
    if average:
        mean = _mean_corrected_depth(cap, path, workers, advance)
        pts, idx = path.backproject(mean)
        pts = pts.astype(np.float32)
        outside = path.outside_range(np.nan_to_num(mean)) if cal is not None else 0
    else:
        depth = cap.depth(frame)
        pts, idx = path.points(depth), path.index(depth)
        outside = path.outside_range(depth)
    cols, colored, csum, scalars = None, None, {}, None
    if color and cap.has_color:
        cintr, ext, csrc = capture_colour_calibration(cap)
        res = colour_points(pts, cap.color(frame), cintr, ext, depth_focal_px=0.5 * (intr.fx + intr.fy))
        cols, colored = res.colors, res.colored
        csum = {**res.summary(), "calibration": csrc}
        scalars = {"colored": colored.astype(np.float32)}
    elif cap.has_ir:
        ir = cap.ir_mean() if average else cap.ir(frame)
        cols = amplitude_colors(ir.ravel()[idx])
    gate = {}
    if cal is not None:
        gate = enforce(check_support(outside, len(pts), cal.support_range_mm, str(cap.path)),
                       f"the cloud of {cap.path}", accept_implausible)
    comments = [f"accepted implausible: {f}" for f in gate.get("findings", [])] if gate.get("accepted") else None
    out = None if output is None else write_ply(output, pts, colors=cols, scalars=scalars, comments=comments)
    return CloudRun(points=pts, colors=cols, index=idx, n_frames=len(cap) if average else 1, intrinsics=intr,
                    intrinsics_source=source, calibrated=cal is not None, averaged=average, output=out,
                    seconds=time.perf_counter() - t0, outside_support=outside, plausibility=gate,
                    colored=colored, color_summary=csum)

