"""The capture folder: one sensor pose, N frames (the data contract).

::

    capture/
      capture.json      {"sensor": "kinect_v2", "depth_unit_mm": 1.0,
                         "intrinsics": {...} (optional), "timestamps_s": [...] (optional)}
      depth/000000.png  uint16 PNG, mm, Z, 0 = invalid  (.tif/.tiff/.npy also read)
      ir/000000.png     uint16 amplitude (optional)
      color/000000.jpg  8-bit colour (optional)

:class:`Capture` is a lazy, indexable dataset (``len(cap)``, ``cap[i]`` -> depth frame);
:class:`CaptureWriter` streams frames into a temporary folder and renames it into place.
"""

from __future__ import annotations

import io
import os
import shutil
import threading
import warnings
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from tofmetry.errors import FormatError, InputError
from tofmetry.io import images
from tofmetry.io._atomic import atomic_dir, atomic_write_json, read_json
from tofmetry.io.frames_log import read_frames_log
from tofmetry.sensor.intrinsics import CameraIntrinsics
from tofmetry.sensor.profiles import PROFILES


class EmptyFrameWarning(UserWarning):
    """A depth frame in which every pixel is 0 (no measurement)."""


class CutRecordingWarning(UserWarning):
    """A live recording that was never closed (power cut, crash): read as its complete frames."""


def _frame_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes and not p.name.startswith("."))


@dataclass
class CaptureMeta:
    """Content of ``capture.json``."""

    sensor: str = "kinect_v2"
    depth_unit_mm: float = 1.0
    intrinsics: CameraIntrinsics | None = None
    timestamps_s: list[float] | None = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {"sensor": self.sensor, "depth_unit_mm": self.depth_unit_mm}
        if self.intrinsics is not None:
            d["intrinsics"] = self.intrinsics.to_dict()
        if self.timestamps_s is not None:
            d["timestamps_s"] = [float(t) for t in self.timestamps_s]
        d.update(self.extra)
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str) -> "CaptureMeta":
        if not isinstance(d, dict):
            raise FormatError(f"{source}: expected a JSON object")
        unit = d.get("depth_unit_mm", 1.0)
        if not isinstance(unit, (int, float)) or unit <= 0:
            raise FormatError(f"{source}: depth_unit_mm must be a positive number, found {unit!r}")
        intr = d.get("intrinsics")
        ts = d.get("timestamps_s")
        if ts is not None:
            if not isinstance(ts, list) or not all(isinstance(t, (int, float)) for t in ts):
                raise FormatError(f"{source}: timestamps_s must be a list of numbers")
        extra = {k: v for k, v in d.items() if k not in ("sensor", "depth_unit_mm", "intrinsics", "timestamps_s")}
        return cls(
            sensor=str(d.get("sensor", "unknown")),
            depth_unit_mm=float(unit),
            intrinsics=CameraIntrinsics.from_dict(intr, source=f"{source} 'intrinsics'") if intr else None,
            timestamps_s=[float(t) for t in ts] if ts is not None else None,
            extra=extra,
        )


class Capture:
    """A capture folder opened for reading (lazy: frames load on access).

    Parameters
    ----------
    path : folder holding ``capture.json`` and ``depth/``.

    Raises
    ------
    FormatError
        Naming the file: missing folder, no frames, wrong bit depth, wrong resolution,
        frames of mixed size, timestamps not matching the frame count.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.is_dir():
            raise InputError(f"capture folder not found: {self.path}")
        meta_path = self.path / "capture.json"
        if meta_path.is_file():
            self.meta = CaptureMeta.from_dict(read_json(meta_path, "capture.json"), str(meta_path))
        else:
            self.meta = CaptureMeta(sensor="unknown")
        self.depth_files = _frame_files(self.path / "depth", images.DEPTH_SUFFIXES)
        self.ir_files = _frame_files(self.path / "ir", (".png", ".tif", ".tiff", ".npy"))
        self.color_files = _frame_files(self.path / "color", (".jpg", ".jpeg", ".png"))
        rec = self.meta.extra.get("recording")
        if isinstance(rec, dict) and rec.get("complete") is False:
            self._read_cut_recording()
        if not self.depth_files:
            raise FormatError(
                f"{self.path}: no depth frames found (expected depth/000000.png ... in the capture folder)"
            )
        self._shape = self._check_headers()
        if self.meta.timestamps_s is not None and len(self.meta.timestamps_s) != len(self.depth_files):
            raise FormatError(
                f"{meta_path}: {len(self.meta.timestamps_s)} timestamps for {len(self.depth_files)} depth frames"
            )
        if self.ir_files and len(self.ir_files) != len(self.depth_files):
            raise FormatError(f"{self.path / 'ir'}: {len(self.ir_files)} IR frames for {len(self.depth_files)} depth frames")

    def _read_cut_recording(self) -> None:
        """A live recording never closed: keep the frames 0..n-1 that have a depth file and a line in
        ``frames.jsonl`` (timestamps and temperatures from it), warn, change nothing on disk."""
        rows = read_frames_log(self.path)
        stems = {p.stem for p in self.depth_files}
        n = 0
        while f"{n:06d}" in stems and n in rows:
            n += 1
        if n == 0:
            raise FormatError(f"{self.path}: a recording cut off before its first complete frame (no frame has both "
                              f"its depth file and its line in frames.jsonl)")
        keep = {f"{i:06d}" for i in range(n)}
        dropped = len(self.depth_files) - n
        self.depth_files = [p for p in self.depth_files if p.stem in keep]
        self.ir_files = [p for p in self.ir_files if p.stem in keep]
        self.color_files = [p for p in self.color_files if p.stem in keep]
        self.meta.timestamps_s = [rows[i]["timestamp_s"] for i in range(n)]
        keys = sorted({k for i in range(n) for k in rows[i]["temperature_c"]})
        if keys:
            self.meta.extra["temperature_c"] = {k: [rows[i]["temperature_c"].get(k) for i in range(n)] for k in keys}
        warnings.warn(f"{self.path}: the recording was never closed (cut off, or still recording); read as its {n} complete "
                      "frame(s)"
                      + (f" ({dropped} incomplete depth frame(s) left out)" if dropped else "")
                      + f"; run 'tofmetry record recover {self.path}' to finish it on disk",
                      CutRecordingWarning, stacklevel=3)

    # ---------------------------------------------------------------- checks
    def _check_headers(self) -> tuple[int, int]:
        """Check bit depth and size of every PNG from its header (cheap), else of frame 0."""
        shapes = {}
        for f in self.depth_files:
            if f.suffix.lower() == ".png":
                w, h, bit, ctype = images.png_header(f)
                if bit != 16 or ctype not in (0, 4):
                    raise FormatError(
                        f"{f}: expected a 16-bit greyscale PNG (uint16 mm), found bit depth {bit}, colour type {ctype}"
                    )
                shapes.setdefault((h, w), f)
            elif not shapes:
                shapes[images.read_depth_image(f).shape] = f
        if len(shapes) > 1:
            desc = ", ".join(f"{w}x{h} ({p.name})" for (h, w), p in shapes.items())
            raise FormatError(f"{self.path}: depth frames of mixed size: {desc}")
        shape = next(iter(shapes))
        expected = None
        if self.meta.intrinsics is not None:
            expected = self.meta.intrinsics.shape
            src = "capture.json intrinsics"
        elif self.meta.sensor in PROFILES:
            expected = PROFILES[self.meta.sensor].depth.shape
            src = f"sensor {self.meta.sensor!r}"
        if expected is not None and shape != expected:
            raise FormatError(
                f"{shapes[shape]}: wrong resolution {shape[1]}x{shape[0]}, expected {expected[1]}x{expected[0]} from {src}"
            )
        return shape

    # ---------------------------------------------------------------- access
    def __len__(self) -> int:
        return len(self.depth_files)

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the depth frames."""
        return self._shape

    @property
    def sensor(self) -> str:
        return self.meta.sensor

    @property
    def has_ir(self) -> bool:
        return bool(self.ir_files)

    @property
    def has_color(self) -> bool:
        return bool(self.color_files)

    @property
    def timestamps_s(self) -> np.ndarray | None:
        return None if self.meta.timestamps_s is None else np.asarray(self.meta.timestamps_s, dtype=np.float64)

    def intrinsics(self, override: CameraIntrinsics | None = None) -> tuple[CameraIntrinsics, str]:
        """The intrinsics to use and where they came from (override > capture.json > profile)."""
        if override is not None:
            return override, "given"
        if self.meta.intrinsics is not None:
            return self.meta.intrinsics, "capture.json"
        if self.meta.sensor in PROFILES:
            return PROFILES[self.meta.sensor].depth, f"typical {self.meta.sensor} profile (not calibrated)"
        raise InputError(f"{self.path}: no intrinsics in capture.json and unknown sensor {self.meta.sensor!r}; pass --intrinsics")

    def depth(self, i: int, as_float: bool = False) -> np.ndarray:
        """Frame ``i``: (H, W) uint16 depth [mm] (``depth_unit_mm`` applied if != 1).

        ``as_float=True``: (H, W) float32 [mm], not rounded (keeps the precision of float
        ``.npy`` frames such as ``tofmetry correct --float32`` output)."""
        f = self.depth_files[i]
        d = images.read_depth_image(f, as_float=as_float)
        if d.shape != self._shape:
            raise FormatError(f"{f}: size {d.shape[1]}x{d.shape[0]} differs from the capture's {self._shape[1]}x{self._shape[0]}")
        if self.meta.depth_unit_mm != 1.0:
            if as_float:
                d = (d * np.float32(self.meta.depth_unit_mm)).astype(np.float32)
            else:
                d = np.clip(np.rint(d.astype(np.float64) * self.meta.depth_unit_mm), 0, 65535).astype(np.uint16)
        if not d.any():
            warnings.warn(f"{f}: all-zero depth frame (no valid measurement)", EmptyFrameWarning, stacklevel=2)
        return d

    __getitem__ = depth

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self.depth(i)

    def ir(self, i: int) -> np.ndarray:
        """IR amplitude frame ``i``: (H, W) uint16."""
        if not self.ir_files:
            raise InputError(f"{self.path}: capture has no IR frames (ir/ folder)")
        return images.read_ir_image(self.ir_files[i])

    def color(self, i: int) -> np.ndarray:
        """Colour frame ``i``: (Hc, Wc, 3) uint8 RGB."""
        if not self.color_files:
            raise InputError(f"{self.path}: capture has no colour frames (color/ folder)")
        return images.read_color_image(self.color_files[min(i, len(self.color_files) - 1)])

    def depth_stack(self, indices: Iterable[int] | None = None, advance=None) -> np.ndarray:
        """Load frames into a (T, H, W) uint16 stack (use only for short captures);
        ``advance()`` is called after each frame (progress)."""
        idx = list(range(len(self))) if indices is None else list(indices)
        out = np.empty((len(idx), *self._shape), dtype=np.uint16)
        for k, i in enumerate(idx):
            out[k] = self.depth(i)
            if advance is not None:
                advance()
        return out

    def ir_mean(self, max_frames: int = 20) -> np.ndarray:
        """Mean IR amplitude over up to ``max_frames`` frames: (H, W) float32."""
        n = min(len(self.ir_files), max_frames)
        acc = np.zeros(self._shape, np.float64)
        for i in range(n):
            acc += self.ir(i)
        return (acc / max(n, 1)).astype(np.float32)

    def __repr__(self) -> str:
        return f"Capture({str(self.path)!r}, frames={len(self)}, sensor={self.sensor!r}, shape={self._shape})"


class CaptureWriter:
    """Stream frames into a new capture folder, atomically.

    Use as a context manager; the folder appears under its name only when the block
    finishes without error (an interrupted run leaves a hidden ``.NAME.*.tmp`` folder at most,
    never a capture that looks complete). Refuses to replace an existing capture unless ``force``.
    Frames are appended in order with :meth:`add`, or written by index from several threads with
    :meth:`put` (every index ``0 .. n-1`` must be written once).

    Examples
    --------
    >>> with CaptureWriter(out, meta) as w:          # doctest: +SKIP
    ...     for depth, ir in frames:
    ...         w.add(depth, ir=ir)
    """

    def __init__(self, path: str | os.PathLike, meta: CaptureMeta | None = None, force: bool = False):
        self.path = Path(path)
        self.meta = meta or CaptureMeta()
        self.force = force
        self._ctx = None
        self._tmp: Path | None = None
        self._shape = None
        self._lock = threading.Lock()
        self._written: set[int] = set()

    @property
    def n(self) -> int:
        """Number of frames written so far."""
        return len(self._written)

    def __enter__(self) -> "CaptureWriter":
        # a 'with' whose __enter__ fails never calls __exit__: until the folder is ready, the stack
        # removes the staging folder itself; then it is handed on to __exit__
        with ExitStack() as stack:
            self._tmp = stack.enter_context(atomic_dir(self.path, force=self.force))
            for sub in ("depth", "ir", "color"):
                (self._tmp / sub).mkdir()
            self._ctx = stack.pop_all()
        return self

    def add(self, depth: np.ndarray, ir: np.ndarray | None = None, color: np.ndarray | None = None) -> None:
        """Append one frame: depth (H, W) uint16 [mm]; ir (H, W) uint16; color (Hc, Wc, 3) uint8 RGB."""
        self.put(self.n, depth, ir, color)

    def put(self, index: int, depth: np.ndarray, ir: np.ndarray | None = None, color: np.ndarray | None = None) -> None:
        """Write frame ``index`` (thread-safe; any order).

        Parameters
        ----------
        index : frame number, 0-based (file ``depth/{index:06d}.png``)
        depth : (H, W) uint16 [mm] (PNG), or (H, W) float32 [mm] (``.npy``, unrounded, e.g. the
            output of ``tofmetry correct --float32``)
        ir : optional (H, W) amplitude (clipped to uint16, PNG)
        color : optional (Hc, Wc, 3) uint8 RGB (JPEG)
        """
        if self._tmp is None:
            raise RuntimeError("CaptureWriter.put is only available inside the 'with' block")
        if depth.ndim != 2 or depth.dtype not in (np.uint16, np.float32):
            raise FormatError(f"CaptureWriter: depth frame {index} must be (H, W) uint16 or float32 mm, found "
                              f"{depth.shape} {depth.dtype}")
        with self._lock:
            if self._shape is None:
                self._shape = depth.shape
            elif depth.shape != self._shape:
                raise FormatError(f"CaptureWriter: frame {index} has size {depth.shape}, previous frames {self._shape}")
            if index in self._written:
                raise FormatError(f"CaptureWriter: frame {index} written twice")
            self._written.add(index)
        name = f"{index:06d}"
        # plain writes: the whole folder is moved into place atomically at the end
        if depth.dtype == np.uint16:
            (self._tmp / "depth" / f"{name}.png").write_bytes(images.encode_png16(depth))
        else:
            buf = io.BytesIO()
            np.save(buf, depth)
            (self._tmp / "depth" / f"{name}.npy").write_bytes(buf.getvalue())
        if ir is not None:
            (self._tmp / "ir" / f"{name}.png").write_bytes(images.encode_png16(np.clip(ir, 0, 65535).astype(np.uint16)))
        if color is not None:
            images.write_color_jpg(self._tmp / "color" / f"{name}.jpg", color)

    def copy_frames(self, kind: str, files: list[Path]) -> None:
        """Copy existing frame files unchanged (e.g. the IR frames of a corrected capture).

        Parameters
        ----------
        kind : ``"ir"`` or ``"color"``
        files : frame files, copied under their own names
        """
        if kind not in ("ir", "color"):
            raise InputError(f"CaptureWriter.copy_frames: kind must be 'ir' or 'color', found {kind!r}")
        for f in files:
            shutil.copyfile(f, self._tmp / kind / Path(f).name)

    @property
    def staging(self) -> Path:
        """The temporary folder being filled; side files written here appear atomically with the capture
        (e.g. ``write_intrinsics(w.staging / "color_intrinsics.json", ...)``)."""
        if self._tmp is None:
            raise RuntimeError("CaptureWriter.staging is only available inside the 'with' block")
        return self._tmp

    def _finish(self) -> None:
        if self.n == 0:
            raise FormatError(f"{self.path}: no frames were written")
        if max(self._written) != self.n - 1:
            missing = sorted(set(range(max(self._written) + 1)) - self._written)[:5]
            raise FormatError(f"{self.path}: frames {missing} were never written")
        for sub in ("ir", "color"):
            if not any((self._tmp / sub).iterdir()):
                (self._tmp / sub).rmdir()
        ts = self.meta.timestamps_s
        if ts is not None and len(ts) != self.n:
            raise FormatError(f"{self.path}: {len(ts)} timestamps for {self.n} frames")
        atomic_write_json(self._tmp / "capture.json", self.meta.to_dict())

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self._finish()
            except BaseException as err:
                self._ctx.__exit__(type(err), err, err.__traceback__)
                raise
            self._ctx.__exit__(None, None, None)
            return False
        self._ctx.__exit__(exc_type, exc, tb)
        return False


def write_capture(path, depth_frames, meta: CaptureMeta | None = None, ir_frames=None, color_frames=None,
                  force: bool = False) -> Path:
    """Write a whole capture from sequences of frames (see :class:`CaptureWriter`)."""
    ir_frames = list(ir_frames) if ir_frames is not None else None
    color_frames = list(color_frames) if color_frames is not None else None
    with CaptureWriter(path, meta, force=force) as w:
        for i, d in enumerate(depth_frames):
            w.add(d, None if ir_frames is None else ir_frames[i], None if color_frames is None else color_frames[i])
    return Path(path)


def read_capture(path: str | os.PathLike) -> Capture:
    """Open and validate a capture folder."""
    return Capture(path)
