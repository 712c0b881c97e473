"""``mat.json``: the layout of a printed dot mat (``tofmetry mat``), which ``tofmetry reconstruct --mat`` places
the views on.

Format 1::

    {"format": "tofmetry-dot-mat", "version": 1,
     "mat": {"seed": int, "size_m": [w, h], "dot_radius_m": [min, max], "cover": float,
             "yaw_deg": float, "dark": float, "light": float},
     "print": {"image": "mat.png", "dpi": float, "size_mm": [w, h]}}

The dots are drawn from the seed (:class:`tofmetry._shared.dot_mat.DotMat`): the file and the image
describe the same sheet. Printed at another scale, the mat is another mat: print at 100 %.
"""

from __future__ import annotations

import os
from pathlib import Path

from tofmetry._shared.dot_mat import DotMat
from tofmetry.errors import InputError
from tofmetry.io._atomic import atomic_write_json, read_json

MAT_FORMAT, MAT_VERSION = "tofmetry-dot-mat", 1


def write_mat(path: str | os.PathLike, mat: DotMat, image: str | None = None, dpi: float | None = None) -> Path:
    """Write ``mat.json`` atomically (``image``, ``dpi``: the printable image written beside it)."""
    d = {"format": MAT_FORMAT, "version": MAT_VERSION, "mat": mat.to_dict()}
    if image is not None:
        d["print"] = {"image": image, "dpi": dpi, "size_mm": [round(1e3 * x, 1) for x in mat.size_m],
                      "note": "print at 100 % (no fit-to-page): another scale is another mat"}
    return atomic_write_json(path, d)


def read_mat(path: str | os.PathLike) -> DotMat:
    """The dot mat a ``mat.json`` describes; a wrong file says what it found."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file (a mat.json written by 'tofmetry mat')")
    d = read_json(p)
    if not isinstance(d, dict) or d.get("format") != MAT_FORMAT:
        found = d.get("format") if isinstance(d, dict) else type(d).__name__
        raise InputError(f"{p}: expected a {MAT_FORMAT!r} file (tofmetry mat), found format {found!r}")
    if d.get("version") != MAT_VERSION:
        raise InputError(f"{p}: {MAT_FORMAT} version {d.get('version')!r} is not supported (expected {MAT_VERSION})")
    return DotMat.from_dict(d.get("mat"), f"{p}: mat")
