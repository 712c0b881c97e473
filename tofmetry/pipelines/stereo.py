"""Pipeline ``calibrate stereo``: a folder of paired IR and colour board images -> IR–colour extrinsics.

Folder layout: ``NNNN_ir.<ext>`` and ``NNNN_color.<ext>`` (any image format OpenCV reads; IR may
be 16-bit), one pair per stem. The board's corners are found in both images of each pair
(:func:`~tofmetry.calibrate.detect_corners`); a pair where either image shows no whole board is
skipped and named. Both detections are put in the same physical order (the first row pointing
right in the image: the two cameras look the same way, so one grid order is one board corner).
Every 4th usable pair is held out of the fit to validate it.

With a ChArUco board (``charuco=``) the corners come with their ids
(:func:`~tofmetry.calibrate.detect_charuco`): a board partly outside either image still counts, each
pair contributing the corners both cameras found (at least 6), with their own object points.

Outputs (:func:`write_stereo_outputs`): iai_kinect2's ``calib_pose.yaml`` and ``stereo.json``
(extrinsics, uncertainties, residuals, held-out error, pairs used and skipped).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.calibrate import CharucoBoard, StereoResult, board_object_points, calibrate_stereo, common_corners, \
    detect_charuco, detect_corners
from tofmetry.errors import InputError
from tofmetry.io import atomic_write_json
from tofmetry.io.iai_kinect2 import write_calib_pose
from tofmetry.io.images import GRAY_IMAGE_SUFFIXES, read_color_image, read_gray_image
from tofmetry.sensor.intrinsics import CameraIntrinsics


@dataclass
class StereoRun:
    """Result of :func:`stereo_from_images`: ``result`` (StereoResult), the pair stems used, the
    skipped ones with the reason, and the intrinsics held fixed."""

    result: StereoResult
    pairs: list[str]
    skipped: dict[str, str]
    ir: CameraIntrinsics
    color: CameraIntrinsics
    sources: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {**self.result.to_dict(), "pairs": self.pairs, "skipped": self.skipped,
                "ir_intrinsics": self.ir.to_dict(), "color_intrinsics": self.color.to_dict(), "sources": self.sources}


def list_pairs(folder: str | os.PathLike) -> list[tuple[str, Path, Path]]:
    """``(stem, ir_path, color_path)`` of every ``<stem>_ir.*`` with a ``<stem>_color.*``, sorted."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"pairs folder not found: {folder}")
    files = {p.name: p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in GRAY_IMAGE_SUFFIXES}
    ir = {p.stem[:-3]: p for p in files.values() if p.stem.endswith("_ir")}
    col = {p.stem[:-6]: p for p in files.values() if p.stem.endswith("_color")}
    stems = sorted(set(ir) & set(col))
    if not stems:
        raise InputError(f"{folder}: no image pairs; expected NNNN_ir.<ext> and NNNN_color.<ext> "
                         f"({len(ir)} IR and {len(col)} colour images found)")
    return [(s, ir[s], col[s]) for s in stems]


def _oriented(corners: np.ndarray, board: tuple[int, int]) -> np.ndarray:
    """The 180°-ambiguous grid order fixed: the first row runs towards +u."""
    c = np.asarray(corners, np.float64).reshape(-1, 2)
    return c[::-1].copy() if c[board[0] - 1, 0] < c[0, 0] else c


def stereo_from_images(folder: str | os.PathLike, board: tuple[int, int], square_mm: float,
                       ir: CameraIntrinsics, color: CameraIntrinsics, advance=None,
                       charuco: CharucoBoard | None = None, min_common: int = 6) -> StereoRun:
    """Detect the board in every pair of ``folder`` and calibrate the IR -> colour extrinsics.

    Parameters
    ----------
    folder : folder of ``NNNN_ir.*`` / ``NNNN_color.*`` pairs
    board : (cols, rows) inner corners; square_mm : square size [mm]
    ir, color : intrinsics of the two cameras (held fixed)
    advance : optional progress callable, one call per pair
    charuco : a ChArUco board instead of a checkerboard (``board`` and ``square_mm`` are then
        ignored): partial views allowed, each pair uses the corners both images show
    min_common : ChArUco: fewest corners common to both images for a pair to be used

    Raises
    ------
    InputError
        No pairs, an image of the wrong size, or fewer than 3 usable pairs.
    """
    obj = None if charuco is not None else board_object_points(board, square_mm)
    used, skipped, A, B, O = [], {}, [], [], []
    for stem, pir, pcol in list_pairs(folder):
        imgs = []
        for what, path, intr, read in (("IR", pir, ir, read_gray_image), ("colour", pcol, color, read_color_image)):
            img = read(path)
            if img.shape[:2] != intr.shape:
                raise InputError(f"{path}: {what} image is {img.shape[1]}x{img.shape[0]}, the {what} intrinsics "
                                 f"are {intr.width}x{intr.height}")
            imgs.append(img)
        if charuco is not None:
            da, db = detect_charuco(imgs[0], charuco), detect_charuco(imgs[1], charuco)
            if advance is not None:
                advance()
            if da is None or db is None:
                skipped[stem] = "fewer than 6 ChArUco corners found in the " + ("IR" if da is None else "colour") \
                    + " image"
                continue
            ids, pa, pb = common_corners(da.ids, da.corners, db.ids, db.corners)
            if len(ids) < min_common:
                skipped[stem] = (f"{len(ids)} ChArUco corners found in both images ({len(da.ids)} IR, "
                                 f"{len(db.ids)} colour); need at least {min_common}")
                continue
            used.append(stem)
            A.append(pa)
            B.append(pb)
            O.append(charuco.object_points(ids))
            continue
        ca, cb = detect_corners(imgs[0], board), detect_corners(imgs[1], board)
        if advance is not None:
            advance()
        if ca is None or cb is None:
            skipped[stem] = "board not found in the " + ("IR" if ca is None else "colour") + " image"
            continue
        used.append(stem)
        A.append(_oriented(ca, board))
        B.append(_oriented(cb, board))
        O.append(obj)
    if len(used) < 3:
        raise InputError(f"{folder}: the board was found in both images of {len(used)} pair(s); need at least 3 "
                         f"(skipped: {skipped})")
    res = calibrate_stereo(O, A, B, ir, color)
    src = {} if charuco is None else {"charuco": charuco.to_dict(), "corners_per_pair": [len(o) for o in O]}
    return StereoRun(res, used, skipped, ir, color, src)


def write_stereo_outputs(run: StereoRun, out_dir: str | os.PathLike) -> list[Path]:
    """Write ``calib_pose.yaml`` (iai_kinect2) and ``stereo.json`` into ``out_dir`` (atomically each)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pose = write_calib_pose(out / "calib_pose.yaml", run.result.extrinsics, run.ir, run.color)
    js = atomic_write_json(out / "stereo.json", run.to_dict())
    return [pose, js]
