"""iai_kinect2 calibration files (OpenCV FileStorage YAML, ``%YAML:1.0`` + ``!!opencv-matrix``).

iai_kinect2 (``kinect2_calibration`` / ``kinect2_bridge``) stores one device's calibration
in a folder::

    calib_ir.yaml      cameraMatrix (3x3), distortionCoefficients (1x5), rotation (3x3), projection (4x4)
    calib_color.yaml   same keys, colour camera (1920x1080)
    calib_pose.yaml    rotation (3x3), translation (3x1) [m], essential (3x3), fundamental (3x3)
    calib_depth.yaml   depthShift [mm]

Conventions (from iai_kinect2's ``kinect2_calibration.cpp``):

* ``calib_pose`` comes from ``cv::stereoCalibrate(board, pointsIr, pointsColor, ...)``, so
  ``p_color = R @ p_ir + t`` (IR/depth camera -> colour camera), ``t`` in metres.
* ``depthShift`` is the mean of (board-plane distance - measured depth) [mm]; ``kinect2_bridge``
  adds it to every depth pixel: ``corrected = measured + depthShift``.
* Their recordings (``kinect_cal_data``) also hold ``NNNN_ir_points.yaml`` (``points``: the
  detected corners, a flat list ``[u0, v0, u1, v1, ...]`` in pixels).

PyYAML reads these files once the ``%YAML:1.0`` directive (not YAML 1.1 syntax) is dropped and
``!!opencv-matrix`` is known to its safe loader (``cv2.FileStorage`` is not used: its parser
aborts the process on some malformed files); writing uses a small emitter that reproduces OpenCV 2/3's
byte layout (``%YAML:1.0`` header, ``%.16e`` numbers, integral values as ``1.``, wrapping at
column 71), which iai_kinect2 (built against OpenCV 2/3) loads.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from tofmetry._shared.geometry import skew
from tofmetry.errors import FormatError, InputError
from tofmetry.io._atomic import atomic_write_bytes
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics

IR_SIZE = (512, 424)
COLOR_SIZE = (1920, 1080)
CALIB_FILES = ("calib_ir.yaml", "calib_color.yaml", "calib_pose.yaml", "calib_depth.yaml")

_DT = {"d": np.float64, "f": np.float32, "i": np.int32, "u": np.uint8, "c": np.int8, "w": np.uint16, "s": np.int16}


# ----------------------------------------------------------------------------- reading
class _OpenCvLoader(yaml.SafeLoader):
    """PyYAML's safe loader plus OpenCV's ``!!opencv-matrix`` tag (a plain mapping)."""


_OpenCvLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", yaml.SafeLoader.construct_mapping)


def read_opencv_yaml(path: str | os.PathLike) -> dict[str, np.ndarray | float | str]:
    """Read a top-level OpenCV FileStorage YAML map.

    Parsed with PyYAML's safe loader (the ``%YAML:1.0`` directive dropped, ``!!opencv-matrix``
    read as a mapping), not with ``cv2.FileStorage``, whose parser aborts the process on some
    malformed files (found by fuzzing).

    Parameters
    ----------
    path : file such as ``calib_ir.yaml``.

    Returns
    -------
    dict
        ``!!opencv-matrix`` entries -> (rows, cols) float64 ndarray; numbers -> float;
        flat numeric sequences -> (N,) float64 ndarray; strings -> str.

    Raises
    ------
    InputError
        The file does not exist.
    FormatError
        The file is not OpenCV FileStorage YAML (naming the file).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"OpenCV YAML file not found: {path}")
    raw = path.read_bytes()
    if not raw.lstrip().startswith(b"%YAML"):
        raise FormatError(
            f"{path}: not an OpenCV FileStorage YAML file (expected a '%YAML:1.0' first line, found {raw[:20]!r})"
        )
    try:
        text = raw.decode("utf-8")
        body = text.lstrip().split("\n", 1)[1] if "\n" in text.lstrip() else ""
        loader = _OpenCvLoader(body)
        try:
            root = loader.get_single_data()
        finally:
            loader.dispose()
    except (yaml.YAMLError, UnicodeDecodeError, RecursionError, ValueError, TypeError) as exc:
        msg = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
        raise FormatError(f"{path}: not readable as OpenCV FileStorage YAML ({msg})") from None
    if not isinstance(root, dict):
        raise FormatError(f"{path}: expected a map of named entries at the top level")
    out: dict = {}
    for key, node in root.items():
        try:
            out[str(key)] = _node_value(node, path, str(key))
        except (ValueError, TypeError, OverflowError, RecursionError) as exc:
            msg = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
            raise FormatError(f"{path}: entry {key!r} is not readable ({msg})") from None
    return out


def _number(v, path: Path, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise FormatError(f"{path}: entry {key!r}: expected a number, found {type(v).__name__}")
    return float(v)


def _node_value(node, path: Path, key: str):
    if isinstance(node, dict):
        if not {"rows", "cols", "data"} <= set(node):
            raise FormatError(f"{path}: entry {key!r} is a map but not an !!opencv-matrix")
        rows, cols = node["rows"], node["cols"]
        if not (isinstance(rows, int) and isinstance(cols, int)) or isinstance(rows, bool) or isinstance(cols, bool) \
                or rows < 0 or cols < 0:
            raise FormatError(f"{path}: entry {key!r}: rows and cols must be non-negative integers")
        data = node["data"] if isinstance(node["data"], list) else [node["data"]]
        vals = [_number(v, path, key) for v in data]
        if len(vals) != rows * cols:
            raise FormatError(f"{path}: entry {key!r}: {len(vals)} values for a {rows}x{cols} matrix")
        return np.asarray(vals, dtype=np.float64).reshape(rows, cols)
    if isinstance(node, list):
        vals = []
        for i, item in enumerate(node):
            if isinstance(item, bool) or not isinstance(item, (int, float)):
                raise FormatError(f"{path}: entry {key!r}: element {i} of the sequence is not a number")
            vals.append(float(item))
        return np.asarray(vals, dtype=np.float64)
    if isinstance(node, bool):
        return str(node).lower()
    if isinstance(node, (int, float)):
        return float(node)
    if isinstance(node, str):
        return node
    return None


def _matrix(data: dict, key: str, shape: tuple[int, ...] | list[tuple[int, ...]], path: Path) -> np.ndarray:
    if key not in data:
        raise FormatError(f"{path}: missing entry {key!r} (found {sorted(data)})")
    m = data[key]
    if not isinstance(m, np.ndarray) or m.ndim != 2:
        raise FormatError(f"{path}: entry {key!r} is not an OpenCV matrix (!!opencv-matrix), found {type(m).__name__}")
    shapes = shape if isinstance(shape, list) else [shape]
    if m.shape not in shapes:
        exp = " or ".join(f"{s[0]}x{s[1]}" for s in shapes)
        raise FormatError(f"{path}: entry {key!r} has shape {m.shape[0]}x{m.shape[1]}, expected {exp}")
    if not np.all(np.isfinite(m)):
        raise FormatError(f"{path}: entry {key!r} holds non-finite values")
    return m


def read_calib_camera(path: str | os.PathLike, width: int, height: int) -> CameraIntrinsics:
    """Read an iai_kinect2 camera file (``calib_ir.yaml``/``calib_color.yaml``).

    ``width``/``height`` are not stored in the file; pass the camera's image size [px].
    Only 5 distortion coefficients ``(k1, k2, p1, p2, k3)`` are representable; a file
    with 8 (rational model) whose k4..k6 are non-zero is rejected.
    """
    path = Path(path)
    data = read_opencv_yaml(path)
    K = _matrix(data, "cameraMatrix", (3, 3), path)
    dist = _matrix(data, "distortionCoefficients", [(1, 4), (1, 5), (1, 8), (4, 1), (5, 1), (8, 1)], path).ravel()
    if dist.size == 8 and np.any(dist[5:] != 0):
        raise FormatError(f"{path}: rational distortion (k4..k6 = {dist[5:].tolist()}) is not supported; expected 5 coefficients")
    dist = np.concatenate([dist[:5], np.zeros(5 - min(dist.size, 5))])
    if abs(K[0, 1]) > 1e-9 or np.any(K[2] != [0, 0, 1]) or K[1, 0] != 0:
        raise FormatError(f"{path}: cameraMatrix is not an upper-triangular pinhole matrix without skew: {K.tolist()}")
    try:
        return CameraIntrinsics(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], tuple(dist))
    except InputError as exc:
        raise FormatError(f"{path}: {exc}") from None


def read_calib_ir(path: str | os.PathLike, width: int = IR_SIZE[0], height: int = IR_SIZE[1]) -> CameraIntrinsics:
    """Read ``calib_ir.yaml`` -> IR/depth intrinsics (512x424 unless given)."""
    return read_calib_camera(path, width, height)


def read_calib_color(path: str | os.PathLike, width: int = COLOR_SIZE[0], height: int = COLOR_SIZE[1]) -> CameraIntrinsics:
    """Read ``calib_color.yaml`` -> colour intrinsics (1920x1080 unless given)."""
    return read_calib_camera(path, width, height)


def read_calib_depth(path: str | os.PathLike) -> float:
    """Read ``calib_depth.yaml`` -> ``depthShift`` [mm] (added to measured depth by iai_kinect2)."""
    path = Path(path)
    data = read_opencv_yaml(path)
    if "depthShift" not in data:
        raise FormatError(f"{path}: missing entry 'depthShift' (found {sorted(data)})")
    v = data["depthShift"]
    if isinstance(v, np.ndarray) and v.size == 1:
        v = float(v.ravel()[0])
    if not isinstance(v, float) or not math.isfinite(v):
        raise FormatError(f"{path}: depthShift must be a finite number [mm], found {v!r}")
    return v


def read_calib_pose(path: str | os.PathLike) -> Extrinsics:
    """Read ``calib_pose.yaml`` -> :class:`Extrinsics` IR -> colour (``p_color = R p_ir + t``, t [m])."""
    path = Path(path)
    data = read_opencv_yaml(path)
    R = _matrix(data, "rotation", (3, 3), path)
    t = _matrix(data, "translation", [(3, 1), (1, 3)], path).ravel()
    try:
        return Extrinsics(R, t, "ir", "color")
    except InputError as exc:
        raise FormatError(f"{path}: {exc}") from None


def read_ir_points(path: str | os.PathLike, board: tuple[int, int] | None = None) -> np.ndarray:
    """Read ``NNNN_ir_points.yaml`` -> (N, 2) float64 corner pixels (u, v).

    Parameters
    ----------
    board : (cols, rows) inner corners; if given, N must equal cols*rows.

    Raises
    ------
    FormatError
        No ``points`` entry, odd number of values, or N not matching the board.
    """
    path = Path(path)
    data = read_opencv_yaml(path)
    if "points" not in data:
        raise FormatError(f"{path}: missing entry 'points' (found {sorted(data)})")
    p = data["points"]
    if not isinstance(p, np.ndarray):
        raise FormatError(f"{path}: 'points' must be a list of numbers, found {type(p).__name__}")
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 2 and p.shape[1] == 2:
        pts = p
    elif p.size % 2 == 0:
        pts = p.reshape(-1, 2)
    else:
        raise FormatError(f"{path}: 'points' holds {p.size} values, expected pairs (u, v)")
    if board is not None and len(pts) != board[0] * board[1]:
        raise FormatError(
            f"{path}: {len(pts)} corners do not match the board {board[0]}x{board[1]} "
            f"(expected {board[0] * board[1]} inner corners)"
        )
    return pts


# ----------------------------------------------------------------------------- writing
def _fmt(v: float) -> str:
    """OpenCV 2/3 ``icvDoubleToString``: integral -> ``'%d.'``, else ``'%.16e'``."""
    v = float(v)
    if math.isnan(v):
        return ".Nan"
    if math.isinf(v):
        return ".Inf" if v > 0 else "-.Inf"
    iv = int(round(v))
    if iv == v and abs(v) < 2**31:
        return f"{iv}."
    return f"{v:.16e}"


def _flow(prefix: str, values: list[str], indent: int, margin: int = 71) -> list[str]:
    """Emit a YAML flow sequence the way OpenCV's emitter wraps it."""
    lines = []
    line = prefix + " ["
    first = True
    for s in values:
        if not first:
            line += ","
        if len(line) + len(s) > margin and len(line) + len(s) - indent > 10:
            lines.append(line)
            line = " " * indent
        else:
            line += " "
        line += s
        first = False
    line += " ]"
    lines.append(line)
    return lines


def format_opencv_yaml(entries: dict) -> str:
    """Text of an OpenCV FileStorage YAML file (``%YAML:1.0``) in OpenCV 2/3 layout.

    Values: 2-D ndarray -> ``!!opencv-matrix`` (dt ``d``); number -> scalar; 1-D sequence of
    numbers -> flow list; str -> string.
    """
    out = ["%YAML:1.0", "---"] if True else []
    for key, val in entries.items():
        if isinstance(val, np.ndarray) and val.ndim == 2:
            m = np.asarray(val, dtype=np.float64)
            out += [f"{key}: !!opencv-matrix", f"   rows: {m.shape[0]}", f"   cols: {m.shape[1]}", "   dt: d"]
            out += _flow("   data:", [_fmt(x) for x in m.ravel()], indent=7)
        elif isinstance(val, (list, tuple, np.ndarray)):
            arr = np.asarray(val, dtype=np.float64).ravel()
            out += _flow(f"{key}:", [_float_fmt(x) for x in arr], indent=4)
        elif isinstance(val, str):
            out.append(f'{key}: "{val}"')
        else:
            out.append(f"{key}: {_fmt(val)}")
    return "\n".join(out) + "\n"


def _float_fmt(v: float) -> str:
    """Single-precision numbers (``%.8e``), as iai_kinect2's point lists."""
    v = float(v)
    iv = int(round(v))
    if iv == v and abs(v) < 2**31:
        return f"{iv}."
    return f"{v:.8e}"


def write_opencv_yaml(path: str | os.PathLike, entries: dict) -> Path:
    """Write ``entries`` as OpenCV FileStorage YAML atomically (see :func:`format_opencv_yaml`)."""
    return atomic_write_bytes(path, format_opencv_yaml(entries).encode())


def _camera_entries(intr: CameraIntrinsics, projection: np.ndarray | None = None) -> dict:
    K = intr.K
    if projection is None:
        projection = np.eye(4)
        projection[:3, :3] = K
    P = np.asarray(projection, float)
    if P.shape != (4, 4):
        raise InputError(f"projection must be 4x4, found {P.shape}")
    return {"cameraMatrix": K, "distortionCoefficients": intr.dist_array.reshape(1, 5),
            "rotation": np.eye(3), "projection": P}


def write_calib_ir(path: str | os.PathLike, intr: CameraIntrinsics, projection: np.ndarray | None = None) -> Path:
    """Write iai_kinect2 ``calib_ir.yaml`` (cameraMatrix, distortionCoefficients, rotation=I,
    projection = ``[K 0; 0 1]`` unless given)."""
    return write_opencv_yaml(path, _camera_entries(intr, projection))


def write_calib_color(path: str | os.PathLike, intr: CameraIntrinsics, projection: np.ndarray | None = None) -> Path:
    """Write iai_kinect2 ``calib_color.yaml`` (same layout as ``calib_ir.yaml``)."""
    return write_opencv_yaml(path, _camera_entries(intr, projection))


def read_projection(path: str | os.PathLike) -> np.ndarray | None:
    """The 4x4 ``projection`` of a camera file (iai_kinect2 usually stores ``[K 0; 0 1]``;
    some devices hold a different, rectified matrix), or None if absent."""
    path = Path(path)
    d = read_opencv_yaml(path)
    return _matrix(d, "projection", (4, 4), path) if "projection" in d else None


def write_calib_depth(path: str | os.PathLike, depth_shift_mm: float) -> Path:
    """Write iai_kinect2 ``calib_depth.yaml``: ``depthShift`` [mm] (corrected = measured + shift)."""
    if not math.isfinite(float(depth_shift_mm)):
        raise InputError(f"depth_shift_mm must be finite, found {depth_shift_mm}")
    return write_opencv_yaml(path, {"depthShift": float(depth_shift_mm)})


def essential_fundamental(extr: Extrinsics, ir: CameraIntrinsics, color: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Essential ``E = [t]x R`` and fundamental ``F = Kc^-T E Kir^-1`` (scaled to ``F[2,2] = 1``)
    as ``cv::stereoCalibrate`` returns them for camera 1 = IR, camera 2 = colour."""
    E = skew(extr.translation) @ extr.rotation
    F = np.linalg.inv(color.K).T @ E @ np.linalg.inv(ir.K)
    if abs(F[2, 2]) > 1e-300:
        F = F / F[2, 2]
    return E, F


def write_calib_pose(path: str | os.PathLike, extr: Extrinsics, ir: CameraIntrinsics | None = None,
                     color: CameraIntrinsics | None = None, essential: np.ndarray | None = None,
                     fundamental: np.ndarray | None = None) -> Path:
    """Write iai_kinect2 ``calib_pose.yaml`` from IR -> colour extrinsics [m].

    ``essential`` and ``fundamental`` are written as given, else derived (the fundamental needs
    ``ir`` and ``color`` intrinsics; without them it is written as zeros, unused by iai_kinect2).
    """
    if (extr.source, extr.target) not in (("ir", "color"), ("depth", "color")):
        raise InputError(f"write_calib_pose: expected IR -> colour extrinsics, found {extr.source} -> {extr.target}")
    if ir is not None and color is not None:
        E, F = essential_fundamental(extr, ir, color)
    else:
        E = skew(extr.translation) @ extr.rotation
        F = np.zeros((3, 3))
    E = E if essential is None else np.asarray(essential, float).reshape(3, 3)
    F = F if fundamental is None else np.asarray(fundamental, float).reshape(3, 3)
    return write_opencv_yaml(path, {"rotation": extr.rotation, "translation": extr.translation.reshape(3, 1),
                                    "essential": E, "fundamental": F})


def write_ir_points(path: str | os.PathLike, corners: np.ndarray) -> Path:
    """Write ``NNNN_ir_points.yaml`` from (N, 2) corner pixels."""
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    return write_opencv_yaml(path, {"points": c.ravel()})


# ----------------------------------------------------------------------------- whole folder
@dataclass(frozen=True)
class IaiCalibration:
    """One device's iai_kinect2 calibration.

    Attributes
    ----------
    ir : CameraIntrinsics          IR/depth camera (512x424).
    color : CameraIntrinsics | None  colour camera (1920x1080), if present.
    ir_to_color : Extrinsics | None  ``p_color = R p_ir + t`` [m], if present.
    depth_shift_mm : float | None   iai_kinect2 ``depthShift`` [mm], if present.
    ir_projection, color_projection : (4, 4) or None, the files' ``projection`` (kept for exact
        round trips; not used by tofmetry).
    essential, fundamental : (3, 3) or None, as stored in ``calib_pose.yaml`` (derivable from the
        rest; kept for exact round trips).
    """

    ir: CameraIntrinsics
    color: CameraIntrinsics | None = None
    ir_to_color: Extrinsics | None = None
    depth_shift_mm: float | None = None
    ir_projection: np.ndarray | None = None
    color_projection: np.ndarray | None = None
    essential: np.ndarray | None = None
    fundamental: np.ndarray | None = None


def read_iai_calibration(folder: str | os.PathLike) -> IaiCalibration:
    """Read ``calib_ir.yaml`` (required) and optional colour/pose/depth files from ``folder``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"iai_kinect2 calibration folder not found: {folder}")
    if not (folder / "calib_ir.yaml").is_file():
        raise InputError(f"{folder}: no calib_ir.yaml (an iai_kinect2 calibration folder holds calib_ir/color/pose/depth.yaml)")
    ir = read_calib_ir(folder / "calib_ir.yaml")
    color = read_calib_color(folder / "calib_color.yaml") if (folder / "calib_color.yaml").is_file() else None
    pose = E = F = None
    if (folder / "calib_pose.yaml").is_file():
        pose = read_calib_pose(folder / "calib_pose.yaml")
        pd = read_opencv_yaml(folder / "calib_pose.yaml")
        E = _matrix(pd, "essential", (3, 3), folder / "calib_pose.yaml") if "essential" in pd else None
        F = _matrix(pd, "fundamental", (3, 3), folder / "calib_pose.yaml") if "fundamental" in pd else None
    shift = read_calib_depth(folder / "calib_depth.yaml") if (folder / "calib_depth.yaml").is_file() else None
    return IaiCalibration(ir, color, pose, shift, read_projection(folder / "calib_ir.yaml"),
                          read_projection(folder / "calib_color.yaml") if color is not None else None, E, F)


def write_iai_calibration(folder: str | os.PathLike, cal: IaiCalibration) -> list[Path]:
    """Write the files of ``cal`` that are present into ``folder`` (each atomically)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = [write_calib_ir(folder / "calib_ir.yaml", cal.ir, cal.ir_projection)]
    if cal.color is not None:
        written.append(write_calib_color(folder / "calib_color.yaml", cal.color, cal.color_projection))
    if cal.ir_to_color is not None:
        written.append(write_calib_pose(folder / "calib_pose.yaml", cal.ir_to_color, cal.ir, cal.color,
                                        cal.essential, cal.fundamental))
    if cal.depth_shift_mm is not None:
        written.append(write_calib_depth(folder / "calib_depth.yaml", cal.depth_shift_mm))
    return written

