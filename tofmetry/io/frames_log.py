"""The frame log of a live recording: ``frames.jsonl``, one JSON line per frame written.

:class:`~tofmetry.io.live_capture.LiveCaptureWriter` appends a line once a frame's files are in
place; :class:`~tofmetry.io.capture.Capture` reads it to open a recording that was cut off.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

#: File name of the frame log inside a capture folder.
FRAMES_LOG = "frames.jsonl"


def read_frames_log(path: str | os.PathLike) -> dict[int, dict]:
    """The rows of a recording's ``frames.jsonl`` by frame index (a line cut short is left out).

    Parameters
    ----------
    path : the capture folder

    Returns
    -------
    dict index -> ``{"index", "timestamp_s", "temperature_c"}``; empty when there is no log
    """
    rows: dict[int, dict] = {}
    log = Path(path) / FRAMES_LOG
    if log.is_file():
        for line in log.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                r = json.loads(line)
                rows[int(r["index"])] = {"index": int(r["index"]), "timestamp_s": float(r["timestamp_s"]),
                                         "temperature_c": dict(r.get("temperature_c") or {})}
            except (ValueError, KeyError, TypeError, AttributeError):
                continue                     # the line in flight, cut short
    return rows
