"""Open3D RGB-D folders (reconstruction-system layout) -> capture.

::

    dataset/
      depth/000000.png ...     uint16, ``depth_scale`` units per metre (Open3D default 1000)
      color/000000.jpg ...     (or image/ or rgb/) colour frames paired by sorted order
      camera_intrinsic.json    optional, Open3D PinholeCameraIntrinsic JSON
                               {"width", "height", "intrinsic_matrix": [9 values, column-major]}

Depth is copied losslessly (``depth_unit_mm = 1000 / depth_scale``). Open3D intrinsics have
no distortion (zeros are recorded).
"""

from __future__ import annotations

import os
from pathlib import Path

from tofmetry.errors import FormatError, InputError
from tofmetry.io._atomic import atomic_write_json, read_json
from tofmetry.io.intrinsics_json import read_intrinsics
from tofmetry.io.tum import import_depth_color_lists
from tofmetry.sensor.intrinsics import CameraIntrinsics

OPEN3D_DEPTH_SCALE = 1000.0
_IMG = (".png", ".jpg", ".jpeg")


def read_open3d_intrinsics(path: str | os.PathLike) -> CameraIntrinsics:
    """Open3D ``PinholeCameraIntrinsic`` JSON -> CameraIntrinsics (column-major ``intrinsic_matrix``)."""
    d = read_json(path, "Open3D camera intrinsic")
    try:
        m = [float(x) for x in d["intrinsic_matrix"]]
        w, h = int(d["width"]), int(d["height"])
    except (KeyError, TypeError, ValueError, OverflowError):
        raise FormatError(f"{path}: expected width, height and intrinsic_matrix (9 numbers, column-major)") from None
    if len(m) != 9:
        raise FormatError(f"{path}: intrinsic_matrix has {len(m)} values, expected 9")
    # column-major: [fx, 0, 0, 0, fy, 0, cx, cy, 1]
    return CameraIntrinsics(w, h, m[0], m[4], m[6], m[7])


def write_open3d_intrinsics(path: str | os.PathLike, intr: CameraIntrinsics):
    """Inverse of :func:`read_open3d_intrinsics` (distortion is not representable and must be zero)."""
    if intr.has_distortion:
        raise InputError("Open3D PinholeCameraIntrinsic has no distortion; undistort first")
    return atomic_write_json(path, {"width": intr.width, "height": intr.height,
                                    "intrinsic_matrix": [intr.fx, 0, 0, 0, intr.fy, 0, intr.cx, intr.cy, 1]})


def import_open3d(src: str | os.PathLike, out: str | os.PathLike, depth_scale: float = OPEN3D_DEPTH_SCALE,
                  intrinsics: CameraIntrinsics | None = None, force: bool = False, max_frames: int | None = None,
                  progress=None) -> dict:
    """Open3D RGB-D folder -> capture (frames paired by sorted file name)."""
    root = Path(src)
    ddir = root / "depth"
    if not ddir.is_dir():
        raise InputError(f"{root}: no depth/ folder (expected an Open3D RGB-D dataset)")
    dfiles = sorted(p.name for p in ddir.iterdir() if p.suffix.lower() in (".png",))
    if not dfiles:
        raise FormatError(f"{ddir}: no depth PNG files")
    cdir = next((root / n for n in ("color", "image", "rgb") if (root / n).is_dir()), None)
    cfiles = sorted(p.name for p in cdir.iterdir() if p.suffix.lower() in _IMG) if cdir else []
    if cfiles and len(cfiles) != len(dfiles):
        raise FormatError(f"{root}: {len(dfiles)} depth frames but {len(cfiles)} colour frames in {cdir.name}/")
    if intrinsics is None and (root / "camera_intrinsic.json").is_file():
        intrinsics = read_open3d_intrinsics(root / "camera_intrinsic.json")
    depth_list = [(float(i), f"depth/{f}") for i, f in enumerate(dfiles)]
    color_list = [(float(i), f"{cdir.name}/{f}") for i, f in enumerate(cfiles)]
    return import_depth_color_lists(root, out, depth_list, color_list, depth_scale, "unknown", intrinsics, force,
                                    max_frames, progress, 0.5, "open3d")


def import_open3d_cli(src, out, *, force: bool = False, progress=None, depth_scale: float | None = None,
                      max_frames: int | None = None, intrinsics=None, **_ignored) -> dict:
    """Registry entry for :func:`import_open3d`."""
    intr = read_intrinsics(intrinsics) if intrinsics else None
    return import_open3d(src, out, depth_scale or OPEN3D_DEPTH_SCALE, intr, force, max_frames, progress)
