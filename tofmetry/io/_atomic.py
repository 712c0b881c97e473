"""JSON files (written atomically) and the atomic writers of :mod:`tofmetry._shared.atomic`.

``atomic_write_bytes`` and ``atomic_dir`` live in :mod:`tofmetry._shared.atomic` (figures use them
too); they are re-exported here for the format modules of this package.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from tofmetry._shared.atomic import atomic_dir, atomic_write_bytes
from tofmetry.errors import InputError

__all__ = ["atomic_dir", "atomic_write_bytes", "atomic_write_json", "read_json", "to_json"]


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def to_json(obj, indent: int | None = 2) -> str:
    """JSON text with numpy arrays/scalars converted; NaN written as null."""
    return json.dumps(_nan_to_none(obj), indent=indent, default=_json_default, allow_nan=False)


def _nan_to_none(o):
    if isinstance(o, float):
        return None if o != o or o in (float("inf"), float("-inf")) else o
    if isinstance(o, np.floating):
        return _nan_to_none(float(o))
    if isinstance(o, dict):
        return {str(k): _nan_to_none(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_nan_to_none(v) for v in o]
    if isinstance(o, np.ndarray):
        return _nan_to_none(o.tolist())
    return o


def atomic_write_json(path: str | os.PathLike, obj) -> Path:
    """Write ``obj`` as indented JSON atomically."""
    return atomic_write_bytes(path, (to_json(obj) + "\n").encode())


def read_json(path: str | os.PathLike, what: str = "JSON file") -> dict:
    """Read a JSON file; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} not found: {path}")
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not valid JSON (not UTF-8 text: byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise InputError(f"{path}: not valid JSON (nested too deeply)") from None
