"""Intrinsics pipeline: a folder of checkerboard images in, an :class:`IntrinsicsRun` out."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from tofmetry.calibrate import IntrinsicsResult, calibrate_intrinsics, cross_validate_intrinsics, detect_corners
from tofmetry.calibrate import figures as F
from tofmetry.io import atomic_write_json
from tofmetry.io.images import read_color_image, read_ir_image
from tofmetry.errors import InputError
from tofmetry.pipelines._common import IMAGE_SUFFIXES, _adv, _save_fig
from tofmetry.sensor import CameraIntrinsics


@dataclass(eq=False)
class IntrinsicsRun:
    """Checkerboard intrinsics from a folder of images.

    Attributes
    ----------
    result : IntrinsicsResult (kept views; ``result.rejected_views`` the outlier views)
    names : image names with a detected board (incl. outlier views), same order as ``corners``
    rejected : image names where no board was detected
    rejected_views : outlier views (RMS above ``max(1 px, 5 x median)``), left out of the fit
    corners : list of (cols*rows, 2) float64 [px], one per ``names``
    image_size : (width, height) [px]
    cv : k-fold pose-wise held-out reprojection RMS (see ``cross_validate_intrinsics``), names of the views
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

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self.result.intrinsics

    def to_dict(self) -> dict:
        cv = dict(self.cv)
        if "views" in cv:
            cv["views"] = [self.names[i] for i in cv["views"]]
        return {**self.result.to_dict(), "images_dir": self.images_dir, "board": list(self.board),
                "square_mm": self.square_mm, "image_size": list(self.image_size), "detected": self.names,
                "rejected": self.rejected, "cross_validation": cv, "seconds": self.seconds}


def _list_images(images_dir: Path) -> list[Path]:
    if not images_dir.is_dir():
        raise InputError(f"images folder not found: {images_dir}")
    files = sorted(p for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))
    if not files:
        raise InputError(f"{images_dir}: no images ({', '.join(IMAGE_SUFFIXES)})")
    return files


def intrinsics_from_images(images_dir: Path, board: tuple[int, int], square_mm: float, *, leave_one_out: bool = True,
                           fix_k3: bool = False, advance=None, k_folds: int = 5) -> IntrinsicsRun:
    """Detect the board in every image of ``images_dir``, calibrate, reject outlier views,
    analyse stability (leave-one-out) and cross-validate (k-fold over views, held-out views'
    pose solved with the fitted intrinsics).

    Parameters
    ----------
    images_dir : folder of 16-bit IR PNG/TIFF/NPY or 8-bit colour JPEG images
    board : (cols, rows) inner corners; square_mm : square size [mm]
    advance : optional progress callable (one call per image, per leave-one-out refit, per fold)
    """
    t0 = time.perf_counter()
    images_dir = Path(images_dir)
    cols, rows = (int(x) for x in board)
    if cols < 2 or rows < 2 or not square_mm > 0:
        raise InputError(f"board needs >= 2x2 inner corners and square_mm > 0; found {cols}x{rows}, {square_mm}")
    adv = _adv(advance)
    corners, names, rejected, size = [], [], [], None
    for f in _list_images(images_dir):
        img = read_color_image(f) if f.suffix.lower() in (".jpg", ".jpeg") else read_ir_image(f)
        s = (img.shape[1], img.shape[0])
        if size is None:
            size = s
        elif s != size:
            raise InputError(f"{f}: size {s[0]}x{s[1]} differs from the first image's {size[0]}x{size[1]}")
        c = detect_corners(img, (cols, rows))
        if c is None:
            rejected.append(f.name)
        else:
            corners.append(c)
            names.append(f.name)
        adv()
    res = calibrate_intrinsics(corners, names, (cols, rows), square_mm, size, leave_one_out=leave_one_out,
                               fix_k3=fix_k3, advance=adv)
    excl = [names.index(n) for n in res.rejected_views]
    cv = cross_validate_intrinsics(corners, (cols, rows), square_mm, size, k=k_folds, fix_k3=fix_k3, exclude=excl) \
        if len(corners) - len(excl) >= 4 else {}
    return IntrinsicsRun(res, names, rejected, list(res.rejected_views), corners, size, (cols, rows), float(square_mm),
                         cv, str(images_dir), time.perf_counter() - t0)


def write_intrinsics_report(run: IntrinsicsRun, folder: Path) -> list[Path]:
    """``intrinsics_report.json``, ``coverage.png`` and ``per_image.png`` (per-image RMS,
    rejection threshold, leave-one-out influence) in ``folder`` (created)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    res = run.result
    kept = [c for n, c in zip(run.names, run.corners) if n in set(res.used)]
    w, h = run.image_size
    out = [atomic_write_json(folder / "intrinsics_report.json", run.to_dict())]
    out.append(_save_fig(F.fig_coverage(kept, (h, w), f"Corner coverage: {len(kept)} images, {100 * res.coverage:.0f} % "
                                        f"of the area, {100 * res.cell_coverage:.0f} % of 8x8 cells"),
                         folder / "coverage.png"))
    out.append(_save_fig(F.fig_intrinsics_per_image(run), folder / "per_image.png"))
    return out

