"""Pipeline ``filter``: a capture -> a new capture with its flying (mixed) pixels set to 0.

Frames stream through :func:`~tofmetry.pipelines.frame_stream.stream_frames` (depth, IR and
colour decoded and encoded in threads, the detector of :mod:`tofmetry.assess.flying` in
between); the output appears only when complete (:class:`~tofmetry.io.CaptureWriter`).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from tofmetry.assess import FlyingPixelParams, remove_flying_pixels
from tofmetry.io import Capture, CaptureMeta, CaptureWriter
from tofmetry.pipelines.paths import refuse_inside_inputs
from tofmetry.pipelines.frame_stream import stream_frames
from tofmetry.sensor import CameraIntrinsics


@dataclass
class FilterRun:
    """Result of :func:`filter_capture`.

    Attributes
    ----------
    output : the new capture folder
    n_frames : frames filtered
    removed : flying pixels set to 0, all frames together
    valid : valid pixels of the input, all frames together
    params : the detector's thresholds
    seconds : wall time [s]
    """

    output: Path
    n_frames: int
    removed: int
    valid: int
    params: FlyingPixelParams
    seconds: float

    @property
    def removed_share(self) -> float:
        """Removed pixels as a share of the valid ones."""
        return self.removed / max(self.valid, 1)

    def to_dict(self) -> dict:
        return {"output": str(self.output), "n_frames": self.n_frames, "removed": self.removed, "valid": self.valid,
                "removed_share": self.removed_share, "params": self.params.to_dict(), "seconds": self.seconds}


def filter_capture(capture: str | os.PathLike | Capture, output: str | os.PathLike,
                   params: FlyingPixelParams | None = None, *, intrinsics: CameraIntrinsics | None = None,
                   force: bool = False, workers: int | None = None,
                   advance: Callable[[], None] | None = None) -> FilterRun:
    """Remove the flying pixels of every frame of a capture; IR and colour frames are kept.

    Parameters
    ----------
    capture : capture folder (or an open :class:`~tofmetry.io.Capture`); never modified
    output : new capture folder (``capture.json`` records the detector's thresholds)
    params : detector thresholds (default :class:`~tofmetry.assess.FlyingPixelParams`)
    intrinsics : intrinsics overriding the capture's (the detector needs the focal length)
    force : replace an existing output folder
    workers : decoding/encoding threads (default: one per core, at least 2)
    advance : optional progress callable, called once per frame

    Returns
    -------
    FilterRun
    """
    t0 = time.perf_counter()
    cap = capture if isinstance(capture, Capture) else Capture(capture)
    output = Path(output)
    refuse_inside_inputs(output, cap.path)
    intr, _ = cap.intrinsics(intrinsics)
    p = params or FlyingPixelParams()
    m = cap.meta
    meta = CaptureMeta(sensor=m.sensor, depth_unit_mm=1.0, intrinsics=m.intrinsics, timestamps_s=m.timestamps_s,
                       extra={**m.extra, "filtered": {"flying_pixels": p.to_dict(), "source": str(cap.path)}})
    counts = {"removed": 0, "valid": 0}

    def read(i: int):
        return (cap.depth(i), cap.ir(i) if cap.has_ir else None, cap.color(i) if cap.has_color else None)

    def process(i: int, frame):
        depth, ir, color = frame
        kept = remove_flying_pixels(depth, intr, p, ir=ir)
        n_valid = int(np.count_nonzero(depth))
        counts["valid"] += n_valid
        counts["removed"] += n_valid - int(np.count_nonzero(kept))
        return kept, ir, color

    with CaptureWriter(output, meta, force=force) as writer:
        stream_frames(len(cap), read, process, lambda i, f: writer.put(i, *f), workers=workers, advance=advance)
    return FilterRun(output=output, n_frames=len(cap), removed=counts["removed"], valid=counts["valid"], params=p,
                     seconds=time.perf_counter() - t0)
