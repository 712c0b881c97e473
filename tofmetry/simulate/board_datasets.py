"""Board datasets for the board depth calibration, rendered by the virtual sensor.

``board_dataset(out, ...)`` writes the layout of :mod:`tofmetry.io.board_dataset` that
``tofmetry calibrate depth`` reads: ``board.json`` (a checkerboard, or a ChArUco board with
``"type": "charuco"``) and ``poses/NNNN/`` captures (depth + IR, the sensor warm), no corner files
(the calibration finds the boards in the IR images), no intrinsics (it fits them on the corners
unless given). Beside them, never read by processing: ``truth.json`` (the sensor draw, the
board-to-camera pose of every pose) and ``truth.npz`` (per pose the noise-free systematic depth
error ``systematic_mm_NNNN`` (H, W) [mm]: range error, deformation and amplitude bias of every
pixel, :meth:`~tofmetry.simulate.camera.VirtualKinect.systematic_mm`).

Poses: a checkerboard is seen whole (:func:`~tofmetry.simulate.poses.board_poses`, pushed against
the image centre, corners and edges); a ChArUco board is aimed at them and overhangs the image
(:func:`~tofmetry.simulate.poses.charuco_poses`, partial views). Both at distances drawn in
``dist_range_m``: the default 0.6-1.3 m keeps the default ChArUco board's 9.3 mm marker modules at
2.5 px or more on the Kinect v2 (its decoder's limit is about 2 px).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tofmetry.errors import InputError
from tofmetry.io import CaptureMeta, atomic_dir, atomic_write_json
from tofmetry.simulate import scenes
from tofmetry.simulate.datasets import CHARUCO_DEFAULT, Progress, _sensor, _truth_common, _write_npz, write_frames
from tofmetry.simulate.errors import ErrorModel
from tofmetry.simulate.family import SensorDraw

#: The checkerboard of :func:`board_dataset` by default: 9 x 6 inner corners of 50 mm (0.5 x 0.35 m).
CHECKERBOARD_DEFAULT = {"cols": 9, "rows": 6, "square_mm": 50.0}
#: Distances of the board from the camera [m] (see the module docstring).
BOARD_DISTANCES_M = (0.6, 1.3)


def board_spec(board) -> dict:
    """The board of :func:`board_dataset` as its ``board.json`` content.

    Parameters
    ----------
    board : ``"checkerboard"`` (:data:`CHECKERBOARD_DEFAULT`), ``"charuco"``
        (:data:`~tofmetry.simulate.datasets.CHARUCO_DEFAULT`), or a dict: ``{"cols", "rows",
        "square_mm"}`` (inner corners) or ``{"type": "charuco", "squares_x", "squares_y",
        "square_mm", "marker_mm", "dictionary"}``
    """
    if isinstance(board, str):
        if board == "checkerboard":
            return {"type": "checkerboard", **CHECKERBOARD_DEFAULT}
        if board == "charuco":
            return {"type": "charuco", **CHARUCO_DEFAULT}
        raise InputError(f"board_dataset: board must be 'checkerboard', 'charuco' or a dict, found {board!r}")
    if not isinstance(board, dict):
        raise InputError(f"board_dataset: board must be 'checkerboard', 'charuco' or a dict, found {type(board).__name__}")
    try:
        if board.get("type") == "charuco":
            b = {"type": "charuco", "squares_x": int(board["squares_x"]), "squares_y": int(board["squares_y"]),
                 "square_mm": float(board["square_mm"]), "marker_mm": float(board["marker_mm"]),
                 "dictionary": str(board.get("dictionary", "DICT_4X4_50"))}
            ok = b["squares_x"] >= 3 and b["squares_y"] >= 3 and 0 < b["marker_mm"] < b["square_mm"]
        else:
            b = {"type": "checkerboard", "cols": int(board["cols"]), "rows": int(board["rows"]),
                 "square_mm": float(board["square_mm"])}
            ok = b["cols"] >= 2 and b["rows"] >= 2 and b["square_mm"] > 0
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"board_dataset: board {board!r} lacks or mistypes {e}") from None
    if not ok:
        raise InputError(f"board_dataset: implausible board {b}")
    return b


def _scene_and_pose(b: dict, intr, n: int, rng: np.random.Generator, dist_range_m, max_tilt_deg: float):
    """Scene factory ``T -> Scene`` and the ``n`` board-to-camera poses [m] of board ``b``."""
    from tofmetry.simulate.poses import board_poses, charuco_poses

    sq = b["square_mm"] / 1000.0
    if b["type"] == "charuco":
        c, r = b["squares_x"] - 1, b["squares_y"] - 1
        gx, gy = np.meshgrid(np.arange(1, c + 1) * sq, np.arange(1, r + 1) * sq)
        pts = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
        poses = charuco_poses(n, intr, b["squares_x"] * sq, b["squares_y"] * sq, rng, dist_range=dist_range_m,
                              max_tilt_deg=max_tilt_deg, corners_m=pts)

        def scene(T):
            return scenes.charuco(b["squares_x"], b["squares_y"], sq, b["marker_mm"] / 1000.0, b["dictionary"],
                                  board_to_world=T)
        return scene, poses
    poses = board_poses(n, intr, b["cols"], b["rows"], sq, rng, dist_range=dist_range_m, max_tilt_deg=max_tilt_deg)
    return (lambda T: scenes.checkerboard(b["cols"], b["rows"], sq, T)), poses


def board_dataset(out: str | os.PathLike, n_poses: int = 20, board="charuco", seed: int = 0,
                  errors: ErrorModel | None = None, sensor: SensorDraw | None = None,
                  dist_range_m: tuple[float, float] = BOARD_DISTANCES_M, max_tilt_deg: float = 35.0,
                  n_frames: int = 1, supersample: int = 4, force: bool = False, progress: Progress = None) -> Path:
    """A board dataset for the board depth calibration (see the module docstring).

    Parameters
    ----------
    out : the dataset folder (refused if it exists unless ``force``)
    n_poses : board poses (one capture each, ``poses/0000`` ...)
    board : see :func:`board_spec`
    seed : draws the poses (``rng [seed, 13]``) and the sensor's noise
    errors, sensor : the sensor (default Kinect v2; ``random_sensor(seed)`` for another of the class)
    dist_range_m : (near, far) board distance [m]; max_tilt_deg : largest board tilt [deg]
    n_frames : frames per pose (the calibration uses the first)
    supersample : sub-rays per pixel and axis on edges (anti-aliased IR for the corner detectors)

    Returns
    -------
    ``out``
    """
    if int(n_poses) < 2:
        raise InputError(f"board_dataset: n_poses must be >= 2, found {n_poses}")
    lo, hi = (float(x) for x in dist_range_m)
    if not 0.3 <= lo < hi:
        raise InputError(f"board_dataset: dist_range_m must be (near, far) with 0.3 <= near < far [m], found {dist_range_m}")
    b = board_spec(board)
    sensor = _sensor(errors, sensor)
    vk = sensor.camera(seed, supersample)
    scene_of, poses = _scene_and_pose(b, vk.intrinsics, int(n_poses), np.random.default_rng([int(seed), 13]),
                                      (lo, hi), float(max_tilt_deg))
    out = Path(out)
    names, arrays = [], {}
    with atomic_dir(out, force=force) as tmp:
        for k, T in enumerate(poses):
            name = f"{k:04d}"
            scene = scene_of(T)
            rd = vk.render(scene)
            ts = 3600.0 + 60.0 * k + np.arange(n_frames, dtype=float)
            meta = CaptureMeta(sensor="kinect_v2", timestamps_s=ts.tolist())
            write_frames(tmp / "poses" / name, vk.iter_frames(scene, n_frames, rendering=rd, timestamps_s=ts), meta)
            arrays[f"systematic_mm_{name}"] = vk.systematic_mm(rd).astype(np.float32)
            names.append(name)
            if progress is not None:
                progress(1)
        atomic_write_json(tmp / "board.json", {**b, "sensor": "kinect_v2", "source": "tofmetry simulate board-dataset"})
        truth = _truth_common(vk, seed, sensor) | {
            "dataset": "board_dataset", "board": b, "dist_range_m": [lo, hi], "max_tilt_deg": float(max_tilt_deg),
            "board_frame": ("ChArUco: OpenCV's, origin at the outer top-left corner of the squares" if b["type"] ==
                            "charuco" else "checkerboard: origin at the first inner corner") +
                           ", x along columns, y along rows, z into the board; metres",
            "poses": [{"pose": n, "board_to_camera": T} for n, T in zip(names, poses)],
            "systematic_note": "truth.npz systematic_mm_NNNN: the noise-free depth error of each pixel [mm] "
                               "(measured = true Z + systematic + noise)"}
        atomic_write_json(tmp / "truth.json", truth)
        _write_npz(tmp / "truth.npz", **arrays)
    return out
