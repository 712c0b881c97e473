"""Intrinsics pipeline: a folder of checkerboard or ChArUco images in, an :class:`IntrinsicsRun` out."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.calibrate import figures as F
from tofmetry.calibrate import (
    CharucoBoard, IntrinsicsResult, calibrate_intrinsics, cross_validate_intrinsics, detect_board, detect_charuco,
)
from tofmetry.errors import DegenerateFitError, InputError
from tofmetry.io import atomic_write_json
from tofmetry.io.images import GRAY_IMAGE_SUFFIXES, read_gray_image
from tofmetry._shared.figures import save_png
from tofmetry.pipelines._common import _adv
from tofmetry.pipelines.plausibility import check_intrinsics, enforce, refuse_degenerate
from tofmetry.sensor import CameraIntrinsics


@dataclass(eq=False)
class IntrinsicsRun:
    """Checkerboard intrinsics from a folder of images.

    Attributes
    ----------
    result : IntrinsicsResult (kept views; ``result.rejected_views`` the outlier views)
    names : image names with a detected board (incl. outlier views), same order as ``corners``
    rejected : image names where no board was detected (or a corner disagreed with its grid neighbours)
    rejected_reasons : dict rejected image name -> why
    rejected_views : outlier views (RMS above ``max(1 px, 5 x median)``), left out of the fit
    corners : list of (cols*rows, 2) float64 [px], one per ``names``
    image_size : (width, height) [px]
    cv : k-fold pose-wise held-out reprojection RMS (see ``cross_validate_intrinsics``), names of the views
    detections : dict image name -> how its corners were found: ``detector`` (OpenCV grid finder),
        ``model_fraction`` (share of corners refined by the X-junction fit), ``median_corner_std_px``
        (median standard uncertainty of its corners from the fit residuals [px]), ``median_blur_px``
        (fitted edge blur, Gaussian sigma [px]), ``dtype`` (of the file)
    object_points : list of (N_v, 3) board coordinates [mm] per ``names`` (ChArUco: each view's
        own corners), empty for a checkerboard (every view has the whole board)
    charuco : the ChArUco board (``CharucoBoard.to_dict()``), None for a checkerboard
    plausibility : the plausibility gate's record (:mod:`tofmetry.pipelines.plausibility`):
        ``{"checked", "accepted", "findings"}``; ``accepted`` is True when implausible findings were
        accepted by the caller (``--accept-implausible``)
    """

    result: IntrinsicsResult
    names: list
    rejected: list
    rejected_views: list
    corners: list
    image_size: tuple
    board: tuple
    square_mm: float
    cv: dict
    images_dir: str = ""
    seconds: float = float("nan")
    detections: dict = field(default_factory=dict)
    rejected_reasons: dict = field(default_factory=dict)
    plausibility: dict = field(default_factory=dict)
    object_points: list = field(default_factory=list)
    charuco: dict | None = None

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self.result.intrinsics

    def to_dict(self) -> dict:
        cv = dict(self.cv)
        if "views" in cv:
            cv["views"] = [self.names[i] for i in cv["views"]]
        return {**self.result.to_dict(), "images_dir": self.images_dir, "board": list(self.board),
                "square_mm": self.square_mm, "image_size": list(self.image_size), "detected": self.names,
                "rejected": self.rejected, "rejected_reasons": self.rejected_reasons, "cross_validation": cv,
                "detections": self.detections, "seconds": self.seconds, "plausibility": self.plausibility,
                "charuco": self.charuco}


def list_board_images(images_dir: Path) -> list[Path]:
    """The images of a folder, by suffix (:data:`~tofmetry.io.images.GRAY_IMAGE_SUFFIXES`), sorted
    by name; hidden files are skipped. Raises InputError when the folder is missing or holds none."""
    images_dir = Path(images_dir)
    if not images_dir.is_dir():
        raise InputError(f"images folder not found: {images_dir}")
    files = sorted(p for p in images_dir.iterdir()
                   if p.is_file() and p.suffix.lower() in GRAY_IMAGE_SUFFIXES and not p.name.startswith("."))
    if not files:
        raise InputError(f"{images_dir}: no images (expected files ending in {', '.join(GRAY_IMAGE_SUFFIXES)})")
    return files


def intrinsics_from_images(images_dir: Path, board: tuple[int, int], square_mm: float, *, leave_one_out: bool = True,
                           fix_k3: bool = False, advance=None, k_folds: int = 5,
                           accept_implausible: bool = False, charuco: CharucoBoard | None = None) -> IntrinsicsRun:
    """Detect the board in every image of ``images_dir``, calibrate, reject outlier views,
    analyse stability (leave-one-out) and cross-validate (k-fold over views, held-out views'
    pose solved with the fitted intrinsics).

    Parameters
    ----------
    images_dir : folder of checkerboard images: any 8- or 16-bit single-channel image OpenCV
        reads (PNG, BMP, TIFF, PGM ...), greyscale stored as colour (BMP, JPEG), or ``.npy``
        (:func:`~tofmetry.io.images.read_gray_image`); all of one size
    board : (cols, rows) inner corners; square_mm : square size [mm]
    advance : optional progress callable (one call per image, per leave-one-out refit, per fold)
    charuco : a ChArUco board instead of a checkerboard (``board`` and ``square_mm`` are then taken
        from it): views that see part of the board count (:func:`~tofmetry.calibrate.detect_charuco`,
        at least 6 corners after the neighbour check)
    accept_implausible : return a result that fails the plausibility gate
        (:func:`~tofmetry.pipelines.plausibility.check_intrinsics`: reprojection RMS above 1 px, a
        focal length far from the sensor profile's ...) instead of raising; ``run.plausibility`` says so

    Raises
    ------
    FormatError
        An unreadable image (the message names it); InputError for mixed sizes, no images.
    EstimationError
        Fewer than 3 images with a board.
    ImplausibleResultError
        The result fails the plausibility gate (unless ``accept_implausible``), or the fit converged
        to values no camera has (always: nothing could be written).
    """
    t0 = time.perf_counter()
    images_dir = Path(images_dir)
    if charuco is not None:
        board, square_mm = charuco.inner, charuco.square_mm
    cols, rows = (int(x) for x in board)
    if cols < 2 or rows < 2 or not square_mm > 0:
        raise InputError(f"board needs >= 2x2 inner corners and square_mm > 0; found {cols}x{rows}, {square_mm}")
    adv = _adv(advance)
    corners, names, rejected, size, detections, rejected_reasons = [], [], [], None, {}, {}
    objs = []
    for f in list_board_images(images_dir):
        img = read_gray_image(f)
        s = (img.shape[1], img.shape[0])
        if size is None:
            size = s
        elif s != size:
            raise InputError(f"{f}: size {s[0]}x{s[1]} differs from the first image's {size[0]}x{size[1]}")
        if charuco is not None:
            cd = detect_charuco(img, charuco)
            if cd is None:
                rejected.append(f.name)
                rejected_reasons[f.name] = "fewer than 6 ChArUco corners found"
            else:
                corners.append(cd.corners)
                objs.append(cd.object_points)
                names.append(f.name)
                std = cd.std_px[np.isfinite(cd.std_px)]
                detections[f.name] = {"detector": f"charuco-{cd.stretch}", "corners": len(cd.ids),
                                      "markers": cd.n_markers, "model_fraction": cd.fraction_model,
                                      "median_corner_std_px": float(np.median(std)) if std.size else float("nan"),
                                      "dropped_ids": cd.dropped, "dtype": str(img.dtype)}
            adv()
            continue
        det = detect_board(img, (cols, rows))
        if det is None:
            rejected.append(f.name)
            rejected_reasons[f.name] = "board not found"
        elif not det.usable:
            rejected.append(f.name)
            rejected_reasons[f.name] = (f"{det.n_suspect} corner(s) disagree with their grid neighbours (by up to "
                                        f"{max(det.refinement.grid_residual_px[det.refinement.suspect]):.2f} px)")
        else:
            corners.append(det.corners)
            names.append(f.name)
            ref = det.refinement
            std = ref.std_px[np.isfinite(ref.std_px)]
            detections[f.name] = {"detector": det.detector, "model_fraction": ref.fraction_model,
                                  "median_corner_std_px": float(np.median(std)) if std.size else float("nan"),
                                  "median_blur_px": float(np.nanmedian(ref.blur_px)) if ref.model_ok.any()
                                  else float("nan"), "dtype": str(img.dtype)}
        adv()
    obj_arg = objs if charuco is not None else None
    what = f"the intrinsic calibration of {images_dir} (board {cols}x{rows}, {square_mm:g} mm squares)"
    try:
        res = calibrate_intrinsics(corners, names, (cols, rows), square_mm, size, leave_one_out=leave_one_out,
                                   fix_k3=fix_k3, advance=adv, object_points=obj_arg)
    except DegenerateFitError as e:
        raise refuse_degenerate(e, what) from None
    gate = enforce(check_intrinsics(res.intrinsics, res.rms_px), what, accept_implausible)
    excl = [names.index(n) for n in res.rejected_views]
    cv = cross_validate_intrinsics(corners, (cols, rows), square_mm, size, k=k_folds, fix_k3=fix_k3, exclude=excl,
                                   object_points=obj_arg) if len(corners) - len(excl) >= 4 else {}
    return IntrinsicsRun(res, names, rejected, list(res.rejected_views), corners, size, (cols, rows), float(square_mm),
                         cv, str(images_dir), time.perf_counter() - t0, detections, rejected_reasons, gate,
                         objs, None if charuco is None else charuco.to_dict())


def write_intrinsics_report(run: IntrinsicsRun, folder: Path) -> list[Path]:
    """``intrinsics_report.json`` (result, predicted ray-error map on a 16 px grid, corner-region
    coverage), ``coverage.png`` (corner coverage, uncovered image corners, predicted ray error)
    and ``per_image.png`` (per-image RMS, rejection threshold, leave-one-out influence) in
    ``folder`` (created)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    res = run.result
    kept = [c for n, c in zip(run.names, run.corners) if n in set(res.used)]
    w, h = run.image_size
    out = [atomic_write_json(folder / "intrinsics_report.json", run.to_dict())]
    title = (f"Corner coverage: {len(kept)} images, {100 * res.coverage:.0f} % of the area, "
             f"{100 * res.cell_coverage:.0f} % of 8x8 cells")
    out.append(save_png(F.fig_coverage(kept, (h, w), title, corner_regions=res.corner_regions_coverage,
                                        predicted_ray=res.predicted_ray, uncovered=res.uncovered_corners,
                                        region_corners=res.corner_regions_corners), folder / "coverage.png"))
    out.append(save_png(F.fig_intrinsics_per_image(run), folder / "per_image.png"))
    return out
