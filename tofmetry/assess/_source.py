"""Adapt the inputs of the analyses: a :class:`~tofmetry.io.Capture`-like object or arrays.

The analyses accept either a capture (anything with ``__len__``, ``depth(i)``, ``shape``
and optionally ``ir(i)``/``has_ir``/``timestamps_s``) or plain frames. Frames are
streamed one at a time from captures; arrays are used as they are.
"""

from __future__ import annotations

from typing import Callable, Iterator

import numpy as np

from tofmetry.errors import InputError


def is_capture(obj) -> bool:
    """True for capture-like objects (lazy frame access by index)."""
    return hasattr(obj, "depth") and callable(getattr(obj, "depth")) and hasattr(obj, "__len__")


def frame_iter(source, progress: Callable[[], None] | None = None) -> Iterator[np.ndarray]:
    """Yield (H, W) depth frames [mm] from a capture or a (T, H, W) array / iterable."""
    if is_capture(source):
        for i in range(len(source)):
            yield source.depth(i)
            if progress is not None:
                progress()
    else:
        for f in source:
            yield np.asarray(f)
            if progress is not None:
                progress()


def n_frames(source) -> int | None:
    """Number of frames if known without reading them."""
    try:
        return len(source)
    except TypeError:
        return None


def capture_ir(source, ir: np.ndarray | None, max_frames: int = 20) -> np.ndarray | None:
    """The (H, W) float IR amplitude to use: the given one, else the capture's mean IR, else None."""
    if ir is not None:
        a = np.asarray(ir, dtype=np.float64)
        if a.ndim == 3:
            a = a[: max_frames].mean(axis=0)
        return a
    if is_capture(source) and getattr(source, "has_ir", False):
        return np.asarray(source.ir_mean(max_frames), dtype=np.float64)
    return None


def check_frame(frame: np.ndarray, shape: tuple[int, int] | None, index: int, what: str) -> np.ndarray:
    """Check a frame is 2-D and of the expected shape; return it."""
    f = np.asarray(frame)
    if f.ndim != 2:
        raise InputError(f"{what}: frame {index} must be an (H, W) depth map [mm], found shape {f.shape}")
    if shape is not None and f.shape != tuple(shape):
        raise InputError(f"{what}: frame {index} has shape {f.shape}, expected {tuple(shape)}")
    return f

