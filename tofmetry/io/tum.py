"""TUM RGB-D benchmark folders -> capture.

::

    sequence/
      depth.txt     "# timestamp filename" lines -> depth/<t>.png (uint16, 5000 units per metre)
      rgb.txt       "# timestamp filename" lines -> rgb/<t>.png (optional)
      depth/ rgb/

Depth is copied *losslessly*: the raw values are written and ``capture.json`` gets
``depth_unit_mm = 1000 / scale`` (0.2 mm for TUM), which :class:`~tofmetry.io.Capture`
applies on reading. Colour frames are associated to depth by nearest timestamp (within
``max_dt_s``). TUM does not ship intrinsics in the folder: pass them (``intrinsics``) or the
capture records none (sensor ``"unknown"``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tofmetry.errors import FormatError, InputError
from tofmetry.io import images
from tofmetry.io.capture import CaptureMeta, CaptureWriter
from tofmetry.io.datasets import safe_relative
from tofmetry.io.intrinsics_json import read_intrinsics

TUM_DEPTH_SCALE = 5000.0


def read_tum_list(path: str | os.PathLike) -> list[tuple[float, str]]:
    """``timestamp filename`` lines (``#`` comments skipped) -> [(t [s], relative path)]."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"TUM list not found: {path}")
    out = []
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(f"{path}: not a TUM list (not UTF-8 text: byte {exc.start})") from None
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        if len(tok) < 2:
            raise FormatError(f"{path}:{n}: expected 'timestamp filename', found {line!r}")
        try:
            t = float(tok[0])
            if t != t or t in (float("inf"), float("-inf")):
                raise ValueError
            out.append((t, tok[1]))
        except ValueError:
            raise FormatError(f"{path}:{n}: timestamp {tok[0]!r} is not a number") from None
    if not out:
        raise FormatError(f"{path}: no entries")
    return out


def associate(t_a: np.ndarray, t_b: np.ndarray, max_dt_s: float) -> np.ndarray:
    """Index into ``t_b`` of the nearest timestamp for each ``t_a`` (-1 if farther than ``max_dt_s``)."""
    t_b = np.asarray(t_b, float)
    if len(t_b) == 0:
        return np.full(len(t_a), -1)
    order = np.argsort(t_b)
    tb = t_b[order]
    pos = np.clip(np.searchsorted(tb, t_a), 1, len(tb) - 1) if len(tb) > 1 else np.zeros(len(t_a), int)
    if len(tb) > 1:
        left = pos - 1
        pos = np.where(np.abs(tb[left] - t_a) <= np.abs(tb[pos] - t_a), left, pos)
    idx = order[pos]
    return np.where(np.abs(t_b[idx] - t_a) <= max_dt_s, idx, -1)


def import_depth_color_lists(root: Path, out, depth_list, color_list, scale: float, sensor: str, intrinsics,
                             force: bool, max_frames: int | None, progress, max_dt_s: float, fmt: str) -> dict:
    """Shared writer for TUM-like (timestamped) and Open3D-like (paired) folders."""
    if not scale or scale <= 0:
        raise InputError(f"depth scale must be > 0 units per metre, found {scale}")
    if max_frames is not None:
        depth_list = depth_list[:max_frames]
    td = np.array([t for t, _ in depth_list])
    cidx = associate(td, np.array([t for t, _ in color_list]), max_dt_s) if color_list else np.full(len(td), -1)
    if color_list and (cidx < 0).any() and not (cidx < 0).all():
        # keep only depth frames with a colour partner so colour stays aligned with depth
        keep = cidx >= 0
        depth_list = [d for d, k in zip(depth_list, keep) if k]
        td, cidx = td[keep], cidx[keep]
    with_color = bool(color_list) and (cidx >= 0).all()
    meta = CaptureMeta(sensor=sensor, depth_unit_mm=1000.0 / scale, intrinsics=intrinsics,
                       timestamps_s=[float(t) for t in td] if fmt == "tum" else None, extra={"source": str(root), "format": fmt,
                                                                 "depth_units_per_m": scale})
    with CaptureWriter(out, meta, force=force) as w:
        for k, (_, rel) in enumerate(depth_list):
            f = root / safe_relative(rel, f"{root}: listed depth file")
            if not f.is_file():
                raise InputError(f"{root}: listed depth file missing: {f}")
            d = images.read_depth_image(f)
            if intrinsics is not None and d.shape != intrinsics.shape:
                raise FormatError(f"{f}: {d.shape[1]}x{d.shape[0]} does not match the intrinsics {intrinsics.width}x{intrinsics.height}")
            col = images.read_color_image(root / safe_relative(color_list[cidx[k]][1], f"{root}: listed colour file")) \
                if with_color else None
            w.add(d, color=col)
            if progress is not None:
                progress()
    return {"frames": len(depth_list), "color": with_color, "depth_unit_mm": 1000.0 / scale,
            "notes": [f"depth written losslessly with depth_unit_mm = {1000.0 / scale:g} (raw {scale:g} units per metre)"]}


def import_tum(src: str | os.PathLike, out: str | os.PathLike, depth_scale: float = TUM_DEPTH_SCALE, intrinsics=None,
               force: bool = False, max_frames: int | None = None, progress=None, max_dt_s: float = 0.02) -> dict:
    """TUM RGB-D folder -> capture (see the module docstring)."""
    root = Path(src)
    if not (root / "depth.txt").is_file():
        raise InputError(f"{root}: no depth.txt (expected a TUM RGB-D sequence folder)")
    depth_list = read_tum_list(root / "depth.txt")
    color_list = read_tum_list(root / "rgb.txt") if (root / "rgb.txt").is_file() else []
    return import_depth_color_lists(root, out, depth_list, color_list, depth_scale, "unknown", intrinsics, force,
                                    max_frames, progress, max_dt_s, "tum")


def import_tum_cli(src, out, *, force: bool = False, progress=None, depth_scale: float | None = None,
                   max_frames: int | None = None, intrinsics=None, **_ignored) -> dict:
    """Registry entry for :func:`import_tum`."""
    intr = read_intrinsics(intrinsics) if intrinsics else None
    return import_tum(src, out, depth_scale or TUM_DEPTH_SCALE, intr, force, max_frames, progress)
