"""Drive a session with a device: read frames, feed them, show the status, pass requests to the operator.

:func:`run_recording` is what ``tofmetry record`` calls. The prompt callback answers the session's
requests: in the terminal it is ``input()``; a test plays the operator (it moves the virtual device
and types the reference distances). A corrected depth preview is written as ``OUT/preview.png``
(atomically, at most once a second of device time).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from tofmetry.calibrate import DepthCalibration, apply_depth_calibration
from tofmetry.devices.base import Device, DeviceFrame
from tofmetry.errors import InputError
from tofmetry.io import atomic_write_bytes, atomic_write_json
from tofmetry.record.session import Request, Session, Status


def preview_image(depth: np.ndarray, calibration: DepthCalibration | None = None, range_mm=(400.0, 4500.0)) -> np.ndarray:
    """(H, W, 3) uint8 BGR colour image of the (corrected) depth; invalid pixels black.

    Parameters
    ----------
    depth : (H, W) uint16 depth Z [mm]
    calibration : applied first when given (:func:`tofmetry.calibrate.apply_depth_calibration`)
    range_mm : depths mapped to the ends of the colour scale [mm]
    """
    z = apply_depth_calibration(depth, calibration) if calibration is not None else depth.astype(np.float32)
    lo, hi = range_mm
    g = np.clip((np.asarray(z, np.float32) - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8)
    img = cv2.applyColorMap(g, cv2.COLORMAP_TURBO)
    img[depth == 0] = 0
    return img


class PreviewWriter:
    """Write ``path`` (PNG) from a frame at most every ``every_s`` of device time."""

    def __init__(self, path: Path, calibration: DepthCalibration | None = None, every_s: float = 1.0):
        self.path, self.calibration, self.every_s = Path(path), calibration, every_s
        self._last = None
        self.written = 0

    def update(self, frame: DeviceFrame, force: bool = False) -> None:
        if not force and self._last is not None and frame.timestamp_s - self._last < self.every_s:
            return
        ok, buf = cv2.imencode(".png", preview_image(frame.depth, self.calibration))
        if ok:
            atomic_write_bytes(self.path, buf.tobytes())
            self._last = frame.timestamp_s
            self.written += 1


@dataclass
class RecordResult:
    """What a recording did: its summary (also ``OUT/record.json``), frames read, seconds, how it ended."""

    summary: dict
    frames_read: int
    seconds: float
    ended: str        # "done" | "stream ended" | "interrupted"


def run_recording(device: Device, session: Session, prompt: Callable[[Request], str | None], *,
                  on_status: Callable[[Status, DeviceFrame | None], None] | None = None,
                  calibration: DepthCalibration | None = None, max_frames: int | None = None,
                  preview_every_s: float = 1.0) -> RecordResult:
    """Run ``session`` on ``device`` until it is done, the stream ends or ``max_frames`` frames were read.

    Parameters
    ----------
    device : a :class:`~tofmetry.devices.base.Device` (opened here if it is not open; closed at the end)
    session : one of :mod:`tofmetry.record.protocols`
    prompt : answers a :class:`Request` (``None``: confirmed); raising ``KeyboardInterrupt`` stops cleanly
    on_status : called after every frame (live display)
    calibration : depth calibration for the preview
    max_frames : safety limit on frames read

    Returns
    -------
    RecordResult; the session's files are closed whatever happens (a recording is kept as far as it went).
    """
    t0 = time.perf_counter()
    n = 0
    ended = "done"
    preview = PreviewWriter(session.out / "preview.png", calibration, preview_every_s)
    opened_here = not device.is_open
    try:
        if opened_here:
            device.open()
        st = session.start(device.info)
        if st is not None:
            _handle(st, None, session, prompt, on_status)
        while not session.done:
            if max_frames is not None and n >= max_frames:
                ended = "frame limit"
                break
            frame = device.read()
            if frame is None:
                ended = "stream ended"
                break
            n += 1
            st = session.feed(frame)
            preview.update(frame)
            _handle(st, frame, session, prompt, on_status)
    except KeyboardInterrupt:
        ended = "interrupted"
    finally:
        summary = session.finish()
        if opened_here:
            device.close()
    summary = dict(summary, ended=ended, frames_read=n, preview=str(preview.path) if preview.written else None)
    if session.out.is_dir():
        atomic_write_json(session.out / "record.json", summary)
    return RecordResult(summary, n, time.perf_counter() - t0, ended)


def _handle(st: Status, frame, session: Session, prompt, on_status) -> None:
    if on_status is not None:
        on_status(st, frame)
    if st.request is not None:
        session.answer(st.request, prompt(st.request))


def answers_from(distances_mm: list[float] | None, ask: Callable[[str], str]) -> Callable[[Request], str | None]:
    """A prompt: reference distances from a list (``--distances``) first, else ``ask(text)``; moves are
    confirmed with ``ask`` (press Enter)."""
    queue = list(distances_mm or [])

    def prompt(req: Request) -> str | None:
        if req.kind == "distance":
            if queue:
                return str(queue.pop(0))
            return ask(req.text + ": ")
        return ask(req.text + " — press Enter when ready ")

    return prompt


def check_output(out: Path) -> None:
    """Refuse an existing non-empty output (a recording never replaces anything)."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"output {out} already exists and is not empty; a recording never replaces files "
                         "(choose a new folder)")
