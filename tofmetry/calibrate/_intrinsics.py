"""Geometric (IR) intrinsics from checkerboard images, with uncertainty and stability analysis.

Pipeline: robust percentile stretch of the (dark, 16-bit) IR image to 8 bit ->
``cv2.findChessboardCornersSB`` (sub-pixel, falls back to ``findChessboardCorners`` +
``cornerSubPix``) -> ``cv2.calibrateCameraExtended`` (Brown model fx, fy, cx, cy, k1, k2, p1,
p2, k3, with standard deviations and per-view RMS) -> leave-one-out refits: the spread of each
parameter over the folds, and the images whose removal moves a parameter by more than its
standard uncertainty (``influence > 1``) -> corner coverage of the image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor import CameraIntrinsics

PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def normalize_ir(img: np.ndarray, lo_pct: float = 0.5, hi_pct: float = 99.5, gamma: float = 1.0) -> np.ndarray:
    """Robust percentile stretch of an IR/grey image to uint8.

    Parameters
    ----------
    img : (H, W) uint16/float or (H, W, 3) colour (converted to grey)
    lo_pct, hi_pct : percentiles mapped to 0 and 255 (computed over non-zero pixels)
    gamma : optional gamma (< 1 brightens dark IR)

    Returns
    -------
    (H, W) uint8
    """
    a = np.asarray(img)
    if a.ndim == 3:
        a = cv2.cvtColor(a.astype(np.uint8) if a.dtype != np.uint8 else a, cv2.COLOR_RGB2GRAY)
    if a.ndim != 2:
        raise InputError(f"normalize_ir: expected an (H, W) image, found shape {a.shape}")
    f = a.astype(np.float64)
    nz = f[f > 0]
    if nz.size == 0:
        return np.zeros(a.shape, np.uint8)
    lo, hi = np.percentile(nz, [lo_pct, hi_pct])
    if hi <= lo:
        hi = lo + 1.0
    x = np.clip((f - lo) / (hi - lo), 0.0, 1.0)
    if gamma != 1.0:
        x = x ** gamma
    return np.round(x * 255.0).astype(np.uint8)


def detect_corners(img8: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel inner corners of a ``cols x rows`` checkerboard, or None.

    Returns
    -------
    (cols*rows, 2) float32 [px] in OpenCV order, or None when not found.
    """
    cols, rows = board
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    ok, c = cv2.findChessboardCornersSB(img8, (cols, rows), flags=flags)
    if not ok or c is None:
        ok, c = cv2.findChessboardCorners(img8, (cols, rows),
                                          flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not ok:
            return None
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
        c = cv2.cornerSubPix(img8, c, (5, 5), (-1, -1), crit)
    return np.asarray(c, np.float32).reshape(-1, 2)


def board_object_points(board: tuple[int, int], square_mm: float) -> np.ndarray:
    """(cols*rows, 3) float32 board points [mm], ``(i s, j s, 0)``, OpenCV corner order."""
    cols, rows = board
    g = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(np.float32)
    return np.column_stack([g * float(square_mm), np.zeros(len(g), np.float32)]).astype(np.float32)


@dataclass(eq=False)
class IntrinsicsResult:
    """Result of :func:`calibrate_intrinsics`.

    Attributes
    ----------
    intrinsics : CameraIntrinsics
    rms_px : float, overall reprojection RMS
    std : dict param -> standard uncertainty (OpenCV stdDeviationsIntrinsics)
    per_image_rms_px : dict image name -> reprojection RMS
    loo : dict param -> std of the leave-one-out estimates (how much it varies)
    loo_range : dict param -> max - min over the leave-one-out folds
    influence : dict image -> max over params of |change on removal| / std
    flagged : list of images whose removal changes a parameter beyond its uncertainty
    coverage : float, fraction of the image area inside the boards' corner hulls
    cell_coverage : float, fraction of 8x8 image cells holding a detected corner
    warnings : list of str
    used : list of image names used
    """

    intrinsics: CameraIntrinsics
    rms_px: float
    std: dict
    per_image_rms_px: dict
    loo: dict = field(default_factory=dict)
    loo_range: dict = field(default_factory=dict)
    influence: dict = field(default_factory=dict)
    flagged: list = field(default_factory=list)
    coverage: float = float("nan")
    cell_coverage: float = float("nan")
    warnings: list = field(default_factory=list)
    used: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "intrinsics": self.intrinsics.to_dict(), "rms_px": self.rms_px, "std": self.std,
            "per_image_rms_px": self.per_image_rms_px, "leave_one_out_std": self.loo,
            "leave_one_out_range": self.loo_range, "influence": self.influence, "flagged": self.flagged,
            "coverage": self.coverage, "cell_coverage": self.cell_coverage, "warnings": self.warnings, "images_used": self.used,
        }


def _calib(obj, img, size, flags):
    K0 = np.eye(3)
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    out = cv2.calibrateCameraExtended(obj, img, size, K0, np.zeros(5), flags=flags, criteria=crit)
    rms, K, dist, _r, _t, std_i, _std_e, per_view = out
    d = np.asarray(dist, float).ravel()
    d = np.concatenate([d, np.zeros(max(0, 5 - len(d)))])[:5]
    vals = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d])
    return float(rms), vals, np.asarray(std_i, float).ravel()[:9], np.asarray(per_view, float).ravel()


def corner_coverage(corners: list[np.ndarray], shape: tuple[int, int], cells: int = 8) -> float:
    """Fraction of a ``cells x cells`` grid over the image holding at least one corner."""
    h, w = shape
    occ = np.zeros((cells, cells), bool)
    for c in corners:
        c = np.asarray(c).reshape(-1, 2)
        iu = np.clip((c[:, 0] * cells / w).astype(int), 0, cells - 1)
        iv = np.clip((c[:, 1] * cells / h).astype(int), 0, cells - 1)
        occ[iv, iu] = True
    return float(occ.mean())


def calibrate_intrinsics(corners: list[np.ndarray], names: list[str], board: tuple[int, int], square_mm: float,
                         image_size: tuple[int, int], leave_one_out: bool = True, fix_k3: bool = False,
                         min_coverage: float = 0.5, advance=None) -> IntrinsicsResult:
    """Brown-model calibration from detected checkerboard corners.

    Parameters
    ----------
    corners : list of (cols*rows, 2) float [px], one per image where detection succeeded
    names : image names (same length)
    board : (cols, rows) inner corners
    square_mm : square size [mm]
    image_size : (width, height) [px]
    leave_one_out : refit without each image in turn (stability analysis)
    fix_k3 : keep k3 = 0 (advisable when coverage is poor)
    min_coverage : below this fraction of the image area covered by the boards (union of
        the corner hulls) a warning is issued

    Raises
    ------
    EstimationError
        Fewer than 3 usable images.
    """
    if len(corners) != len(names):
        raise InputError(f"calibrate_intrinsics: {len(corners)} corner sets for {len(names)} names")
    if len(corners) < 3:
        raise EstimationError(f"intrinsic calibration needs at least 3 images with a detected board, found {len(corners)}")
    obj = board_object_points(board, square_mm)
    n = obj.shape[0]
    for nm, c in zip(names, corners):
        if np.asarray(c).reshape(-1, 2).shape[0] != n:
            raise InputError(f"{nm}: {np.asarray(c).size // 2} corners, expected {n} for a {board[0]}x{board[1]} board")
    O = [obj] * len(corners)
    I = [np.asarray(c, np.float32).reshape(-1, 1, 2) for c in corners]
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rms, vals, std, per_view = _calib(O, I, tuple(image_size), flags)
    w, h = image_size
    intr = CameraIntrinsics(w, h, vals[0], vals[1], vals[2], vals[3], tuple(vals[4:]))
    res = IntrinsicsResult(
        intrinsics=intr, rms_px=rms, std=dict(zip(PARAMS, std.tolist())),
        per_image_rms_px=dict(zip(names, per_view.tolist())), used=list(names),
    )
    res.cell_coverage = corner_coverage(corners, (h, w))
    res.coverage = float(coverage_mask(corners, (h, w)).mean())
    if res.coverage < min_coverage:
        res.warnings.append(
            f"the boards cover only {100 * res.coverage:.0f} % of the image area ({100 * res.cell_coverage:.0f} % of "
            "8x8 cells): distortion and focal length are poorly constrained where there are no corners; add "
            "images with larger or closer boards reaching the image borders and corners"
        )
    if leave_one_out and len(corners) >= 4:
        folds = []
        for j in range(len(corners)):
            _, v, _, _ = _calib(O[:j] + O[j + 1:], I[:j] + I[j + 1:], tuple(image_size), flags)
            folds.append(v)
            if advance is not None:
                advance()
        folds = np.array(folds)
        res.loo = dict(zip(PARAMS, folds.std(axis=0, ddof=1).tolist()))
        res.loo_range = dict(zip(PARAMS, (folds.max(axis=0) - folds.min(axis=0)).tolist()))
        safe = np.where(std > 0, std, np.inf)
        for j, nm in enumerate(names):
            ratio = np.abs(folds[j] - vals) / safe
            res.influence[nm] = float(np.max(ratio))
            if res.influence[nm] > 1.0:
                worst = PARAMS[int(np.argmax(ratio))]
                res.flagged.append(nm)
                res.warnings.append(
                    f"{nm}: removing it moves {worst} by {ratio.max():.1f} standard uncertainties"
                )
    return res


def ray_difference_px(a: CameraIntrinsics, b: CameraIntrinsics, mask: np.ndarray | None = None) -> np.ndarray:
    """Back-projection difference between two models, expressed in pixels.

    For every pixel, the ray of model ``a`` is reprojected with model ``b``'s focal lengths
    (undistorted normalised coordinates times (fx, fy) of ``b``): (H, W) float64 [px] distance
    between the two models' rays, NaN outside ``mask``.
    """
    ra, rb = a.ray_table(), b.ray_table()
    d = np.hypot((ra[..., 0] - rb[..., 0]) * b.fx, (ra[..., 1] - rb[..., 1]) * b.fy)
    if mask is not None:
        d = np.where(mask, d, np.nan)
    return d


def coverage_mask(corners: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: union of the convex hulls of each image's detected corners (the covered area)."""
    h, w = shape
    m = np.zeros((h, w), np.uint8)
    for c in corners:
        hull = cv2.convexHull(np.asarray(c, np.float32).reshape(-1, 1, 2))
        cv2.fillConvexPoly(m, np.round(hull).astype(np.int32), 1)
    return m.astype(bool)
