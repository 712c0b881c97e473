"""E57 point clouds (ASTM E2807) via ``pye57``: export from PLY and back.

Only Cartesian points (and 8-bit colour when present) are written, one scan, identity pose,
coordinates in metres (E57's unit). Mesh faces and normals are not part of E57 scans and are
dropped (reported). ``pye57`` is an optional dependency, imported on use.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tofmetry.errors import FormatError, InputError
from tofmetry.io.ply import read_ply, write_ply


def write_e57(path: str | os.PathLike, points: np.ndarray, colors: np.ndarray | None = None,
              name: str = "tofmetry") -> Path:
    """Write one scan.

    Parameters
    ----------
    points : (N, 3) float [m]; colors : (N, 3) uint8 RGB or None.

    The file is written to a temporary sibling and renamed (atomic).
    """
    import pye57

    p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    if len(p) == 0:
        raise InputError("write_e57: no points")
    if not np.all(np.isfinite(p)):
        raise InputError("write_e57: points hold NaN/inf")
    data = {"cartesianX": p[:, 0].copy(), "cartesianY": p[:, 1].copy(), "cartesianZ": p[:, 2].copy()}
    if colors is not None:
        c = np.asarray(colors).reshape(-1, 3)
        if len(c) != len(p):
            raise InputError(f"write_e57: {len(c)} colours for {len(p)} points")
        for k, ch in zip(("colorRed", "colorGreen", "colorBlue"), c.T):
            data[k] = np.ascontiguousarray(ch.astype(np.uint8))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.e57")
    try:
        e = pye57.E57(str(tmp), mode="w")
        try:
            e.write_scan_raw(data, name=name)
        finally:
            e.close()
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def read_e57(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read every scan (transformed to the file's frame) -> ``{"points": (N,3) float64 [m], "colors": (N,3) uint8?}``."""
    import pye57

    path = Path(path)
    if not path.is_file():
        raise InputError(f"E57 file not found: {path}")
    try:
        e = pye57.E57(str(path))
    except Exception as exc:  # libE57 raises its own exception types
        raise FormatError(f"{path}: not a readable E57 file ({exc})") from None
    try:
        pts, cols = [], []
        for i in range(e.scan_count):
            hdr = e.get_header(i)
            fields = set(hdr.point_fields)
            want_col = {"colorRed", "colorGreen", "colorBlue"} <= fields
            raw = e.read_scan_raw(i)
            if not {"cartesianX", "cartesianY", "cartesianZ"} <= set(raw):
                raise FormatError(f"{path}: scan {i} has no Cartesian coordinates")
            xyz = np.column_stack([raw["cartesianX"], raw["cartesianY"], raw["cartesianZ"]]).astype(np.float64)
            xyz = xyz @ np.asarray(hdr.rotation_matrix).T + np.asarray(hdr.translation)
            pts.append(xyz)
            if want_col:
                cols.append(np.column_stack([raw["colorRed"], raw["colorGreen"], raw["colorBlue"]]).astype(np.uint8))
    finally:
        e.close()
    out = {"points": np.concatenate(pts) if pts else np.zeros((0, 3))}
    if cols and len(cols) == len(pts):
        out["colors"] = np.concatenate(cols)
    return out


def export_e57_cli(src, out, *, force: bool = False, **_ignored) -> dict:
    """Registry entry: PLY (cloud or mesh vertices) -> E57."""
    out = Path(out)
    if out.exists() and not force:
        raise InputError(f"output {out} already exists; refusing to overwrite (pass --force)")
    ply = read_ply(src)
    dropped = [k for k in ("faces", "normals") if k in ply]
    write_e57(out, ply["points"], ply.get("colors"), name=Path(src).stem)
    return {"points": int(len(ply["points"])), "colors": "colors" in ply, "dropped": dropped}


def export_ply_cli(src, out, *, force: bool = False, **_ignored) -> dict:
    """Registry entry: E57 -> PLY (binary)."""
    out = Path(out)
    if out.exists() and not force:
        raise InputError(f"output {out} already exists; refusing to overwrite (pass --force)")
    d = read_e57(src)
    write_ply(out, d["points"], colors=d.get("colors"))
    return {"points": int(len(d["points"])), "colors": "colors" in d}
