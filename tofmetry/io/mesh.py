"""Read a point cloud or a triangle mesh (PLY / OBJ / STL) into plain arrays.

PLY files go through :func:`tofmetry.io.read_ply` (keeps scalar fields); OBJ / STL and any
PLY our reader cannot parse go through Open3D. Units are not converted here: see
:func:`tofmetry.evaluate.check_units` for the metres-vs-millimetres check.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tofmetry.errors import FormatError, InputError
from tofmetry.io.ply import read_ply

SUPPORTED_SUFFIXES = (".ply", ".obj", ".stl")


@dataclass
class Geometry:
    """A cloud or a mesh as arrays.

    Attributes
    ----------
    points : (N, 3) float64 [file units, metres expected]
    faces : (M, 3) int64 triangle indices, or None for a cloud
    normals : (N, 3) float64 vertex normals, or None
    source : str, where it was read from (for messages)
    """

    points: np.ndarray
    faces: np.ndarray | None = None
    normals: np.ndarray | None = None
    source: str = "<array>"

    @property
    def is_mesh(self) -> bool:
        return self.faces is not None and len(self.faces) > 0


def read_geometry(path: str | os.PathLike, what: str = "geometry") -> Geometry:
    """Read a PLY/OBJ/STL cloud or mesh.

    Parameters
    ----------
    path : file path
    what : str, role of the file used in error messages ("model", "reference")

    Raises
    ------
    InputError
        Missing file, unsupported suffix, no vertices, non-finite vertices, faces indexing
        outside the vertex array.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} file not found: {path}")
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise InputError(f"{what} {path}: unsupported format {suffix!r}; expected one of {', '.join(SUPPORTED_SUFFIXES)}")
    pts = faces = normals = None
    if suffix == ".ply":
        try:  # never handed to Open3D: its PLY parser crashes the process on some malformed files (fuzzing)
            d = read_ply(path)
            pts, faces, normals = d["points"], d.get("faces"), d.get("normals")
        except FormatError as exc:
            raise InputError(f"{what} {exc}") from None
    if pts is None:
        import open3d as o3d

        mesh = o3d.io.read_triangle_mesh(str(path))
        if len(mesh.triangles) > 0:
            pts = np.asarray(mesh.vertices, dtype=np.float64)
            faces = np.asarray(mesh.triangles, dtype=np.int64)
            normals = np.asarray(mesh.vertex_normals, dtype=np.float64) if mesh.has_vertex_normals() else None
        else:
            pcd = o3d.io.read_point_cloud(str(path)) if suffix != ".stl" else None
            if pcd is not None and len(pcd.points) > 0:
                pts = np.asarray(pcd.points, dtype=np.float64)
                normals = np.asarray(pcd.normals, dtype=np.float64) if pcd.has_normals() else None
            else:
                pts = np.asarray(mesh.vertices, dtype=np.float64)
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        raise InputError(f"{what} {path}: empty (no vertices / points)")
    if not np.isfinite(pts).all():
        raise InputError(f"{what} {path}: {int((~np.isfinite(pts).all(1)).sum())} vertices are NaN/inf")
    if faces is not None:
        faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if len(faces) == 0:
            faces = None
        elif faces.min() < 0 or faces.max() >= len(pts):
            raise InputError(f"{what} {path}: faces index vertices outside 0..{len(pts) - 1}")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        if len(normals) != len(pts):
            normals = None
    return Geometry(points=pts, faces=faces, normals=normals, source=str(path))
