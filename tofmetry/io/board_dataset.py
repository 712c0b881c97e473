"""Board dataset: chessboard or ChArUco poses for board-based calibration (and the iai_kinect2 importer).

::

    dataset/
      board.json            {"cols": 5, "rows": 7, "square_mm": 30.0, "sensor": "kinect_v2", "source": ...}
                            or a ChArUco board: {"type": "charuco", "squares_x": 13, "squares_y": 10,
                            "square_mm": 80.0, "marker_mm": 56.0, "dictionary": "DICT_4X4_100", ...}
      intrinsics.json       IR/depth intrinsics (optional; e.g. from iai_kinect2 calib_ir.yaml)
      color_intrinsics.json colour intrinsics (optional)
      extrinsics.json       IR -> colour extrinsics [m] (optional)
      depth_shift.json      {"depth_shift_mm": s, "convention": "corrected = measured + shift"} (optional)
      depth_shift.npz       the same shift as a tofmetry DepthCalibration (zero surfaces, constant range curve;
                            written by the pipeline's importer, :mod:`tofmetry.pipelines.iai_import`)
      poses/NNNN/           one capture per board pose (capture.json, depth/, ir/, color/)
      poses/NNNN/corners.json  {"board": [cols, rows], "corners_px": [[u, v], ...] (or a list of such grids: several
                            boards in one view), "source": ...}; without it the boards are found in the IR image.
                            ChArUco: {"board": [cols, rows], "ids": [k, ...], "corners_px": [[u, v], ...]}, the
                            corners seen (inner corners cols x rows, id k = column k % cols, row k // cols)

``tofmetry calibrate depth`` dispatches here when the folder holds ``board.json``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tofmetry.errors import FormatError, InputError
from tofmetry.io._atomic import atomic_dir, atomic_write_json, read_json
from tofmetry.io.capture import Capture, CaptureMeta, CaptureWriter
from tofmetry.io import images
from tofmetry.io.intrinsics_json import read_intrinsics, write_intrinsics
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics


@dataclass(frozen=True)
class BoardSpec:
    """Chessboard: ``cols x rows`` inner corners, square size [mm]."""

    cols: int
    rows: int
    square_mm: float

    @property
    def size(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    @classmethod
    def parse(cls, text: str, square_mm: float) -> "BoardSpec":
        """``"5x7"`` (inner corners, cols x rows) and a square size [mm]."""
        m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text or "")
        if not m:
            raise InputError(f"--board: expected inner corners as COLSxROWS (e.g. 5x7), found {text!r}")
        cols, rows = int(m.group(1)), int(m.group(2))
        if cols < 2 or rows < 2:
            raise InputError(f"--board: need at least 2x2 inner corners, found {text!r}")
        if not square_mm or square_mm <= 0:
            raise InputError(f"--square-mm must be > 0, found {square_mm}")
        return cls(cols, rows, float(square_mm))


#: Keys of a ChArUco ``board.json`` (``"type": "charuco"``; ``dictionary`` optional, default DICT_4X4_50).
CHARUCO_KEYS = ("squares_x", "squares_y", "square_mm", "marker_mm", "dictionary")


def write_corners(path: str | os.PathLike, corners, board: BoardSpec, source: str = "", ids=None) -> Path:
    """Write ``corners.json``: one grid (cols*rows, 2) [px] or a list of grids (several boards in one view);
    with ``ids`` (ChArUco), the (N, 2) corners seen and their ids."""
    if ids is not None:
        k = np.asarray(ids, np.int64).ravel()
        c = np.asarray(corners, float).reshape(-1, 2)
        if len(k) != len(c) or (k.size and (k.min() < 0 or k.max() >= board.cols * board.rows)):
            raise InputError(f"{path}: {len(c)} corners with {len(k)} ids in 0..{board.cols * board.rows - 1} expected")
        return atomic_write_json(path, {"board": [board.cols, board.rows], "ids": k.tolist(), "corners_px": c,
                                        "source": source})
    grids = corners if isinstance(corners, (list, tuple)) else [corners]
    out = []
    for c in grids:
        c = np.asarray(c, float).reshape(-1, 2)
        if len(c) != board.cols * board.rows:
            raise InputError(f"{path}: {len(c)} corners do not match the board {board.cols}x{board.rows}")
        out.append(c)
    data = out[0] if len(out) == 1 and not isinstance(corners, (list, tuple)) else np.stack(out)
    return atomic_write_json(path, {"board": [board.cols, board.rows], "corners_px": data, "source": source})


def read_corners(path: str | os.PathLike, board: BoardSpec):
    """(cols*rows, 2) float64 corner pixels, or a list of such grids when the file holds several
    boards (``corners_px`` of shape (M, cols*rows, 2)); FormatError naming the file on mismatch.
    A file with ``ids`` (ChArUco) gives one (cols*rows, 2) grid, NaN where a corner was not seen."""
    d = read_json(path, "corners file")
    try:
        c = np.asarray(d["corners_px"], float)
    except (KeyError, TypeError, ValueError, OverflowError):
        raise FormatError(f"{path}: expected {{'corners_px': [[u, v], ...]}} (or a list of such grids)") from None
    n = board.cols * board.rows
    if "ids" in d:
        try:
            k = np.asarray(d["ids"], np.int64).ravel()
        except (TypeError, ValueError, OverflowError):
            raise FormatError(f"{path}: 'ids' must be a list of corner ids") from None
        if c.ndim != 2 or c.shape[1] != 2 or len(c) != len(k) or (k.size and (k.min() < 0 or k.max() >= n)) \
                or len(np.unique(k)) != len(k):
            raise FormatError(f"{path}: expected one [u, v] per id and distinct ids in 0..{n - 1} (board "
                              f"{board.cols}x{board.rows} inner corners), found {c.shape} corners and {len(k)} ids")
        g = np.full((n, 2), np.nan)
        g[k] = c
        return g
    if c.ndim == 3 and c.shape[1:] == (n, 2) and c.shape[0] >= 1:
        return [g for g in c]
    if c.ndim != 2 or c.shape[1] != 2 or len(c) != n:
        raise FormatError(
            f"{path}: {c.shape[0] if c.ndim else 0} corners do not match the board {board.cols}x{board.rows} "
            f"(expected {n}, or a list of grids of {n})"
        )
    return c


def charuco_spec(meta: dict, where: str) -> dict:
    """The ChArUco board of a ``board.json`` (``"type": "charuco"``) as a plain dict of :data:`CHARUCO_KEYS`
    (checked for types and sizes; the dictionary name is checked where the board is built)."""
    try:
        spec = {"squares_x": int(meta["squares_x"]), "squares_y": int(meta["squares_y"]),
                "square_mm": float(meta["square_mm"]), "marker_mm": float(meta["marker_mm"]),
                "dictionary": str(meta.get("dictionary", "DICT_4X4_50"))}
    except (KeyError, TypeError, ValueError, OverflowError):
        raise FormatError(f"{where}: a ChArUco board needs squares_x, squares_y (squares), square_mm, marker_mm "
                          "[, dictionary]") from None
    if spec["squares_x"] < 3 or spec["squares_y"] < 3 or not 0 < spec["marker_mm"] < spec["square_mm"]:
        raise FormatError(f"{where}: ChArUco board needs >= 3x3 squares and 0 < marker_mm < square_mm, found {spec}")
    return spec


class BoardDataset:
    """A board dataset opened for reading (see the module docstring).

    Attributes
    ----------
    board : BoardSpec, the inner corners and square size (ChArUco: ``squares - 1`` each way)
    charuco : the ChArUco board (:func:`charuco_spec` dict) when ``board.json`` says ``"type": "charuco"``,
        else None (a checkerboard)
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        meta = read_json(self.path / "board.json", "board.json")
        if not isinstance(meta, dict):
            raise FormatError(f"{self.path / 'board.json'}: expected a JSON object (cols, rows, square_mm, or a "
                              f"ChArUco board), found {type(meta).__name__}")
        self.charuco = None
        if str(meta.get("type", "checkerboard")).lower() == "charuco":
            self.charuco = charuco_spec(meta, str(self.path / "board.json"))
            self.board = BoardSpec(self.charuco["squares_x"] - 1, self.charuco["squares_y"] - 1, self.charuco["square_mm"])
        else:
            try:
                self.board = BoardSpec(int(meta["cols"]), int(meta["rows"]), float(meta["square_mm"]))
            except (KeyError, TypeError, ValueError, OverflowError):
                raise FormatError(f"{self.path / 'board.json'}: expected cols, rows (inner corners) and square_mm, "
                                  "or \"type\": \"charuco\" with squares_x, squares_y, square_mm, marker_mm") from None
        self.meta = meta
        self.sensor = str(meta.get("sensor", "unknown"))
        pdir = self.path / "poses"
        self.names = sorted(p.name for p in pdir.iterdir() if p.is_dir() and not p.name.startswith(".")) if pdir.is_dir() else []

    def __len__(self) -> int:
        return len(self.names)

    def capture(self, i: int) -> Capture:
        return Capture(self.path / "poses" / self.names[i])

    def corners(self, i: int):
        """The pose's corner grid (or list of grids), None without ``corners.json``."""
        f = self.path / "poses" / self.names[i] / "corners.json"
        return read_corners(f, self.board) if f.is_file() else None

    def intrinsics(self) -> CameraIntrinsics | None:
        f = self.path / "intrinsics.json"
        return read_intrinsics(f) if f.is_file() else None

    def depth_shift_mm(self) -> float | None:
        f = self.path / "depth_shift.json"
        return float(read_json(f, "depth_shift.json")["depth_shift_mm"]) if f.is_file() else None

    def extrinsics(self) -> Extrinsics | None:
        f = self.path / "extrinsics.json"
        return Extrinsics.from_dict(read_json(f, "extrinsics.json"), source_name=str(f)) if f.is_file() else None

    def load_poses(self, indices=None) -> list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
        """``[(depth (H,W) uint16 mm, ir (H,W) uint16, corners), ...]`` (first frame of each pose;
        corners: (cols*rows, 2), a list of grids, or None: found in the IR image by the calibration)."""
        out = []
        for i in (range(len(self)) if indices is None else indices):
            cap = self.capture(i)
            out.append((cap.depth(0), cap.ir(0), self.corners(i)))
        return out


_POSE_RE = re.compile(r"^(\d+)_depth\.(png|tif|tiff)$")


def import_iai_kinect2(src: str | os.PathLike, out: str | os.PathLike, board: BoardSpec | None = None,
                       force: bool = False, progress=None, extra=None) -> dict:
    """Convert an iai_kinect2 folder (``kinect_cal_data`` recording and/or ``calib_*.yaml``) to a board dataset.

    Parameters
    ----------
    src : folder with ``NNNN_depth.png``, ``NNNN_ir.png``, optional ``NNNN_ir_points.yaml`` and
        ``NNNN_color.png``, and/or ``calib_ir/color/pose/depth.yaml``.
    out : new dataset folder (refused if it exists unless ``force``).
    board : chessboard (required when the folder holds poses; not stored in iai_kinect2 files).
    progress : optional ``advance()`` callable, called once per pose.
    extra : optional ``extra(folder, calibration)`` writing more files into the dataset's
        temporary folder (committed with the rest), given the ``IaiCalibration`` read from ``src``.

    Returns
    -------
    dict summary: poses, files written, calibration found.
    """
    from tofmetry.io import iai_kinect2 as ik

    src = Path(src)
    if not src.is_dir():
        raise InputError(f"iai_kinect2 folder not found: {src}")
    poses = sorted((m.group(1), src / f) for f in os.listdir(src) if (m := _POSE_RE.match(f)))
    has_cal = (src / "calib_ir.yaml").is_file()
    if not poses and not has_cal:
        raise InputError(f"{src}: neither NNNN_depth.png poses nor calib_ir.yaml found (not an iai_kinect2 folder)")
    if poses and board is None:
        raise InputError(f"{src}: holds {len(poses)} board poses; pass the board (--board COLSxROWS --square-mm S)")
    cal = ik.read_iai_calibration(src) if has_cal else None
    summary = {"poses": 0, "with_corners": 0, "calibration": {}}
    with atomic_dir(out, force=force) as tmp:
        if board is not None:
            atomic_write_json(tmp / "board.json", {"cols": board.cols, "rows": board.rows, "square_mm": board.square_mm,
                                                   "sensor": "kinect_v2", "source": f"iai_kinect2 {src}"})
        if cal is not None:
            write_intrinsics(tmp / "intrinsics.json", cal.ir, sensor="kinect_v2", source=str(src / "calib_ir.yaml"))
            summary["calibration"]["intrinsics"] = cal.ir.to_dict()
            if cal.color is not None:
                write_intrinsics(tmp / "color_intrinsics.json", cal.color, sensor="kinect_v2", source=str(src / "calib_color.yaml"))
            if cal.ir_to_color is not None:
                atomic_write_json(tmp / "extrinsics.json", {**cal.ir_to_color.to_dict(), "sensor": "kinect_v2",
                                                            "file": str(src / "calib_pose.yaml")})
            if cal.depth_shift_mm is not None:
                atomic_write_json(tmp / "depth_shift.json", {"depth_shift_mm": cal.depth_shift_mm,
                                                             "convention": "corrected = measured + depth_shift_mm",
                                                             "sensor": "kinect_v2", "source": str(src / "calib_depth.yaml")})
                summary["calibration"]["depth_shift_mm"] = cal.depth_shift_mm
        if extra is not None and cal is not None:
            extra(tmp, cal)
        meta = CaptureMeta(sensor="kinect_v2", intrinsics=cal.ir if cal else None)
        for name, dpath in poses:
            ir_f = src / f"{name}_ir.png"
            if not ir_f.is_file():
                raise InputError(f"{dpath}: no matching IR image {ir_f.name}")
            depth = images.read_depth_image(dpath)
            ir = images.read_ir_image(ir_f)
            col_f = src / f"{name}_color.png"
            color = images.read_color_image(col_f) if col_f.is_file() else None
            pdir = tmp / "poses" / name
            meta.extra = {"source": str(dpath)}
            with CaptureWriter(pdir, meta) as w:
                w.add(depth, ir=ir, color=color)
            pts_f = src / f"{name}_ir_points.yaml"
            if pts_f.is_file():
                corners = ik.read_ir_points(pts_f, board.size)
                write_corners(pdir / "corners.json", corners, board, source=str(pts_f))
                summary["with_corners"] += 1
            summary["poses"] += 1
            if progress is not None:
                progress()
    return summary


def export_iai_kinect2(src: str | os.PathLike, out: str | os.PathLike, force: bool = False,
                       depth_shift_mm: float | None = None) -> dict:
    """Write iai_kinect2 calibration files from a tofmetry calibration.

    Parameters
    ----------
    src : one of
        * a depth calibration ``.npz`` -> ``calib_ir.yaml`` (its intrinsics) and ``calib_depth.yaml``
          with ``depthShift = -offset_mm`` (iai_kinect2 holds only a constant: the range curve's
          mean; per-pixel surfaces and the range shape are dropped, reported in the summary);
        * an ``intrinsics.json`` -> ``calib_ir.yaml`` (+ ``calib_depth.yaml`` if ``depth_shift_mm``);
        * a folder from ``tofmetry import iai-kinect2`` -> every file it can (ir, color, pose, depth).
    out : output folder; existing ``calib_*.yaml`` there are refused unless ``force``.
    """
    from tofmetry.io.iai_kinect2 import CALIB_FILES, IR_SIZE, IaiCalibration, write_iai_calibration

    src, out = Path(src), Path(out)
    dropped = []
    if src.is_dir():
        if not (src / "intrinsics.json").is_file():
            raise InputError(f"{src}: no intrinsics.json (expected a folder written by 'tofmetry import iai-kinect2')")
        ir = read_intrinsics(src / "intrinsics.json")
        color = read_intrinsics(src / "color_intrinsics.json") if (src / "color_intrinsics.json").is_file() else None
        pose = None
        if (src / "extrinsics.json").is_file():
            pose = Extrinsics.from_dict(read_json(src / "extrinsics.json"), source_name=str(src / "extrinsics.json"))
        shift = depth_shift_mm
        if shift is None and (src / "depth_shift.json").is_file():
            shift = float(read_json(src / "depth_shift.json")["depth_shift_mm"])
        cal = IaiCalibration(ir, color, pose, shift)
    elif src.suffix.lower() == ".npz":
        from tofmetry.io.calibration_file import read_calibration_file

        head, arrays = read_calibration_file(src)
        missing = [k for k in ("sensor", "offset_mm", "intrinsics") if k not in head]
        if missing:
            raise FormatError(f"{src}: not a valid tofmetry calibration: its header lacks {missing}")
        if head.get("sensor") not in ("kinect_v2", "unknown"):
            from tofmetry.errors import SensorMismatchError

            raise SensorMismatchError(f"{src}: calibration is for sensor {head.get('sensor')!r}; iai_kinect2 is for kinect_v2")
        if not isinstance(head["offset_mm"], (int, float)) or not isinstance(head["intrinsics"], dict):
            raise FormatError(f"{src}: not a valid tofmetry calibration: 'offset_mm' must be a number and "
                              "'intrinsics' an object in its header")
        shift = -float(head["offset_mm"]) if depth_shift_mm is None else float(depth_shift_mm)
        if head.get("surface_model") != "none" or len(arrays["node_mm"]) > 1 or "ray_knots" in arrays:
            dropped.append("per-pixel surfaces")
        dropped.append("range-curve shape (only its mean is kept as depthShift)")
        cal = IaiCalibration(CameraIntrinsics.from_dict(head["intrinsics"], source=f"{src} header"), None, None, shift)
    elif src.suffix.lower() == ".json":
        cal = IaiCalibration(read_intrinsics(src), None, None, depth_shift_mm)
    else:
        raise InputError(f"{src}: expected a calibration .npz, an intrinsics.json or an imported iai-kinect2 folder")
    if cal.ir.shape != (IR_SIZE[1], IR_SIZE[0]):
        raise InputError(f"{src}: intrinsics are {cal.ir.width}x{cal.ir.height}; iai_kinect2 IR files are 512x424")
    existing = [f for f in CALIB_FILES if (out / f).exists()]
    if existing and not force:
        raise InputError(f"{out}: already holds {existing}; refusing to overwrite (pass --force)")
    written = write_iai_calibration(out, cal)
    return {"written": [str(p) for p in written], "depth_shift_mm": cal.depth_shift_mm, "dropped": dropped}


def export_iai_kinect2_cli(src, out, *, force: bool = False, depth_shift_mm: float | None = None, **_ignored) -> dict:
    """Registry entry for :func:`export_iai_kinect2`."""
    return export_iai_kinect2(src, out, force=force, depth_shift_mm=depth_shift_mm)
