"""Recording a capture frame by frame, so that a power cut loses at most the frame in flight.

:class:`~tofmetry.io.capture.CaptureWriter` builds a capture in a hidden folder and renames it into
place at the end: right for processing outputs, wrong for a 90-minute recording. A
:class:`LiveCaptureWriter` writes the capture folder in place:

* ``capture.json`` first (sensor, intrinsics, device), marked ``"recording": {"complete": false}``;
* each frame's files durably (temporary file, ``fsync``, rename; IR and colour before depth, so a
  depth frame on disk always has its IR beside it), then one line per frame appended to
  ``frames.jsonl`` (index, device timestamp, temperatures) and ``fsync``-ed;
* at :meth:`LiveCaptureWriter.close`, ``capture.json`` again, with ``timestamps_s`` and the
  temperatures per frame (``temperature_c``), ``"complete": true``.

At any moment the folder reads as a capture of the frames written so far. After a cut,
:func:`recover_capture` removes the files of the frame in flight (IR or colour without its depth)
and writes the final ``capture.json`` from ``frames.jsonl`` (``tofmetry record recover DIR``, which
finds every cut capture under DIR: :func:`recover_recordings`). Until then,
:class:`~tofmetry.io.Capture` reads a cut recording as its complete frames (those logged in
``frames.jsonl`` with their depth file), with a warning, and changes nothing on disk.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from tofmetry.errors import FormatError, InputError
from tofmetry.io import images
from tofmetry.io._atomic import atomic_write_bytes, atomic_write_json, read_json
from tofmetry.io.capture import CaptureMeta
from tofmetry.io.frames_log import FRAMES_LOG, read_frames_log



def durable_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a hidden temporary file, ``fsync`` and rename (mode 0644)."""
    atomic_write_bytes(path, data, mode=0o644, fsync=True)


class LiveCaptureWriter:
    """Write a capture frame by frame, durably (see the module docstring).

    Parameters
    ----------
    path : the capture folder; must not exist or be empty
    meta : sensor, intrinsics and extra keys of ``capture.json`` (its timestamps are filled here)

    Raises
    ------
    InputError : the folder exists and is not empty (a recording never replaces anything)
    """

    def __init__(self, path: str | os.PathLike, meta: CaptureMeta | None = None):
        self.path = Path(path)
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise InputError(f"output {self.path} already exists and is not empty; a recording never replaces files "
                             "(choose a new folder)")
        self.meta = meta or CaptureMeta()
        self.n = 0
        self._shape = None
        self.path.mkdir(parents=True, exist_ok=True)
        (self.path / "depth").mkdir(exist_ok=True)
        atomic_write_json(self.path / "capture.json", self._meta_dict(False, [], {}))
        self._log = open(self.path / FRAMES_LOG, "a", encoding="utf-8")
        self._times: list[float] = []
        self._temps: dict[str, list] = {}

    def _meta_dict(self, complete: bool, times: list, temps: dict) -> dict:
        m = CaptureMeta(self.meta.sensor, self.meta.depth_unit_mm, self.meta.intrinsics,
                        times if complete else None, dict(self.meta.extra))
        d = m.to_dict()
        if complete and temps:
            d["temperature_c"] = temps
        d["recording"] = {"complete": complete, "frames": len(times) if complete else self.n,
                          "frames_log": FRAMES_LOG}
        return d

    def add(self, depth: np.ndarray, timestamp_s: float, ir: np.ndarray | None = None,
            color: np.ndarray | None = None, temperature_c: dict | None = None) -> int:
        """Append one frame durably; returns its index.

        Parameters
        ----------
        depth : (H, W) uint16 depth Z [mm]
        timestamp_s : device time of the frame [s]
        ir : (H, W) amplitude (clipped to uint16) or None
        color : (Hc, Wc, 3) uint8 RGB or None
        temperature_c : name -> temperature [°C] reported for this frame (may be empty)
        """
        if self._log is None:
            raise InputError(f"{self.path}: the recording is closed")
        if depth.ndim != 2 or depth.dtype != np.uint16:
            raise FormatError(f"{self.path}: depth frame {self.n} must be (H, W) uint16 mm, found {depth.shape} {depth.dtype}")
        if self._shape is None:
            self._shape = depth.shape
        elif depth.shape != self._shape:
            raise FormatError(f"{self.path}: frame {self.n} has size {depth.shape}, previous frames {self._shape}")
        name = f"{self.n:06d}"
        if ir is not None:
            (self.path / "ir").mkdir(exist_ok=True)
            durable_write(self.path / "ir" / f"{name}.png", images.encode_png16(np.clip(ir, 0, 65535).astype(np.uint16)))
        if color is not None:
            (self.path / "color").mkdir(exist_ok=True)
            images.write_color_jpg(self.path / "color" / f"{name}.jpg", color)
        durable_write(self.path / "depth" / f"{name}.png", images.encode_png16(depth))
        temps = {str(k): float(v) for k, v in (temperature_c or {}).items()}
        self._log.write(json.dumps({"index": self.n, "timestamp_s": float(timestamp_s), "temperature_c": temps}) + "\n")
        self._log.flush()
        os.fsync(self._log.fileno())
        self._times.append(float(timestamp_s))
        for k, v in temps.items():
            self._temps.setdefault(k, [None] * self.n).append(v)
        for k in self._temps:
            if len(self._temps[k]) < self.n + 1:
                self._temps[k].append(None)
        self.n += 1
        return self.n - 1

    def close(self) -> Path:
        """Write the final ``capture.json`` (timestamps, temperatures, complete). Idempotent."""
        if self._log is not None:
            self._log.close()
            self._log = None
            atomic_write_json(self.path / "capture.json", self._meta_dict(True, self._times, self._temps))
        return self.path

    def __enter__(self) -> "LiveCaptureWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def is_cut_recording(meta: dict) -> bool:
    """True when a ``capture.json`` dict is that of a live recording never closed (``recording.complete`` false)."""
    rec = meta.get("recording") if isinstance(meta, dict) else None
    return isinstance(rec, dict) and rec.get("complete") is False


def find_cut_recordings(root: str | os.PathLike) -> list[Path]:
    """Capture folders at or under ``root`` whose recording was cut off (``capture.json`` says not complete)."""
    root = Path(root)
    metas = [root / "capture.json"] if (root / "capture.json").is_file() else sorted(root.rglob("capture.json"))
    out = []
    for m in metas:
        try:
            if is_cut_recording(read_json(m, "capture.json")):
                out.append(m.parent)
        except FormatError:
            continue
    return out


def recover_recordings(root: str | os.PathLike) -> list[tuple[Path, dict]]:
    """Finish every cut recording at or under ``root`` (:func:`recover_capture` on each).

    Returns
    -------
    list of (capture folder, its :func:`recover_capture` result); empty when nothing was cut

    Raises
    ------
    InputError : ``root`` is not a folder
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"recover: {root} is not a folder (expected a recording made by tofmetry record)")
    return [(p, recover_capture(p)) for p in find_cut_recordings(root)]


def recover_capture(path: str | os.PathLike) -> dict:
    """Finish a recording that was cut off: drop the frame in flight, write the final ``capture.json``.

    Returns
    -------
    dict: ``frames`` kept, ``removed`` file names.
    """
    path = Path(path)
    meta = read_json(path / "capture.json", "capture.json")
    depth = sorted(p.stem for p in (path / "depth").glob("*.png")) if (path / "depth").is_dir() else []
    removed = []
    for sub in ("ir", "color"):
        for p in sorted((path / sub).glob("*")) if (path / sub).is_dir() else []:
            if p.stem not in set(depth) or p.name.startswith("."):
                p.unlink()
                removed.append(f"{sub}/{p.name}")
    for p in path.rglob(".*.tmp"):
        p.unlink()
        removed.append(str(p.relative_to(path)))
    rows = read_frames_log(path)
    n = len(depth)
    for i in range(n):
        if i not in rows:                    # a depth frame whose log line never made it: drop it
            for j in range(i, n):
                for sub, suf in (("depth", ".png"), ("ir", ".png"), ("color", ".jpg")):
                    f = path / sub / f"{j:06d}{suf}"
                    if f.exists():
                        f.unlink()
                        removed.append(f"{sub}/{f.name}")
            n = i
            break
    meta.pop("recording", None)
    meta["timestamps_s"] = [rows[i]["timestamp_s"] for i in range(n)]
    keys = sorted({k for i in range(n) for k in rows[i].get("temperature_c", {})})
    if keys:
        meta["temperature_c"] = {k: [rows[i].get("temperature_c", {}).get(k) for i in range(n)] for k in keys}
    meta["recording"] = {"complete": True, "frames": n, "frames_log": FRAMES_LOG, "recovered": True}
    atomic_write_json(path / "capture.json", meta)
    return {"frames": n, "removed": removed}
