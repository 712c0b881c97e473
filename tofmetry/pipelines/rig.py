"""Pipeline ``calibrate rig``: one folder per sensor of board images of common poses -> ``rig.json``.

Folder layout::

    RIG/
      <sensor A>/intrinsics.json  0000.png 0001.png ...   # the first sub-folder (by name) is the rig frame
      <sensor B>/intrinsics.json  0000.png 0001.png ...
      ...

Every sub-folder holding an ``intrinsics.json`` is a sensor; images with the same stem in two
sub-folders were taken of the same board pose (the board still, all sensors triggered). Any
image format :func:`~tofmetry.io.images.read_gray_image` reads; a 16-bit IR image is fine. The
checkerboard's corners are found in each image (:func:`~tofmetry.calibrate.detect_corners`, the
whole board must be seen); a view a sensor did not see whole is skipped for that sensor and named.
Each sensor is calibrated against the first (:func:`~tofmetry.calibrate.calibrate_rig`, intrinsics
held fixed, every 4th shared view held out for validation).

With a ChArUco board (``charuco=``) a sensor's view counts when it shows at least 6 identified
corners (:func:`~tofmetry.calibrate.detect_charuco`, partial views allowed), and each sensor is
calibrated against the first from the corners both found in a view (at least 6).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.calibrate import CharucoBoard, RigResult, board_object_points, calibrate_rig, detect_charuco, \
    detect_corners
from tofmetry.errors import InputError
from tofmetry.io.images import GRAY_IMAGE_SUFFIXES, read_gray_image
from tofmetry.io.intrinsics_json import read_intrinsics
from tofmetry.io.rig_json import RigSensor, write_rig
from tofmetry.pipelines.stereo import _oriented
from tofmetry.sensor.intrinsics import CameraIntrinsics


@dataclass
class RigRun:
    """Result of :func:`rig_from_folders`.

    Attributes
    ----------
    result : RigResult (extrinsics rig -> sensor, per-pair residuals, uncertainty, held-out error)
    sensors : sensor names (sub-folder names), sensor 0 first (the rig frame)
    intrinsics : list of CameraIntrinsics (held fixed)
    views : view stems (image stems present in at least one sub-folder)
    skipped : dict sensor name -> {view stem: why}
    """

    result: RigResult
    sensors: list
    intrinsics: list
    views: list
    skipped: dict = field(default_factory=dict)
    folder: str = ""

    def rig_sensors(self) -> list[RigSensor]:
        out = []
        for k, (n, intr, e) in enumerate(zip(self.sensors, self.intrinsics, self.result.extrinsics)):
            p = self.result.pairs[k]
            rs = (0.0, 0.0, 0.0) if p is None else tuple(p.rotation_std_deg.tolist())
            ts = (0.0, 0.0, 0.0) if p is None else tuple(p.translation_std_mm.tolist())
            out.append(RigSensor(n, intr, type(e)(e.rotation, e.translation, self.sensors[0], n), rs, ts))
        return out


def _images(folder: Path) -> dict[str, Path]:
    return {p.stem: p for p in sorted(folder.iterdir())
            if p.is_file() and p.suffix.lower() in GRAY_IMAGE_SUFFIXES and not p.name.startswith(".")}


def list_rig_sensors(folder: str | os.PathLike) -> list[Path]:
    """The sensor sub-folders of ``folder`` (those with an ``intrinsics.json``), sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"rig folder not found: {folder}")
    subs = sorted(p for p in folder.iterdir() if p.is_dir() and (p / "intrinsics.json").is_file())
    if len(subs) < 2:
        raise InputError(f"{folder}: expected one sub-folder per sensor, each with intrinsics.json and board images; "
                         f"found {len(subs)} such sub-folder(s)")
    return subs


def rig_from_folders(folder: str | os.PathLike, board: tuple[int, int], square_mm: float, advance=None,
                     charuco: CharucoBoard | None = None) -> RigRun:
    """Detect the board in every sensor's images and calibrate the rig (see the module docstring).

    Parameters
    ----------
    folder : the rig folder; board : (cols, rows) inner corners; square_mm : square size [mm]
    advance : optional progress callable, one call per image
    charuco : a ChArUco board instead of a checkerboard (``board``, ``square_mm`` then ignored)

    Raises
    ------
    InputError
        Fewer than 2 sensor sub-folders, an image whose size differs from its intrinsics, or a sensor
        sharing fewer than 3 usable views with the first.
    """
    subs = list_rig_sensors(folder)
    names = [p.name for p in subs]
    intr: list[CameraIntrinsics] = [read_intrinsics(p / "intrinsics.json") for p in subs]
    imgs = [_images(p) for p in subs]
    views = sorted(set().union(*[set(m) for m in imgs]))
    if not views:
        raise InputError(f"{folder}: no board images in the sensor sub-folders (expected e.g. 0000.png)")
    corners = [[None] * len(views) for _ in subs]
    ids = [[None] * len(views) for _ in subs]
    skipped: dict = {n: {} for n in names}
    for s, (p, k, m) in enumerate(zip(subs, intr, imgs)):
        for v, stem in enumerate(views):
            if stem not in m:
                skipped[names[s]][stem] = "no image"
                continue
            img = read_gray_image(m[stem])
            if img.shape[:2] != k.shape:
                raise InputError(f"{m[stem]}: image is {img.shape[1]}x{img.shape[0]}, {p / 'intrinsics.json'} says "
                                 f"{k.width}x{k.height}")
            if charuco is not None:
                d = detect_charuco(img, charuco)
                if d is None:
                    skipped[names[s]][stem] = "fewer than 6 ChArUco corners found"
                else:
                    corners[s][v], ids[s][v] = d.corners, d.ids
            else:
                c = detect_corners(img, board)
                if c is None:
                    skipped[names[s]][stem] = "board not found whole"
                else:
                    corners[s][v] = _oriented(c, board)
            if advance is not None:
                advance()
    obj = charuco.object_points() if charuco is not None else board_object_points(board, square_mm)
    try:
        res = calibrate_rig([obj] * len(views), corners, intr, ids=ids if charuco is not None else None)
    except InputError as e:
        raise InputError(f"{folder}: {e} (sensors in order: {', '.join(names)}; skipped: "
                         f"{ {n: d for n, d in skipped.items() if d} })") from None
    return RigRun(res, names, intr, views, {n: d for n, d in skipped.items() if d}, str(folder))


def write_rig_outputs(run: RigRun, path: str | os.PathLike) -> Path:
    """``rig.json`` (:mod:`tofmetry.io.rig_json`) with per-sensor diagnostics (views shared with
    sensor 0, fit RMS, held-out RMS / max in px, views skipped)."""
    per = []
    for k, n in enumerate(run.sensors):
        p = run.result.pairs[k]
        d = {"shared_views": int(run.result.shared_views[k]), "skipped_views": run.skipped.get(n, {})}
        if p is not None:
            d.update({"fit_rms_px": float(p.rms_px), "heldout_rms_px": _num(p.heldout_rms_px),
                      "heldout_max_px": _num(p.heldout_max_px), "n_train": p.n_train, "n_heldout": p.n_heldout})
        per.append(d)
    return write_rig(path, run.rig_sensors(), per_sensor=per, source_folder=run.folder, views=run.views,
                     meaning="rig_to_sensor maps a point from the rig frame (the first sensor's camera frame, metres) "
                             "to the sensor's camera frame: p_sensor = R p_rig + t; std: jackknife over the views")


def _num(x: float):
    return None if not np.isfinite(x) else float(x)
