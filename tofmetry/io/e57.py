"""E57 point clouds (ASTM E2807) via ``pye57``'s libE57 bindings: export from PLY and back.

One scan, identity pose, coordinates in metres (E57's unit). Written per point: the Cartesian
coordinates, 8-bit colour when present, the normals as the E57 surface-normals extension
(``nor:normalX/Y/Z``, the one CloudCompare reads) and every other per-point scalar of the PLY
(e.g. ``deviation_mm``) as a float field of tofmetry's own extension, ``tofmetry:<name>`` (namespace
:data:`EXTENSION_URI`): a reader that does not know it skips it, and :func:`read_e57` reads it back
under its name. Only mesh faces are dropped (E57 scans hold points), and the export says so.
``pye57`` is an optional dependency, imported on use.
"""

from __future__ import annotations

import os
import re
import uuid
from pathlib import Path

import numpy as np

from tofmetry._shared.atomic import file_mode
from tofmetry.errors import FormatError, InputError
from tofmetry.io.ply import read_ply, write_ply

#: namespace of tofmetry's per-point fields in E57 files
EXTENSION_PREFIX = "tofmetry"
EXTENSION_URI = "https://github.com/tofmetry/tofmetry/e57/v1"
NORMALS_PREFIX, NORMALS_URI = "nor", "http://www.libe57.org/E57_EXT_surface_normals.txt"
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _float_node(lib, imf, values: np.ndarray):
    v = values[np.isfinite(values)]
    lo, hi = (float(v.min()), float(v.max())) if v.size else (0.0, 0.0)
    return lib.FloatNode(imf, lo, lib.E57_DOUBLE, min(lo, -1e300), max(hi, 1e300))


def write_e57(path: str | os.PathLike, points: np.ndarray, colors: np.ndarray | None = None,
              name: str = "tofmetry", normals: np.ndarray | None = None,
              scalars: dict[str, np.ndarray] | None = None) -> Path:
    """Write one scan.

    Parameters
    ----------
    points : (N, 3) float [m]
    colors : (N, 3) uint8 RGB or None
    normals : (N, 3) float unit normals or None (E57 surface-normals extension)
    scalars : name -> (N,) float per-point fields (``tofmetry:<name>`` extension fields), or None
    name : the scan's name

    The file is written to a temporary sibling and renamed (atomic), with the umask's mode.
    """
    from pye57 import libe57 as lib

    p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    n = len(p)
    if n == 0:
        raise InputError("write_e57: no points")
    if not np.all(np.isfinite(p)):
        raise InputError("write_e57: points hold NaN/inf")
    fields: dict[str, np.ndarray] = {"cartesianX": p[:, 0].copy(), "cartesianY": p[:, 1].copy(),
                                     "cartesianZ": p[:, 2].copy()}
    if colors is not None:
        c = np.asarray(colors).reshape(-1, 3)
        if len(c) != n:
            raise InputError(f"write_e57: {len(c)} colours for {n} points")
        for k, ch in zip(("colorRed", "colorGreen", "colorBlue"), c.T):
            fields[k] = np.ascontiguousarray(ch.astype(np.uint8))
    if normals is not None:
        nr = np.asarray(normals, np.float64).reshape(-1, 3)
        if len(nr) != n:
            raise InputError(f"write_e57: {len(nr)} normals for {n} points")
        for k, ch in zip(("normalX", "normalY", "normalZ"), nr.T):
            fields[f"{NORMALS_PREFIX}:{k}"] = np.ascontiguousarray(ch)
    for key, val in (scalars or {}).items():
        if not _NAME_RE.match(key):
            raise InputError(f"write_e57: field name {key!r} is not an identifier (letters, digits, _)")
        v = np.ascontiguousarray(np.asarray(val, np.float64).ravel())
        if len(v) != n:
            raise InputError(f"write_e57: field {key!r} has {len(v)} values for {n} points")
        fields[f"{EXTENSION_PREFIX}:{key}"] = v
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.e57")
    try:
        imf = lib.ImageFile(str(tmp), "w")
        try:
            _write_scan(lib, imf, fields, name)
        finally:
            imf.close()
        os.chmod(tmp, file_mode())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _write_scan(lib, imf, fields: dict[str, np.ndarray], name: str) -> None:
    imf.extensionsAdd(EXTENSION_PREFIX, EXTENSION_URI)
    imf.extensionsAdd(NORMALS_PREFIX, NORMALS_URI)
    root = imf.root()
    root.set("formatName", lib.StringNode(imf, "ASTM E57 3D Imaging Data File"))
    root.set("guid", lib.StringNode(imf, "{%s}" % uuid.uuid4()))
    root.set("versionMajor", lib.IntegerNode(imf, lib.E57_FORMAT_MAJOR))
    root.set("versionMinor", lib.IntegerNode(imf, lib.E57_FORMAT_MINOR))
    root.set("coordinateMetadata", lib.StringNode(imf, ""))
    data3d = lib.VectorNode(imf, True)
    root.set("data3D", data3d)
    root.set("images2D", lib.VectorNode(imf, True))
    scan = lib.StructureNode(imf)
    scan.set("guid", lib.StringNode(imf, "{%s}" % uuid.uuid4()))
    scan.set("name", lib.StringNode(imf, name))
    scan.set("description", lib.StringNode(imf, "tofmetry; per-point fields in the 'tofmetry' extension"))
    n = len(fields["cartesianX"])
    bounds = lib.StructureNode(imf)
    for ax in "XYZ":
        v = fields[f"cartesian{ax}"]
        bounds.set(f"{ax.lower()}Minimum", lib.FloatNode(imf, float(v.min())))
        bounds.set(f"{ax.lower()}Maximum", lib.FloatNode(imf, float(v.max())))
    scan.set("cartesianBounds", bounds)
    if "colorRed" in fields:
        cl = lib.StructureNode(imf)
        for ch in ("Red", "Green", "Blue"):
            cl.set(f"color{ch}Minimum", lib.IntegerNode(imf, 0))
            cl.set(f"color{ch}Maximum", lib.IntegerNode(imf, 255))
        scan.set("colorLimits", cl)
    proto = lib.StructureNode(imf)
    for key, v in fields.items():
        if key.startswith("color"):
            proto.set(key, lib.IntegerNode(imf, 0, 0, 255))
        else:
            proto.set(key, _float_node(lib, imf, v))
    points = lib.CompressedVectorNode(imf, proto, lib.VectorNode(imf, True))
    scan.set("points", points)
    data3d.append(scan)
    buffers = lib.VectorSourceDestBuffer()
    for key, v in fields.items():
        buffers.append(lib.SourceDestBuffer(imf, key, v, n, True, True))
    writer = points.writer(buffers)
    writer.write(n)
    writer.close()


def read_e57(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read every scan (transformed to the file's frame).

    Returns
    -------
    dict: ``points`` (N, 3) float64 [m]; ``colors`` (N, 3) uint8 when every scan has colour;
    ``normals`` (N, 3) when every scan has the surface-normals extension; and each ``tofmetry:<name>``
    per-point field present in every scan under ``<name>`` (N,) float64.

    Raises
    ------
    InputError
        The file does not exist.
    FormatError
        Not a readable E57 file, or a scan without Cartesian coordinates (the message names the file).
    """
    import pye57

    path = Path(path)
    if not path.is_file():
        raise InputError(f"E57 file not found: {path}")
    try:
        e = pye57.E57(str(path))
    except Exception as exc:  # noqa: BLE001 - libE57 raises its own exception types
        raise FormatError(f"{path}: not a readable E57 file ({exc})") from None
    try:
        try:
            scans = [_read_scan(pye57, e, i, path) for i in range(e.scan_count)]
        except FormatError:
            raise
        except Exception as exc:  # noqa: BLE001 - libE57 / pye57 on a damaged or unusual file
            raise FormatError(f"{path}: not a readable E57 file ({type(exc).__name__}: {exc})") from None
    finally:
        e.close()
    out = {"points": np.concatenate([s["points"] for s in scans]) if scans else np.zeros((0, 3))}
    common = set.intersection(*(set(s) for s in scans)) - {"points"} if scans else set()
    for key in sorted(common):
        out[key] = np.concatenate([s[key] for s in scans])
    return out


def _read_scan(pye57, e, i: int, path: Path) -> dict[str, np.ndarray]:
    from pye57 import libe57 as lib

    hdr = e.get_header(i)
    fields = list(hdr.point_fields)
    if not {"cartesianX", "cartesianY", "cartesianZ"} <= set(fields):
        raise FormatError(f"{path}: scan {i} has no Cartesian coordinates")
    n = int(hdr.point_count)
    arrays, buffers = {}, lib.VectorSourceDestBuffer()
    for f in fields:
        if f.startswith(("cartesian", "color")) and f in ("cartesianX", "cartesianY", "cartesianZ", "colorRed",
                                                          "colorGreen", "colorBlue"):
            dt = np.float64 if f.startswith("cartesian") else np.uint8
        elif f.startswith((f"{EXTENSION_PREFIX}:", f"{NORMALS_PREFIX}:normal")):
            dt = np.float64
        else:
            continue
        arrays[f] = np.empty(n, dt)
        buffers.append(lib.SourceDestBuffer(e.image_file, f, arrays[f], n, True, True))
    if n:
        reader = hdr.points.reader(buffers)
        reader.read()
        reader.close()
    xyz = np.column_stack([arrays["cartesianX"], arrays["cartesianY"], arrays["cartesianZ"]])
    R = np.asarray(hdr.rotation_matrix, float)
    t = np.asarray(hdr.translation, float)
    out = {"points": xyz @ R.T + t}
    if {"colorRed", "colorGreen", "colorBlue"} <= set(arrays):
        out["colors"] = np.clip(np.column_stack([arrays["colorRed"], arrays["colorGreen"], arrays["colorBlue"]]),
                                0, 255).astype(np.uint8)
    nk = [f"{NORMALS_PREFIX}:normal{a}" for a in "XYZ"]
    if set(nk) <= set(arrays):
        out["normals"] = np.column_stack([arrays[k] for k in nk]) @ R.T
    for f, v in arrays.items():
        if f.startswith(f"{EXTENSION_PREFIX}:"):
            out[f.split(":", 1)[1]] = v
    return out


_PLY_STANDARD = {"points", "colors", "normals", "faces"}


def export_e57_cli(src, out, *, force: bool = False, **_ignored) -> dict:
    """Registry entry: PLY (cloud or mesh vertices) -> E57, every per-point field kept (faces dropped)."""
    out = Path(out)
    if out.exists() and not force:
        raise InputError(f"output {out} already exists; refusing to overwrite (pass --force)")
    ply = read_ply(src)
    scalars = {k: v for k, v in ply.items() if k not in _PLY_STANDARD and np.ndim(v) == 1}
    write_e57(out, ply["points"], ply.get("colors"), name=Path(src).stem, normals=ply.get("normals"),
              scalars=scalars)
    kept = (["colors"] if "colors" in ply else []) + (["normals"] if "normals" in ply else []) + sorted(scalars)
    return {"points": int(len(ply["points"])), "colors": "colors" in ply, "fields kept": ", ".join(kept) or "none",
            "dropped": "mesh faces (E57 scans hold points)" if "faces" in ply else "nothing"}


def export_ply_cli(src, out, *, force: bool = False, **_ignored) -> dict:
    """Registry entry: E57 -> PLY (binary), every per-point field kept."""
    out = Path(out)
    if out.exists() and not force:
        raise InputError(f"output {out} already exists; refusing to overwrite (pass --force)")
    d = read_e57(src)
    scalars = {k: v for k, v in d.items() if k not in _PLY_STANDARD}
    write_ply(out, d["points"], colors=d.get("colors"), normals=d.get("normals"), scalars=scalars)
    return {"points": int(len(d["points"])), "colors": "colors" in d, "fields kept": ", ".join(
        [k for k in ("colors", "normals") if k in d] + sorted(scalars)) or "none"}
