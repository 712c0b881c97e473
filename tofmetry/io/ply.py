"""Binary PLY (little-endian) for point clouds and triangle meshes, in metres.

Written with numpy (no third-party writer), read back by Open3D, MeshLab and CloudCompare.
Vertex properties: ``x y z`` float32, optional ``nx ny nz`` float32, ``red green blue``
uchar, and any extra float32 scalar fields (e.g. ``deviation_mm``); faces as
``vertex_indices`` uchar/int32 lists.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tofmetry.errors import FormatError
from tofmetry.io._atomic import atomic_write_bytes

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def write_ply(path: str | os.PathLike, points: np.ndarray, colors: np.ndarray | None = None,
              normals: np.ndarray | None = None, faces: np.ndarray | None = None,
              scalars: dict[str, np.ndarray] | None = None, comments: list[str] | None = None) -> Path:
    """Write a binary little-endian PLY atomically.

    Parameters
    ----------
    points : (N, 3) float [m]
    colors : (N, 3) uint8 RGB, or float in [0, 1]
    normals : (N, 3) float, unit
    faces : (M, 3) int triangle vertex indices
    scalars : name -> (N,) float extra vertex properties
    comments : extra header comment lines (one line each; line breaks are replaced by spaces)
    """
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    n = len(pts)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    scalars = scalars or {}
    fields += [(name, "<f4") for name in scalars]
    v = np.empty(n, dtype=fields)
    v["x"], v["y"], v["z"] = pts.T
    if normals is not None:
        nrm = np.asarray(normals, dtype=np.float32).reshape(-1, 3)
        if len(nrm) != n:
            raise FormatError(f"write_ply: {len(nrm)} normals for {n} points")
        v["nx"], v["ny"], v["nz"] = nrm.T
    if colors is not None:
        c = np.asarray(colors)
        if c.dtype != np.uint8:
            c = np.clip(np.rint(c * 255.0), 0, 255).astype(np.uint8)
        if c.shape != (n, 3):
            raise FormatError(f"write_ply: colours must be (N, 3), found {c.shape} for {n} points")
        v["red"], v["green"], v["blue"] = c.T
    for name, val in scalars.items():
        val = np.asarray(val, dtype=np.float32).ravel()
        if len(val) != n:
            raise FormatError(f"write_ply: scalar {name!r} has {len(val)} values for {n} points")
        v[name] = val
    props = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", "comment tofmetry, units: metres"]
    header += ["comment " + " ".join(str(c).split()) for c in comments or []]
    header += [f"element vertex {n}"]
    header += [f"property {props[t]} {name}" for name, t in fields]
    body = [v.tobytes()]
    if faces is not None:
        f = np.asarray(faces, dtype=np.int32).reshape(-1, 3)
        header += [f"element face {len(f)}", "property list uchar int vertex_indices"]
        fa = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
        fa["n"] = 3
        fa["i"] = f
        body.append(fa.tobytes())
    header.append("end_header")
    data = ("\n".join(header) + "\n").encode("ascii", "replace") + b"".join(body)
    return atomic_write_bytes(path, data)


def read_ply(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a PLY (binary little/big endian or ASCII) into arrays.

    Returns
    -------
    dict with ``points`` (N, 3) float64 and, when present, ``normals`` (N, 3) float64,
    ``colors`` (N, 3) uint8, ``faces`` (M, 3) int64, plus every other vertex property by name.

    Raises
    ------
    FormatError
        Missing file, or anything that is not a PLY this reader understands (naming the file).
    """
    path = Path(path)
    if not path.is_file():
        raise FormatError(f"PLY file not found: {path}")
    try:
        return _read_ply(path, path.read_bytes())
    except FormatError:
        raise
    except (ValueError, KeyError, IndexError, TypeError, OverflowError, UnicodeDecodeError, MemoryError) as exc:
        raise FormatError(f"{path}: not a readable PLY file ({type(exc).__name__}: {str(exc)[:200]})") from None


def _read_ply(path: Path, raw: bytes) -> dict[str, np.ndarray]:
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise FormatError(f"{path}: not a PLY file (missing 'ply' magic or end_header)")
    nl = raw.find(b"\n", end)
    header = raw[:nl].decode("ascii", "replace").splitlines()
    body = raw[nl + 1:]
    fmt = None
    elements: list[list] = []
    for line in header:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3 or not tok[2].isdigit():
                raise FormatError(f"{path}: malformed element line {line!r}")
            elements.append([tok[1], int(tok[2]), []])
        elif tok[0] == "property" and elements:
            if tok[1] == "list":
                if len(tok) != 5 or tok[2] not in _PLY_TYPES or tok[3] not in _PLY_TYPES:
                    raise FormatError(f"{path}: malformed list property {line!r}")
                elements[-1][2].append((tok[4], ("list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]])))
            else:
                if len(tok) != 3 or tok[1] not in _PLY_TYPES:
                    raise FormatError(f"{path}: unknown PLY property type in {line!r}")
                elements[-1][2].append((tok[2], _PLY_TYPES[tok[1]]))
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise FormatError(f"{path}: unsupported PLY format {fmt!r}")
    out: dict[str, np.ndarray] = {}
    if fmt == "ascii":
        lines = body.decode("ascii").split("\n")
        pos = 0
        for name, count, props in elements:
            rows = [lines[pos + i].split() for i in range(count)]
            pos += count
            if name == "vertex":
                arr = np.array(rows, dtype=np.float64).reshape(count, -1)
                for j, (pn, _) in enumerate(props):
                    out[pn] = arr[:, j]
            elif name == "face":
                li = [j for j, (_, t) in enumerate(props) if isinstance(t, tuple)]
                if li:
                    out["faces"] = _fan_triangles([_ascii_list(r, props, li[0]) for r in rows])
    else:
        bo = "<" if fmt == "binary_little_endian" else ">"
        off = 0
        for name, count, props in elements:
            if any(isinstance(t, tuple) for _, t in props):
                polys, off = _binary_lists(path, body, off, count, props, bo)
                if name == "face":
                    out["faces"] = _fan_triangles(polys)
                continue
            dt = np.dtype([(pn, bo + t) for pn, t in props])
            if off + dt.itemsize * count > len(body):
                raise FormatError(f"{path}: truncated PLY body")
            arr = np.frombuffer(body, dtype=dt, count=count, offset=off)
            off += dt.itemsize * count
            if name == "vertex":
                for pn, _ in props:
                    out[pn] = arr[pn].astype(np.float64) if pn not in ("red", "green", "blue") else arr[pn]
    if not all(k in out for k in ("x", "y", "z")):
        raise FormatError(f"{path}: PLY has no x, y, z vertex properties")
    res = {"points": np.column_stack([out.pop("x"), out.pop("y"), out.pop("z")]).astype(np.float64)}
    if all(k in out for k in ("nx", "ny", "nz")):
        res["normals"] = np.column_stack([out.pop("nx"), out.pop("ny"), out.pop("nz")]).astype(np.float64)
    if all(k in out for k in ("red", "green", "blue")):
        res["colors"] = np.column_stack([out.pop("red"), out.pop("green"), out.pop("blue")]).astype(np.uint8)
    res.update(out)
    return res


def _ascii_list(row: list[str], props: list, j: int) -> list[int]:
    """The ``j``-th property of an ASCII record as a list (scalars before it skipped)."""
    pos = 0
    for k, (_, t) in enumerate(props):
        if k == j:
            n = int(row[pos])
            if n < 0 or pos + 1 + n > len(row):
                raise ValueError(f"list of {n} items in a record of {len(row)} values")
            return [int(x) for x in row[pos + 1:pos + 1 + n]]
        pos += 1 + int(row[pos]) if isinstance(t, tuple) else 1
    return []


def _binary_lists(path: Path, body: bytes, off: int, count: int, props: list, bo: str) -> tuple:
    """Records of an element with list properties (polygons of any sizes, extra properties):
    the first list of each record ((count, n) array when all have n items, else a list), and the
    offset after the element."""
    if count:
        types = [t for _, t in props]
        uniform = len(props) == 1 and off + np.dtype(bo + types[0][1]).itemsize <= len(body)
        if uniform:  # the common case, one list of equal sizes: one read
            ct, it = types[0][1], types[0][2]
            n = int(np.frombuffer(body, dtype=bo + ct, count=1, offset=off)[0])
            if 0 <= n <= 64:
                dt = np.dtype([("n", bo + ct), ("i", bo + it, (n,))])
                if off + dt.itemsize * count <= len(body):
                    arr = np.frombuffer(body, dtype=dt, count=count, offset=off)
                    if np.all(arr["n"] == n):
                        return arr["i"].astype(np.int64).reshape(count, n), off + dt.itemsize * count
    polys = []
    for _ in range(count):  # general case: record by record (each consumes >= 1 byte, so this ends)
        first = None
        for _, t in props:
            if isinstance(t, tuple):
                ct, it = np.dtype(bo + t[1]), np.dtype(bo + t[2])
                if off + ct.itemsize > len(body):
                    raise FormatError(f"{path}: truncated PLY body")
                n = int(np.frombuffer(body, dtype=ct, count=1, offset=off)[0])
                off += ct.itemsize
                if n < 0 or off + n * it.itemsize > len(body):
                    raise FormatError(f"{path}: truncated PLY body (a list of {n} items)")
                items = np.frombuffer(body, dtype=it, count=n, offset=off)
                off += n * it.itemsize
                if first is None:
                    first = items.astype(np.int64)
            else:
                off += np.dtype(bo + t).itemsize
                if off > len(body):
                    raise FormatError(f"{path}: truncated PLY body")
        polys.append(first if first is not None else np.zeros(0, np.int64))
    return polys, off


def _fan_triangles(polys) -> np.ndarray:
    """(M, 3) int64 triangles of polygons (lists of vertex indices, or a (K, n) array) as fans;
    polygons of fewer than 3 vertices are dropped."""
    if isinstance(polys, np.ndarray):
        if polys.ndim != 2 or polys.shape[1] < 3:
            return np.zeros((0, 3), np.int64)
        return np.concatenate([polys[:, [0, k, k + 1]] for k in range(1, polys.shape[1] - 1)]).astype(np.int64)
    tris = [np.stack([np.full(len(p) - 2, p[0]), p[1:-1], p[2:]], 1) for p in (np.asarray(q, np.int64) for q in polys)
            if len(p) >= 3]
    return np.concatenate(tris).astype(np.int64) if tris else np.zeros((0, 3), np.int64)
