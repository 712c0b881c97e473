"""Board-based depth calibration: a printed chessboard as the depth reference.

Method
------
1. **Grids.** Per view, the chessboard corners (given, or found in the IR image; every board
   of a view: :func:`find_boards` detects again with the found boards masked out). Each grid's
   pose is solved with the IR/depth intrinsics (``cv2.solvePnP``) and the grid is **rejected
   when its reprojection RMS exceeds a threshold derived from the measured corner noise**
   (:func:`corner_noise_px`, :func:`grid_threshold_px`): a grid spanning two boards or a
   reflection cannot be one plane.
2. **Reference.** Depth and IR share one lens and one pixel grid, so the board plane yields a
   reference Z for every board pixel: ``Z_ref = d / (n . r)``, ``r = (x, y, 1)`` the undistorted
   ray, ``n . X = d`` the plane (:func:`board_samples`). Square boundaries and the board's edge
   are kept out (mixed pixels), so are saturated IR pixels.
3. **The pattern.** ToF depth is biased by the returned amplitude: dark squares read longer,
   by an amount that depends on their amplitude (measured on the Kinect v2 recording: -3 mm at
   high amplitude up to +60 mm at low). The correction is for bright (white) surfaces; views
   whose white squares are saturated (near the camera) enter through their dark squares, with
   the dark-square bias **measured** on the views where both parities are valid, as a function
   of the dark pixels' amplitude (:class:`DarkBias`), clamped to the amplitudes where it was
   measured. Whether those views help is decided by the blocked validation. Held-out errors are
   always judged on white squares.
4. **Model family** (:mod:`tofmetry.calibrate._board_model`): ``a(x) + s(u, v) + zeta(x) g(u, v)``
   with ``x`` the radial path length (continuous-wave ToF) or Z; a ladder of candidates from a
   constant to a range spline with per-pixel surfaces (:func:`candidate_ladder`), gated by the
   support (few views: constant and constant + gain only).
5. **Blocked validation** (:func:`blocked_folds`): contiguous blocks of views in recording
   order, bins of range, regions of the image (a region left out of the fit and predicted).
   The model is **selected on the blocked folds** (simplest candidate within one standard
   error of the best, paired over folds); random k-fold over views is reported beside,
   labelled as such.
6. **Prediction** (:func:`predict_error`): RMS, P95 of |error| and mean error on new views with
   90 % intervals, from the held-out errors of the chosen model on the blocks in recording
   order (bootstrap over views). **Support** (:func:`support_counts`): samples per 16x16 px
   image cell and 100 mm range bin.

All functions are pure (arrays in, results out); file access is in :mod:`tofmetry.io`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.special import gammaincinv
from threadpoolctl import threadpool_limits

from tofmetry.calibrate._board_model import (
    RANGE_VARIABLES, BoardDepthModel, ModelSpec, fit_board_model, to_depth_calibration,
)
from tofmetry.calibrate._board_pose import board_object_points, check_corners, reprojection_rms_with, solve_board_pose
from tofmetry.calibrate._corners import detect_corners, normalize_ir
from tofmetry.calibrate._lens_fit import _folds, calibrate_intrinsics, cross_validate_intrinsics
from tofmetry.calibrate._model import DepthCalibration
from tofmetry.calibrate._support import CalibrationSupport
from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics

# intrinsics helpers live in tofmetry.calibrate and are re-exported here for convenience.
__all__ = [
    "BoardCalibrationResult", "BoardDepthModel", "BoardSamples", "DarkBias", "GridScreen", "ModelSpec",
    "blocked_folds", "board_object_points", "board_samples", "calibrate_depth_from_board", "calibrate_intrinsics",
    "candidate_ladder", "check_corners", "collect_grids", "constant_shift_calibration", "core_correction",
    "corner_noise_px", "cross_validate_intrinsics", "detect_corners", "error_stats", "evaluate_views", "find_boards",
    "fit_board_model", "fit_dark_bias", "grid_threshold_px", "normalize_ir", "outside_support", "predict_error",
    "region_folds", "reprojection_rms_with", "screen_grids", "solve_board_pose", "support_counts",
    "to_depth_calibration",
]

#: IR value of a saturated pixel (16-bit IR of the Kinect v2).
IR_SATURATION = 65535
#: Corner noise floor [px]: no detector is better (keeps thresholds sane on exact synthetic corners).
MIN_CORNER_NOISE_PX = 0.02
#: Allowance over the chi-square bound of the grid test for lens-model and detector errors that
#: vary over the image. Measured on the real Kinect v2 recording: the worst correct view reached
#: 4.6x the median view RMS (0.37 against 0.08 px); wrong grids were at 2.3 px (28x).
GRID_ALLOWANCE = 5.0


# ----------------------------------------------------------------------------- samples
@dataclass
class BoardSamples:
    """Board-pixel depth samples of one board in one view.

    Attributes
    ----------
    u, v : (N,) int pixel coordinates.
    measured_mm, reference_mm : (N,) float64 [mm] (Z).
    white, dark : (N,) bool, pixel on a white / dark square (away from square edges).
    amplitude : (N,) float64 IR amplitude of the pixel.
    pose_rms_px : reprojection RMS of the board pose [px].
    dark_minus_white_mm : median(measured - ref) on dark minus on white [mm] (NaN if one is missing).
    n_rejected : gross outliers removed (holes, flying pixels).
    n_saturated : white-square pixels lost to IR saturation or invalid depth.
    """

    u: np.ndarray
    v: np.ndarray
    measured_mm: np.ndarray
    reference_mm: np.ndarray
    white: np.ndarray
    dark: np.ndarray
    pose_rms_px: float
    dark_minus_white_mm: float
    n_rejected: int = 0
    n_saturated: int = 0
    amplitude: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.amplitude is None:
            self.amplitude = np.full(len(self.u), np.nan)

    def select(self, squares: str = "white") -> "BoardSamples":
        """Subset: ``"white"``, ``"dark"`` or ``"all"`` squares."""
        if squares not in ("white", "dark", "all"):
            raise InputError(f"squares must be 'white', 'dark' or 'all', found {squares!r}")
        m = self.white if squares == "white" else (self.dark if squares == "dark" else self.white | self.dark)
        return BoardSamples(self.u[m], self.v[m], self.measured_mm[m], self.reference_mm[m], self.white[m],
                            self.dark[m], self.pose_rms_px, self.dark_minus_white_mm, self.n_rejected,
                            self.n_saturated, self.amplitude[m])

    @staticmethod
    def concat(parts: list["BoardSamples"]) -> "BoardSamples":
        """Samples of several boards of one view as one set (pose RMS: the worst board's)."""
        if len(parts) == 1:
            return parts[0]
        cat = lambda a: np.concatenate([getattr(p, a) for p in parts])
        dmw = [p.dark_minus_white_mm for p in parts if np.isfinite(p.dark_minus_white_mm)]
        return BoardSamples(cat("u"), cat("v"), cat("measured_mm"), cat("reference_mm"), cat("white"), cat("dark"),
                            max(p.pose_rms_px for p in parts), float(np.median(dmw)) if dmw else float("nan"),
                            sum(p.n_rejected for p in parts), sum(p.n_saturated for p in parts), cat("amplitude"))


def board_samples(depth: np.ndarray, ir: np.ndarray, corners: np.ndarray, board: tuple[int, int], square_mm: float,
                  intr: CameraIntrinsics, edge_margin: float = 0.2, board_margin: float = 0.25,
                  max_abs_dev_mm: float = 100.0, saturation: float = IR_SATURATION) -> BoardSamples:
    """Reference depth from the board plane for every board pixel of one board.

    Parameters
    ----------
    depth : (H, W) uint16 [mm], Z; 0 = invalid.
    ir : (H, W) IR amplitude (decides which square parity is white; saturated pixels are dropped).
    corners : (cols*rows, 2) inner corners [px].
    board : (cols, rows) inner corners; square_mm : square size [mm].
    intr : IR/depth intrinsics.
    edge_margin : fraction of a square kept away from square boundaries (mixed pixels).
    board_margin : fraction of a square kept away from the outer edge of the outer squares.
    max_abs_dev_mm : gross-outlier gate on ``measured - reference`` around its median over the
        board (holes, flying pixels, another object in front) [mm].
    saturation : IR value of a saturated pixel.

    Returns
    -------
    BoardSamples

    Raises
    ------
    InputError : depth / IR / intrinsics sizes differ, or the corners do not match the board.
    EstimationError : fewer than 20 valid board pixels.
    """
    depth = np.asarray(depth)
    ir = np.asarray(ir)
    if depth.shape != intr.shape or ir.shape != intr.shape:
        raise InputError(f"board_samples: depth {depth.shape} / IR {ir.shape} do not match intrinsics {intr.shape}")
    R, t, rms = solve_board_pose(corners, board, square_mm, intr)
    n = R[:, 2]
    d = float(n @ t)
    rays = intr.ray_table()
    cols, rows = board
    s = float(square_mm)
    outline = np.array([[-s, -s, 0], [cols * s, -s, 0], [cols * s, rows * s, 0], [-s, rows * s, 0]], float)
    uv = intr.project(outline @ R.T + t)
    H, W = intr.shape
    u0, v0 = np.clip(np.floor(np.nanmin(uv, 0)).astype(int) - 2, 0, [W - 1, H - 1])
    u1, v1 = np.clip(np.ceil(np.nanmax(uv, 0)).astype(int) + 2, 0, [W - 1, H - 1])
    vv, uu = np.mgrid[v0:v1 + 1, u0:u1 + 1]
    r = rays[v0:v1 + 1, u0:u1 + 1]
    denom = n[0] * r[..., 0] + n[1] * r[..., 1] + n[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        zref = d / denom
    X = np.stack([r[..., 0] * zref, r[..., 1] * zref, zref], -1)
    pb = (X - t) @ R            # board coordinates [mm]
    bx, by = pb[..., 0] / s, pb[..., 1] / s   # in squares; inner corners at integers 0..cols-1
    inside = (bx > -1 + board_margin) & (bx < cols - board_margin) & (by > -1 + board_margin) & (by < rows - board_margin)
    fx, fy = bx - np.floor(bx), by - np.floor(by)
    away = (fx > edge_margin) & (fx < 1 - edge_margin) & (fy > edge_margin) & (fy < 1 - edge_margin)
    parity = (np.floor(np.nan_to_num(bx)).astype(int) + np.floor(np.nan_to_num(by)).astype(int)) & 1
    meas = depth[v0:v1 + 1, u0:u1 + 1].astype(np.float64)
    irs = ir[v0:v1 + 1, u0:u1 + 1].astype(np.float64)
    area = inside & away & (zref > 0)
    # which parity is white: brighter IR over the whole board area (valid depth or not: white
    # squares saturate and lose their depth at close range)
    m0, m1 = area & (parity == 0), area & (parity == 1)
    white_par = 0 if (np.median(irs[m0]) if m0.any() else 0) >= (np.median(irs[m1]) if m1.any() else 0) else 1
    ok = area & (meas > 0) & (irs < saturation)
    dev = meas - zref
    med = float(np.median(dev[ok])) if ok.any() else 0.0
    gross = ok & (np.abs(dev - med) > max_abs_dev_mm)
    keep = ok & ~gross
    if keep.sum() < 20:
        raise EstimationError(f"fewer than 20 valid board pixels in this view ({int(keep.sum())})")
    white = keep & (parity == white_par)
    dark = keep & (parity != white_par)
    n_sat = int(np.sum(area & (parity == white_par) & ~ok))
    dmw = float(np.median(dev[dark]) - np.median(dev[white])) if dark.sum() >= 10 and white.sum() >= 10 else float("nan")
    k = keep.ravel()
    return BoardSamples(uu.ravel()[k], vv.ravel()[k], meas.ravel()[k], zref.ravel()[k], white.ravel()[k],
                        dark.ravel()[k], rms, dmw, int(gross.sum()), n_sat, irs.ravel()[k])


# ----------------------------------------------------------------------------- grids
def _chi2_ppf(q: float, dof: int) -> float:
    """Quantile of the chi-square law (scipy.special, lighter than scipy.stats)."""
    return float(2.0 * gammaincinv(0.5 * dof, q))


def corner_noise_px(rms_px: np.ndarray, n_corners: int) -> float:
    """Corner noise sigma [px] (per axis) from per-grid PnP reprojection RMS values.

    Under isotropic Gaussian corner noise, ``RMS^2 * 2N / sigma^2`` follows a chi-square law with
    ``2N - 6`` degrees of freedom (6 pose parameters); the median grid gives
    ``sigma = median(RMS) sqrt(2N / chi2_median(2N - 6))`` (robust to a few wrong grids).
    Floored at :data:`MIN_CORNER_NOISE_PX`.
    """
    r = np.asarray(rms_px, float)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return float("nan")
    n2 = 2 * int(n_corners)
    dof = max(n2 - 6, 1)
    return max(MIN_CORNER_NOISE_PX, float(np.median(r) * np.sqrt(n2 / _chi2_ppf(0.5, dof))))


def grid_threshold_px(sigma_px: float, n_corners: int, p_false: float = 1e-3, allowance: float = GRID_ALLOWANCE) -> float:
    """Largest PnP reprojection RMS [px] of a correct grid: ``allowance x`` the RMS that corner
    noise ``sigma_px`` exceeds with probability ``p_false`` (chi-square, ``2N - 6`` dof)."""
    n2 = 2 * int(n_corners)
    return float(allowance * sigma_px * np.sqrt(_chi2_ppf(1 - p_false, max(n2 - 6, 1)) / n2))


@dataclass
class GridScreen:
    """Result of :func:`screen_grids`.

    Attributes
    ----------
    rms_px : (M,) PnP reprojection RMS of each grid [px] (inf where the pose failed).
    accepted : (M,) bool.
    sigma_px : corner noise used [px] (measured, or given).
    threshold_px : rejection threshold [px].
    """

    rms_px: np.ndarray
    accepted: np.ndarray
    sigma_px: float
    threshold_px: float


def screen_grids(grids: list[np.ndarray], board: tuple[int, int], square_mm: float, intr: CameraIntrinsics,
                 sigma_px: float | None = None, allowance: float = GRID_ALLOWANCE) -> GridScreen:
    """Accept or reject corner grids by their reprojection error with the board pose.

    Parameters
    ----------
    grids : list of (cols*rows, 2) corner arrays [px].
    sigma_px : corner noise [px]; None = measured from these grids (:func:`corner_noise_px`;
        with fewer than 3 grids the noise cannot be measured and 0.1 px is assumed, said in
        ``sigma_px``'s provenance by the caller).
    """
    n = board[0] * board[1]
    rms = np.full(len(grids), np.inf)
    for j, c in enumerate(grids):
        try:
            rms[j] = solve_board_pose(c, board, square_mm, intr)[2]
        except EstimationError:
            pass
    if sigma_px is None:
        fin = rms[np.isfinite(rms)]
        sigma_px = corner_noise_px(fin, n) if fin.size >= 3 else 0.1
    thr = grid_threshold_px(sigma_px, n, allowance=allowance)
    return GridScreen(rms, np.isfinite(rms) & (rms <= thr), float(sigma_px), thr)


def find_boards(ir: np.ndarray, board: tuple[int, int], max_boards: int = 4) -> list[np.ndarray]:
    """Every ``cols x rows`` board of an IR (or grey) image.

    The detector (:func:`detect_corners`) finds one board; its area (the grid extended by one
    square and a half on every side, through the board-to-image homography) is then filled with
    the image's median grey and the detector runs again, until it finds nothing.

    Returns
    -------
    list of (cols*rows, 2) float64 corner arrays [px] (possibly empty).
    """
    a = np.asarray(ir)
    img = (a if (a.dtype == np.uint8 and a.ndim == 2) else normalize_ir(a)).copy()
    cols, rows = board
    obj = board_object_points(board, 1.0)[:, :2]
    fill = int(np.median(img))
    out: list[np.ndarray] = []
    for _ in range(max_boards):
        c = detect_corners(img, board)
        if c is None:
            break
        out.append(c)
        Hm, _ = cv2.findHomography(obj, c)
        if Hm is None:
            break
        ext = np.array([[-1.5, -1.5], [cols + 0.5, -1.5], [cols + 0.5, rows + 0.5], [-1.5, rows + 0.5]], np.float64)
        poly = cv2.perspectiveTransform(ext[None], Hm)[0]
        cv2.fillConvexPoly(img, np.round(poly).astype(np.int32), fill)
    return out


# ----------------------------------------------------------------------------- evaluation helpers
def error_stats(err_mm: np.ndarray) -> dict:
    """n, mean, std, RMS and 95th percentile of |e| [mm] of an error sample."""
    e = np.asarray(err_mm, float)
    if e.size == 0:
        return {"n": 0, "mean_mm": float("nan"), "std_mm": float("nan"), "rms_mm": float("nan"), "p95_abs_mm": float("nan")}
    return {"n": int(e.size), "mean_mm": float(e.mean()), "std_mm": float(e.std()),
            "rms_mm": float(np.sqrt(np.mean(e ** 2))), "p95_abs_mm": float(np.percentile(np.abs(e), 95))}


def core_correction(cal, u: np.ndarray, v: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
    """Correction [mm] (to add to measured Z) of a core ``DepthCalibration`` at pixels (u, v):
    exactly what applying the calibration to a depth image does (its model's definition)."""
    return -cal.correction_at(u, v, z_mm)[0]


def constant_shift_calibration(shift_mm: float, intrinsics: CameraIntrinsics, sensor: str = "kinect_v2",
                               provenance: dict | None = None):
    """A core ``DepthCalibration`` equal to a constant shift (iai_kinect2 ``depthShift``):
    zero surfaces and a constant range curve ``R = -shift`` (corrected = measured + shift)."""
    s = float(shift_mm)
    return DepthCalibration(
        sensor=sensor, intrinsics=intrinsics, range_knots=np.array([1.0, 1.0, 65535.0, 65535.0]),
        range_coeffs=np.array([-s, -s]), range_degree=1, range_data_mm=np.array([1.0, 65535.0]),
        valid_range_mm=np.array([1.0, 65535.0]), node_mm=np.array([1000.0]),
        surfaces=np.zeros((1, *intrinsics.shape), np.float32), offset_mm=-s, surface_model="none",
        provenance={"method": "constant depth shift", **(provenance or {})},
    )


def support_counts(u: np.ndarray, v: np.ndarray, z_mm: np.ndarray, shape: tuple[int, int], cell_px: int = 16,
                   bin_mm: float = 100.0, z_edges_mm: np.ndarray | None = None) -> dict:
    """Samples per image cell and range bin: the support a fit saw.

    Parameters
    ----------
    u, v : (N,) pixel coordinates; z_mm : (N,) measured Z [mm].
    shape : (H, W); cell_px : cell size [px]; bin_mm : range bin [mm] (measured Z).
    z_edges_mm : explicit range-bin edges (default: multiples of ``bin_mm`` covering the data).

    Returns
    -------
    dict: ``counts`` (Gv, Gu, Nr) int64, ``u_edges`` (Gu+1,), ``v_edges`` (Gv+1,) [px],
    ``z_edges_mm`` (Nr+1,) [mm], ``cell_px``, ``bin_mm``.
    """
    H, W = shape
    u = np.asarray(u)
    v = np.asarray(v)
    z = np.asarray(z_mm, float)
    ue = np.arange(0, W + cell_px, cell_px, dtype=float)
    ve = np.arange(0, H + cell_px, cell_px, dtype=float)
    if z_edges_mm is None:
        if z.size:
            lo, hi = np.floor(z.min() / bin_mm) * bin_mm, (np.floor(z.max() / bin_mm) + 1) * bin_mm
        else:
            lo, hi = 0.0, bin_mm
        z_edges_mm = np.arange(lo, hi + 0.5 * bin_mm, bin_mm)
    ze = np.asarray(z_edges_mm, float)
    counts, _ = np.histogramdd(np.column_stack([v, u, z]) if z.size else np.zeros((0, 3)), bins=(ve, ue, ze))
    return {"counts": counts.astype(np.int64), "u_edges": ue, "v_edges": ve, "z_edges_mm": ze, "cell_px": cell_px,
            "bin_mm": bin_mm}


def outside_support(support: dict, u: np.ndarray, v: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
    """(N,) bool: samples whose (image cell, range bin) holds no training sample."""
    ue, ve, ze, cnt = support["u_edges"], support["v_edges"], support["z_edges_mm"], support["counts"]
    iu = np.clip(np.searchsorted(ue, u, side="right") - 1, 0, len(ue) - 2)
    iv = np.clip(np.searchsorted(ve, v, side="right") - 1, 0, len(ve) - 2)
    iz = np.searchsorted(ze, z_mm, side="right") - 1
    inside = (iz >= 0) & (iz < len(ze) - 1)
    out = np.ones(len(np.atleast_1d(u)), bool)
    out[inside] = cnt[iv[inside], iu[inside], iz[inside]] == 0
    return out


# ----------------------------------------------------------------------------- dark squares
@dataclass
class DarkBias:
    """Dark-square depth bias [mm] as a function of the dark pixel's IR amplitude (measured).

    ``b(A)`` is piecewise linear in ``ln A`` on ``knots`` (constant beyond them: never
    extrapolated), fitted to the per-view contrasts ``median(dev_dark) - median(dev_white)``
    against the views' median ``ln A_dark``, on views where both parities are valid.

    Attributes
    ----------
    ln_knots, values_mm : (K,) knots in ln(amplitude) and bias at the knots [mm] (K = 0: unknown).
    contrast_mm, ln_amplitude : (V,) the measured per-view contrasts and amplitudes.
    residual_mm : RMS of the per-view contrasts about the fitted curve [mm].
    """

    ln_knots: np.ndarray
    values_mm: np.ndarray
    contrast_mm: np.ndarray
    ln_amplitude: np.ndarray
    residual_mm: float

    def __call__(self, amplitude: np.ndarray) -> np.ndarray:
        a = np.log(np.maximum(np.asarray(amplitude, float), 1.0))
        if len(self.ln_knots) == 0:
            return np.full(a.shape, np.nan)
        if len(self.ln_knots) == 1:
            return np.full(a.shape, float(self.values_mm[0]))
        return np.interp(a, self.ln_knots, self.values_mm)

    @property
    def known(self) -> bool:
        return len(self.ln_knots) > 0

    def to_dict(self) -> dict:
        return {"amplitude_knots": np.exp(self.ln_knots).tolist(), "bias_mm": self.values_mm.tolist(),
                "views": len(self.contrast_mm), "residual_mm": self.residual_mm,
                "contrast_mm": self.contrast_mm.tolist(), "amplitude": np.exp(self.ln_amplitude).tolist()}


def fit_dark_bias(samples: list[BoardSamples], max_knots: int = 3) -> DarkBias:
    """:class:`DarkBias` from views holding at least 50 valid pixels of each parity."""
    c, la = [], []
    for s in samples:
        if s.white.sum() >= 50 and s.dark.sum() >= 50:
            dev = s.measured_mm - s.reference_mm
            c.append(float(np.median(dev[s.dark]) - np.median(dev[s.white])))
            la.append(float(np.median(np.log(np.maximum(s.amplitude[s.dark], 1.0)))))
    c, la = np.array(c), np.array(la)
    if c.size == 0:
        return DarkBias(np.zeros(0), np.zeros(0), c, la, float("nan"))
    K = int(min(max_knots, max(1, c.size // 4)))
    if K == 1 or np.ptp(la) < 1e-6:
        val = np.array([float(np.median(c))])
        return DarkBias(np.array([float(np.median(la))]), val, c, la, float(np.sqrt(np.mean((c - val[0]) ** 2))))
    knots = np.quantile(la, np.linspace(0, 1, K))
    knots = np.unique(knots)
    fz = np.clip(np.interp(la, knots, np.arange(len(knots))), 0, len(knots) - 1 - 1e-9)
    k0 = np.floor(fz).astype(int)
    a = fz - k0
    A = np.zeros((c.size, len(knots)))
    A[np.arange(c.size), k0] += 1 - a
    A[np.arange(c.size), k0 + 1] += a
    vals = np.linalg.lstsq(A, c, rcond=None)[0]
    res = float(np.sqrt(np.mean((A @ vals - c) ** 2)))
    return DarkBias(knots, vals, c, la, res)


# ----------------------------------------------------------------------------- validation designs
def blocked_folds(view_order: np.ndarray, view_z_mm: np.ndarray, design: str, k: int | None = None,
                  seed: int = 0) -> list[np.ndarray]:
    """Held-out view indices of each fold of a validation design.

    Parameters
    ----------
    view_order : (V,) recording order of the views (e.g. their index).
    view_z_mm : (V,) median measured Z of each view [mm].
    design : ``"time"`` (contiguous blocks in recording order, default 5), ``"range"`` (bins of
        range: contiguous groups of views sorted by Z, default 4) or ``"random"`` (random k-fold
        over views, default 5; reported beside the blocked designs, never used to select).
        Image regions are not view folds: see :func:`region_folds`.
    k : number of folds (clamped to [2, V]).

    Returns
    -------
    list of (n_f,) int arrays of view indices.
    """
    V = len(view_order)
    if V < 2:
        raise EstimationError(f"validation needs at least 2 views, found {V}")
    if design == "time":
        k = min(k or 5, V)
        return [np.sort(b) for b in np.array_split(np.argsort(view_order, kind="stable"), k)]
    if design == "range":
        k = min(k or 4, V)
        return [np.sort(b) for b in np.array_split(np.argsort(view_z_mm, kind="stable"), k)]
    if design == "random":
        return _folds(V, k or 5, seed)
    raise InputError(f"validation design must be 'time', 'range' or 'random', found {design!r}")


def region_folds(shape: tuple[int, int], grid: tuple[int, int] = (3, 2)) -> list[tuple[int, int, int, int]]:
    """Image regions ``(u0, u1, v0, v1)`` [px, half-open] of a ``(nu, nv)`` split of the image."""
    H, W = shape
    ue = np.linspace(0, W, grid[0] + 1).round().astype(int)
    ve = np.linspace(0, H, grid[1] + 1).round().astype(int)
    return [(ue[i], ue[i + 1], ve[j], ve[j + 1]) for j in range(grid[1]) for i in range(grid[0])]


def candidate_ladder(n_views: int, z_span_mm: float, knot_spacing_mm: float = 200.0,
                     range_variable: str | None = None) -> list[ModelSpec]:
    """Candidate models, simplest first (``complexity``), gated by the support.

    * always: no correction (the identity: every model must beat it) and a constant.
    * 2-5 views: constant; constant + gain in radial range and in Z (if the views span >= 100 mm).
    * >= 6 views: also range splines (knots every ``knot_spacing_mm``, if the span holds 2 of
      them), then range + per-pixel surface: a coarse grid (9x8 nodes) with membrane weights 3
      and 1, a fine grid (17x15) with weights 3 and 1, and the coarse surface plus a gain
      surface (a per-pixel term growing with range).

    ``range_variable`` restricts the surface candidates to one range variable (the selection
    first chooses it among the range-only candidates); None gives both.
    """
    c = [ModelSpec("no correction", "z", 0.0, complexity=-1, identity=True), ModelSpec("constant", "z", 0.0, complexity=0)]
    if n_views >= 2 and z_span_mm >= 100:
        c += [ModelSpec("gain (radial)", "radial", np.inf, complexity=1),
              ModelSpec("gain (Z)", "z", np.inf, complexity=1)]
    if n_views >= 6 and z_span_mm >= 2 * knot_spacing_mm:
        c += [ModelSpec("spline (radial)", "radial", knot_spacing_mm, complexity=2),
              ModelSpec("spline (Z)", "z", knot_spacing_mm, complexity=2)]
    if n_views >= 6:
        sp = knot_spacing_mm if z_span_mm >= 2 * knot_spacing_mm else (np.inf if z_span_mm >= 100 else 0.0)
        for rv in ((range_variable,) if range_variable else RANGE_VARIABLES):
            lab = "radial" if rv == "radial" else "Z"
            c += [ModelSpec(f"coarse surface, smooth 3 ({lab})", rv, sp, surface_smooth=3.0, grid=(9, 8), complexity=3),
                  ModelSpec(f"coarse surface, smooth 1 ({lab})", rv, sp, surface_smooth=1.0, grid=(9, 8), complexity=4),
                  ModelSpec(f"fine surface, smooth 3 ({lab})", rv, sp, surface_smooth=3.0, grid=(17, 15), complexity=5),
                  ModelSpec(f"fine surface, smooth 1 ({lab})", rv, sp, surface_smooth=1.0, grid=(17, 15), complexity=6),
                  ModelSpec(f"coarse surface + gain surface ({lab})", rv, sp, surface_smooth=3.0, gain_smooth=3.0,
                            grid=(9, 8), complexity=7)]
    return c


# ----------------------------------------------------------------------------- pooled samples
@dataclass
class _Pool:
    """All samples of the views used, concatenated (internal)."""

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray          # measured Z [mm] (dark-only views: minus the dark bias)
    zref: np.ndarray
    view: np.ndarray       # view index (0..V-1)
    judge: np.ndarray      # white-square sample (held-out errors are judged on these)
    dark_view: np.ndarray  # sample of a dark-only view

    def take(self, m: np.ndarray) -> "_Pool":
        return _Pool(*(getattr(self, f)[m] for f in ("u", "v", "z", "zref", "view", "judge", "dark_view")))


def _subsample(view: np.ndarray, max_per_view: int, seed: int) -> np.ndarray:
    """Indices keeping at most ``max_per_view`` samples per view (fixed seed)."""
    rng = np.random.default_rng(seed)
    keep = []
    for k in np.unique(view):
        idx = np.flatnonzero(view == k)
        keep.append(idx if len(idx) <= max_per_view else np.sort(rng.choice(idx, max_per_view, replace=False)))
    return np.concatenate(keep) if keep else np.zeros(0, int)


def _fit(pool: _Pool, spec: ModelSpec, shape, intr, use_dark: bool) -> BoardDepthModel:
    m = pool.judge | (pool.dark_view if use_dark else False)
    if spec.complexity <= 0:
        m = pool.judge if pool.judge.any() else m
    return fit_board_model(pool.u[m], pool.v[m], pool.z[m], pool.zref[m], shape, spec, intrinsics=intr)


def _held_out_errors(pool: _Pool, spec: ModelSpec, shape, intr, use_dark: bool, folds: list) -> list[tuple]:
    """Per fold (aligned with ``folds``): ``(label, view ids (n,), errors (n,))`` on the judged
    (white) samples of the fold, or None where the fold cannot be fitted or judged."""
    out = []
    for label, test in folds:
        tr = pool.take(~test)
        te = pool.take(test & pool.judge)
        if te.z.size == 0 or not tr.judge.any():
            out.append(None)
            continue
        try:
            model = _fit(tr, spec, shape, intr, use_dark)
        except EstimationError:
            out.append(None)
            continue
        e = te.z + model.correction(te.u, te.v, te.z) - te.zref
        out.append((label, te.view, e))
    return out


def _design_masks(pool: _Pool, folds_by_design: dict) -> dict:
    out = {}
    for d, folds in folds_by_design.items():
        masks = []
        for j, f in enumerate(folds):
            if d == "region":
                u0, u1, v0, v1 = f
                masks.append((f"region {j}", (pool.u >= u0) & (pool.u < u1) & (pool.v >= v0) & (pool.v < v1)))
            else:
                masks.append((f"{d} {j}", np.isin(pool.view, f)))
        out[d] = masks
    return out


def _fold_mse(results: list) -> np.ndarray:
    """(F,) held-out MSE per fold [mm^2] (NaN where the fold was not fitted)."""
    return np.array([float(np.mean(r[2] ** 2)) if r is not None else np.nan for r in results])


def _finite_mean(x) -> float:
    """Mean of the finite values (inf when there is none: a candidate no fold could judge)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.mean(x)) if x.size else float("inf")


def _done(results: list) -> list:
    return [r for r in results if r is not None]


def predict_error(view_ids: np.ndarray, errors: np.ndarray, n_new_views: int | None = None,
                  view_order: np.ndarray | None = None, block: int | None = None, n_boot: int = 1000,
                  level: float = 0.9, seed: int = 0, max_per_view: int = 100) -> dict:
    """Predicted error on a set of new views from held-out errors, with bootstrap intervals.

    Parameters
    ----------
    view_ids : (N,) view of each held-out error; errors : (N,) held-out errors [mm].
    n_new_views : size of the set of new views the prediction is for (default: as many as were
        held out). Each bootstrap draw assembles that many views and pools their pixels, so the
        interval covers the sampling of views (their pose errors) as well as of pixels.
    view_order : (V,) recording order of the distinct views (sorted ``unique(view_ids)``);
        given, views are drawn in **moving blocks** of ``block`` consecutive views (default
        ``round(sqrt(V))``), so that errors shared by views recorded together (a drift, a group
        of similar poses) widen the interval as they should; None: views drawn independently.
    level : central interval probability.

    Returns
    -------
    dict: ``rms_mm``, ``p95_abs_mm``, ``mean_mm`` (point estimates on all held-out errors), each
    with ``*_interval`` ``[lo, hi]``; ``n_views``, ``n_new_views``, ``block``, ``level``.
    """
    ids = np.asarray(view_ids)
    e = np.asarray(errors, float)
    views = np.unique(ids)
    V = len(views)
    nan2 = [float("nan"), float("nan")]
    if V == 0:
        return {"rms_mm": float("nan"), "p95_abs_mm": float("nan"), "mean_mm": float("nan"), "rms_mm_interval": nan2,
                "p95_abs_mm_interval": nan2, "mean_mm_interval": nan2, "n_views": 0, "n_new_views": 0, "block": 0,
                "level": level}
    rng = np.random.default_rng(seed)
    per = []
    for k in views:
        x = e[ids == k]
        per.append(x if len(x) <= max_per_view else rng.choice(x, max_per_view, replace=False))
    if view_order is not None:
        seq = np.argsort(np.asarray(view_order), kind="stable")
        L = int(block or max(1, round(np.sqrt(V))))
    else:
        seq = np.arange(V)
        L = 1
    L = min(L, V)
    m = int(n_new_views or V)
    stats = np.empty((n_boot, 3))
    for b in range(n_boot):
        pick = []
        while len(pick) < m:
            s0 = int(rng.integers(0, V - L + 1))
            pick.extend(seq[s0:s0 + L].tolist())
        x = np.concatenate([per[i] for i in pick[:m]])
        stats[b] = [np.sqrt(np.mean(x ** 2)), np.percentile(np.abs(x), 95), np.mean(x)]
    a = (1 - level) / 2
    lo, hi = np.quantile(stats, [a, 1 - a], axis=0)
    st = error_stats(e)
    return {"rms_mm": st["rms_mm"], "p95_abs_mm": st["p95_abs_mm"], "mean_mm": st["mean_mm"],
            "rms_mm_interval": [float(lo[0]), float(hi[0])], "p95_abs_mm_interval": [float(lo[1]), float(hi[1])],
            "mean_mm_interval": [float(lo[2]), float(hi[2])], "n_views": V, "n_new_views": m, "block": L,
            "level": level}


# ----------------------------------------------------------------------------- result
@dataclass
class BoardCalibrationResult:
    """Board-based depth calibration.

    Attributes
    ----------
    model : BoardDepthModel fitted on all usable views with the selected candidate.
    spec : the selected :class:`ModelSpec`; use_dark_views : whether views whose white squares
        are saturated entered the fit (through their dark squares and the measured dark bias).
    intrinsics, intrinsics_source : the IR/depth intrinsics used, and where they came from
        ("given", or "fitted on the board corners of N views").
    selection : list of dict per candidate: per design pooled held-out RMS [mm], score, paired
        difference to the best and its standard error; ``chosen`` marks the selected one.
    validation : {design: error stats of the chosen model on held-out folds}; designs "time",
        "range", "region" are blocked, "random" is labelled so and never used to select.
    cv : {"none", "constant_refit", "model"} -> error stats on the time-blocked folds (the
        former table of the CLI).
    cv_per_pose : {"none", "constant_refit", "model"} -> (V,) held-out RMS per view [mm] (time blocks).
    prediction : predicted error on new views (:func:`predict_error`, time-blocked folds).
    prediction_by_design : the same from each blocked design.
    support : :func:`support_counts` of the samples the final fit used.
    dark_bias : :class:`DarkBias`.
    views : list of dict per view (name, status, samples, RMS of its grids, ...).
    grid_screen : dict (corner noise, threshold, rejected grids).
    notes : list of str (what was decided and why).
    samples : {"u", "v", "z_mm"}: pixels and measured Z [mm] of the samples the final fit used.
    z_support_mm : (lo, hi) measured Z [mm] of the training samples (0.5-99.5 %); beyond it the
        correction is held (clamped), never extrapolated.
    held_out : {"view_ids", "errors", "view_order"}: the chosen model's held-out errors on the
        time blocks (for :meth:`predict`).
    grids : per input view, the list of accepted corner grids (cols*rows, 2) [px].
    """

    model: BoardDepthModel
    spec: ModelSpec
    use_dark_views: bool
    intrinsics: CameraIntrinsics
    intrinsics_source: str
    selection: list
    validation: dict
    cv: dict
    cv_per_pose: dict
    prediction: dict
    prediction_by_design: dict
    support: dict
    dark_bias: DarkBias
    views: list
    grid_screen: dict
    fit_residual: dict
    before: dict
    notes: list = field(default_factory=list)
    squares: str = "white"
    k_folds: int = 0
    constant_mm: float = float("nan")
    z_support_mm: tuple = (float("nan"), float("nan"))
    intrinsics_fit: dict | None = None
    samples: dict = field(default_factory=dict, repr=False)
    held_out: dict = field(default_factory=dict, repr=False)
    grids: list = field(default_factory=list, repr=False)

    def predict(self, n_new_views: int, seed: int = 0) -> dict:
        """Predicted error on a set of ``n_new_views`` new views (time-blocked held-out errors,
        moving-block bootstrap; :func:`predict_error`)."""
        h = self.held_out
        if not h:
            return predict_error(np.zeros(0), np.zeros(0))
        return predict_error(h["view_ids"], h["errors"], n_new_views, view_order=h["view_order"], seed=seed)

    @property
    def pose_index(self) -> list:
        """Indices (into the input views) of the views used."""
        return [r["index"] for r in self.views if r.get("used")]

    @property
    def skipped(self) -> list:
        return [(r["index"], r["reason"]) for r in self.views if r["status"] not in ("white", "dark-only")]

    @property
    def unused_dark_views(self) -> list:
        """Indices of the views with saturated white squares the selection left out."""
        return [r["index"] for r in self.views if r["status"] == "dark-only" and not r.get("used")]

    @property
    def dark_minus_white_mm(self) -> np.ndarray:
        return np.array([r["dark_minus_white_mm"] for r in self.views if r["index"] in set(self.pose_index)])

    @property
    def pose_rms_px(self) -> np.ndarray:
        return np.array([r["grid_rms_px"] for r in self.views if r["index"] in set(self.pose_index)])

    @property
    def n_samples(self) -> np.ndarray:
        return np.array([r["n_used"] for r in self.views if r["index"] in set(self.pose_index)])

    def depth_calibration(self, intrinsics: CameraIntrinsics | None = None, sensor: str = "kinect_v2",
                          provenance: dict | None = None):
        """The fitted model as a core ``DepthCalibration`` (save with
        ``tofmetry.io.calibration_file.save_calibration``); its diagnostics carry the summary,
        the prediction and the (sparse) support."""
        intr = intrinsics or self.intrinsics
        sup = self.support
        nz = np.argwhere(sup["counts"] > 0)
        by_n = {str(n): self.predict(n) for n in (1, 5, 10, 20, 50)} if self.held_out else {}
        diag = {"board": self.summary(), "predicted_error": self.prediction, "predicted_error_for_n_views": by_n,
                "support": {"cell_px": sup["cell_px"], "bin_mm": sup["bin_mm"], "u_edges": sup["u_edges"].tolist(),
                            "v_edges": sup["v_edges"].tolist(), "z_edges_mm": sup["z_edges_mm"].tolist(),
                            "index_vuz": nz.tolist(), "count": sup["counts"][tuple(nz.T)].tolist()}}
        support = CalibrationSupport.from_samples(self.samples["u"], self.samples["v"], self.samples["z_mm"], intr.shape) \
            if self.samples else None
        pred = {"method": "blocked validation over the board poses (contiguous blocks of poses in recording order, "
                          "bins of range, regions of the image); per-pose figures", "board": self.prediction,
                "board_for_n_views": by_n} if self.prediction else {}
        return to_depth_calibration(self.model, intr, sensor, provenance=provenance, diagnostics=diag, support=support,
                                    prediction=pred)

    def summary(self) -> dict:
        used = self.pose_index
        dmw = self.dark_minus_white_mm
        return {"model": self.spec.name, "model_description": self.model.describe(), "spec": self.spec.to_dict(),
                "use_dark_views": self.use_dark_views, "intrinsics_source": self.intrinsics_source,
                "squares": self.squares, "k_folds": self.k_folds,
                "cv_held_out": self.cv, "validation": self.validation, "prediction": self.prediction,
                "prediction_by_design": self.prediction_by_design, "selection": self.selection,
                "fit_residual": self.fit_residual, "before": self.before, "dark_bias": self.dark_bias.to_dict(),
                "grid_screen": self.grid_screen,
                "dark_minus_white_mm_median": (float(np.median(dmw[np.isfinite(dmw)])) if np.isfinite(dmw).any()
                                               else None),
                "pose_rms_px_median": float(np.median(self.pose_rms_px)) if len(used) else None,
                "n_poses": len(used), "n_samples": int(np.sum(self.n_samples)),
                "n_dark_only_views": sum(r["status"] == "dark-only" for r in self.views),
                "skipped_poses": self.skipped, "constant_mm": self.constant_mm,
                "z_support_mm": list(self.z_support_mm), "range_support_mm": list(self.model.x_support_mm),
                "range_variable": self.model.range_variable,
                "unsupported_surface_nodes": int(np.sum(self.model.support == 0)) if self.model.support.size else None,
                "support_samples": int(self.support["counts"].sum()), "notes": self.notes}


# ----------------------------------------------------------------------------- the calibration
def _as_grid_list(corners) -> list[np.ndarray] | None:
    if corners is None:
        return None
    if isinstance(corners, (list, tuple)):
        return [np.asarray(c, float) for c in corners]
    return [np.asarray(corners, float)]


def collect_grids(poses: list, board: tuple[int, int], max_boards: int = 4) -> tuple[list[list[np.ndarray]], list[str]]:
    """Corner grids per view: the given ones, else every board found in the IR (:func:`find_boards`)."""
    grids, source = [], []
    for depth, ir, corners in poses:
        g = _as_grid_list(corners)
        if g is None:
            grids.append(find_boards(ir, board, max_boards))
            source.append("detected")
        else:
            grids.append([check_corners(c, board, "corners") for c in g])
            source.append("given")
    return grids, source


def calibrate_depth_from_board(poses: list, board: tuple[int, int], square_mm: float,
                               intrinsics: CameraIntrinsics | None = None, *, names: list[str] | None = None,
                               seed: int = 0, sensor: str = "kinect_v2", min_samples: int = 200,
                               candidates: list[ModelSpec] | None = None, use_dark_views: bool | str = "auto",
                               max_boards: int = 4, max_samples_per_view: int = 600, k_folds: int = 5,
                               sample_kwargs: dict | None = None, advance=None) -> BoardCalibrationResult:
    """Board-based depth calibration with blocked validation and model selection.

    Parameters
    ----------
    poses : list of ``(depth (H,W) uint16 mm, ir (H,W), corners)`` in recording order; corners:
        (cols*rows, 2) [px], a list of such grids (several boards), or None (every board found
        in the IR image).
    board : (cols, rows) inner corners; square_mm : square size [mm].
    intrinsics : IR/depth intrinsics, **used as given**. None: fitted on the corners of these
        views (said in ``intrinsics_source``); needs at least 3 grids.
    names : view names (default ``view000`` ...).
    candidates : model ladder (default :func:`candidate_ladder`, gated by the support).
    use_dark_views : True / False / "auto" for views whose white squares are saturated: auto uses
        them unless, on the blocked folds, they make the held-out error worse by more than one
        standard error (paired over folds).
    min_samples : views with fewer usable pixels are skipped.
    max_samples_per_view : pixels per view used in the fits (random, fixed seed): views weigh
        about equally (a near board's thousands of pixels share one pose error), and the
        validation fits and the final fit follow the same procedure.
    k_folds : folds of the random and time-blocked designs.
    advance : optional progress callable.

    Returns
    -------
    BoardCalibrationResult

    Raises
    ------
    EstimationError : no usable view, or no intrinsics given and fewer than 3 grids to fit them.
    """
    # hundreds of small dense solves: one BLAS thread (threads thrash on a busy machine, 10-100x)
    with threadpool_limits(1, user_api="blas"):
        return _calibrate(poses, board, square_mm, intrinsics, names, seed, sensor, min_samples, candidates,
                          use_dark_views, max_boards, max_samples_per_view, k_folds, sample_kwargs, advance)


def _calibrate(poses, board, square_mm, intrinsics, names, seed, sensor, min_samples, candidates, use_dark_views,
               max_boards, max_samples_per_view, k_folds, sample_kwargs, advance) -> BoardCalibrationResult:
    """:func:`calibrate_depth_from_board` (its body)."""
    adv = advance or (lambda *a: None)
    sample_kwargs = sample_kwargs or {}
    V0 = len(poses)
    if V0 == 0:
        raise EstimationError("no board views given")
    names = list(names) if names is not None else [f"view{i:03d}" for i in range(V0)]
    if len(names) != V0:
        raise InputError(f"calibrate_depth_from_board: {len(names)} names for {V0} views")
    shape = np.asarray(poses[0][0]).shape
    notes: list[str] = []
    grids, gsource = collect_grids(poses, board, max_boards)
    # ---- intrinsics
    ifit = None
    if intrinsics is not None:
        intr, isrc = intrinsics, "given"
        if tuple(intr.shape) != tuple(shape):
            raise InputError(f"intrinsics {intr.width}x{intr.height} do not match the depth images {shape[1]}x{shape[0]}")
    else:
        flat = [(i, c) for i, g in enumerate(grids) for c in g]
        if len(flat) < 3:
            raise EstimationError(f"no intrinsics given and only {len(flat)} board grid(s) to fit them on (need >= 3): "
                                  "pass the device's intrinsics")
        ifit = calibrate_intrinsics([c for _, c in flat], [f"{names[i]}#{j}" for j, (i, _) in enumerate(flat)], board,
                                    square_mm, (shape[1], shape[0]), leave_one_out=False)
        intr = ifit.intrinsics
        isrc = (f"fitted on the board corners of {len(ifit.used)} grids (RMS {ifit.rms_px:.3f} px; "
                f"{len(ifit.rejected_views)} rejected)")
        notes.append(f"no intrinsics given: {isrc}")
    # ---- screen grids (a threshold from the measured corner noise), re-detect where the given grid fails
    allg = [c for g in grids for c in g]
    scr = screen_grids(allg, board, square_mm, intr)
    sigma = scr.sigma_px
    rows: list[dict] = []
    per_view: list[list[np.ndarray]] = []
    rejected = []
    pos = 0
    for i, g in enumerate(grids):
        acc = []
        rms_i = []
        for c in g:
            if scr.accepted[pos]:
                acc.append(c)
                rms_i.append(scr.rms_px[pos])
            else:
                rejected.append({"view": names[i], "rms_px": float(scr.rms_px[pos]), "source": gsource[i]})
            pos += 1
        if not acc and gsource[i] == "given":
            found = find_boards(poses[i][1], board, max_boards)
            if found:
                s2 = screen_grids(found, board, square_mm, intr, sigma_px=sigma)
                acc = [c for c, ok in zip(found, s2.accepted) if ok]
                rms_i = [r for r, ok in zip(s2.rms_px, s2.accepted) if ok]
                if acc:
                    notes.append(f"{names[i]}: the given corners were rejected; {len(acc)} board(s) detected in the IR "
                                 f"image used instead (RMS {max(rms_i):.2f} px)")
        per_view.append(acc)
        rows.append({"index": i, "name": names[i], "n_grids": len(acc), "grid_rms_px": float(max(rms_i)) if rms_i
                     else float("nan")})
    grid_info = {"corner_noise_px": sigma, "threshold_px": scr.threshold_px, "rejected": rejected,
                 "n_grids": len(allg), "n_accepted": int(sum(len(a) for a in per_view))}
    if rejected:
        notes.append(f"{len(rejected)} corner grid(s) rejected: reprojection RMS above {scr.threshold_px:.2f} px "
                     f"(corner noise {sigma:.3f} px): " + ", ".join(f"{r['view']} {r['rms_px']:.2f} px" for r in rejected))
    # ---- samples per view
    samples: list[BoardSamples | None] = []
    for i, acc in enumerate(per_view):
        r = rows[i]
        depth, ir, _ = poses[i]
        parts = []
        for c in acc:
            try:
                parts.append(board_samples(depth, ir, c, board, square_mm, intr, **sample_kwargs))
            except EstimationError as exc:
                r.setdefault("errors", []).append(str(exc))
        s = BoardSamples.concat(parts) if parts else None
        samples.append(s)
        if s is None:
            r.update(status="skipped", reason="no accepted board grid" if not acc else "; ".join(r.get("errors", [])),
                     n_white=0, n_dark=0, n_used=0, z_median_mm=float("nan"), dark_minus_white_mm=float("nan"))
            adv()
            continue
        nw, nd = int(s.white.sum()), int(s.dark.sum())
        r.update(n_white=nw, n_dark=nd, n_saturated=s.n_saturated, z_median_mm=float(np.median(s.measured_mm)),
                 dark_minus_white_mm=s.dark_minus_white_mm, dark_amplitude=float(np.median(s.amplitude[s.dark]))
                 if nd else float("nan"))
        if nw >= min_samples:
            r.update(status="white", reason="", n_used=nw)
        elif nd >= min_samples:
            r.update(status="dark-only", reason=f"white squares saturated ({s.n_saturated} px lost): dark squares used",
                     n_used=nd)
        else:
            r.update(status="skipped", reason=f"only {nw} white and {nd} dark usable pixels (< {min_samples})", n_used=0)
        adv()
    dark = fit_dark_bias([s for s, r in zip(samples, rows) if s is not None and r["status"] == "white"])
    n_white_views = sum(r["status"] == "white" for r in rows)
    if n_white_views == 0:
        reasons = "; ".join(f"{r['name']}: {r['reason']}" for r in rows)
        raise EstimationError(f"no view with usable white board squares ({reasons})")
    if any(r["status"] == "dark-only" for r in rows) and not dark.known:
        for r in rows:
            if r["status"] == "dark-only":
                r.update(status="skipped", reason="white squares saturated and the dark-square bias could not be "
                         "measured (no view with both parities)", n_used=0)
    # ---- pool
    used = [i for i, r in enumerate(rows) if r["status"] in ("white", "dark-only")]
    vidx = {i: j for j, i in enumerate(used)}
    parts = {k: [] for k in ("u", "v", "z", "zref", "view", "judge", "dark_view")}
    for i in used:
        s = samples[i]
        if rows[i]["status"] == "white":
            m = s.white
            z = s.measured_mm[m]
            judge = np.ones(m.sum(), bool)
        else:
            m = s.dark
            z = s.measured_mm[m] - dark(s.amplitude[m])
            judge = np.zeros(m.sum(), bool)
        parts["u"].append(s.u[m])
        parts["v"].append(s.v[m])
        parts["z"].append(z)
        parts["zref"].append(s.reference_mm[m])
        parts["view"].append(np.full(m.sum(), vidx[i]))
        parts["judge"].append(judge)
        parts["dark_view"].append(~judge)
    pool = _Pool(*(np.concatenate(parts[k]) for k in ("u", "v", "z", "zref", "view", "judge", "dark_view")))
    V = len(used)
    view_z = np.array([rows[i]["z_median_mm"] for i in used])
    white_views = np.array([rows[i]["status"] == "white" for i in used])
    has_dark_views = not white_views.all()
    z_span = float(np.ptp(view_z[white_views])) if white_views.sum() > 1 else 0.0
    # ---- candidates and validation designs
    sub = pool.take(_subsample(pool.view, max_samples_per_view, seed))
    designs: dict = {}
    nwv = int(white_views.sum())
    if nwv >= 2:
        order = np.array(used, float)
        designs["time"] = blocked_folds(order, view_z, "time", k=k_folds)
        if nwv >= 3:
            designs["range"] = blocked_folds(order, view_z, "range", k=min(4, nwv))
        designs["region"] = region_folds(shape)
    masks = _design_masks(sub, designs)
    force_dark = has_dark_views and use_dark_views is True
    selection: list[dict] = []
    results_by: dict = {}

    def evaluate(spec: ModelSpec, ud: bool) -> dict:
        res = {d: _held_out_errors(sub, spec, shape, intr, ud, masks[d]) for d in designs}
        results_by[(spec.name, ud)] = res
        row = {"name": spec.name, "use_dark_views": ud, "complexity": spec.complexity, "spec": spec}
        for d in designs:
            done = _done(res[d])
            e = np.concatenate([x for _, _, x in done]) if done else np.zeros(0)
            row[f"{d}_rms_mm"] = float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")
        row["score_mm"] = float(np.sqrt(_finite_mean([row[f"{d}_rms_mm"] ** 2 for d in designs])))
        row["_folds"] = np.concatenate([_fold_mse(res[d]) for d in designs])
        selection.append(row)
        adv()
        return row

    # "No correction" is not a simpler model of the same error but a claim that the sensor has
    # none: it is a candidate only when the views' mean errors do not show an offset (within two
    # standard errors of their mean; with few views one standard error of the held-out scores is
    # wide, and a ToF camera's constant offset is usually there)
    jv = pool.judge
    view_mean = np.array([np.mean((pool.zref - pool.z)[jv & (pool.view == k)]) for k in range(V)
                          if (jv & (pool.view == k)).any()])
    offset_shown = len(view_mean) >= 2 and abs(view_mean.mean()) > 2 * view_mean.std(ddof=1) / np.sqrt(len(view_mean))

    def one_se(rows: list[dict]) -> dict:
        """Simplest row whose mean held-out MSE over all blocked folds exceeds the best one's by
        at most one standard error of the paired fold differences ("no correction" only when the
        views show no offset, see above)."""
        best = min(rows, key=lambda r: _finite_mean(r["_folds"]))
        for r in rows:
            dv = r["_folds"] - best["_folds"]
            dv = dv[np.isfinite(dv)]
            r["paired_excess_mse"] = float(np.mean(dv)) if dv.size else 0.0
            r["paired_excess_se"] = float(np.std(dv, ddof=1) / np.sqrt(dv.size)) if dv.size > 1 else 0.0
        ok = [r for r in rows if r["paired_excess_mse"] <= r["paired_excess_se"]
              and not (r["spec"].identity and offset_shown)] or [best]
        return min(ok, key=lambda r: (r["complexity"], _finite_mean(r["_folds"])))

    if candidates is not None:
        ladder = list(candidates)
    else:
        ladder = candidate_ladder(nwv, z_span, range_variable="radial")
        ladder = [c for c in ladder if c.complexity <= 2]
    if designs:
        stage1 = [evaluate(c, force_dark) for c in ladder]
        if candidates is None and nwv >= 6:
            # the range variable of the best range-only candidate carries the surfaces
            rv = min((r for r in stage1 if r["complexity"] > 0), key=lambda r: r["score_mm"], default=None)
            rv = rv["spec"].range_variable if rv is not None else "radial"
            more = [c for c in candidate_ladder(nwv, z_span, range_variable=rv) if c.complexity >= 3]
            ladder += more
            stage1 += [evaluate(c, force_dark) for c in more]
        chosen = one_se(stage1)
        if has_dark_views and use_dark_views == "auto":
            with_dark = evaluate(chosen["spec"], True)
            dv = with_dark["_folds"] - chosen["_folds"]
            dv = dv[np.isfinite(dv)]
            with_dark["paired_excess_mse"] = float(np.mean(dv)) if dv.size else 0.0
            with_dark["paired_excess_se"] = float(np.std(dv, ddof=1) / np.sqrt(dv.size)) if dv.size > 1 else 0.0
            # all poses are used unless the blocked folds show that the dark-square views (and the
            # bias model they need) make the held-out error worse by more than one standard error
            if not dv.size or with_dark["paired_excess_mse"] <= with_dark["paired_excess_se"]:
                chosen = with_dark
    else:
        ladder = [ModelSpec("constant", "z", 0.0, complexity=0)]
        chosen = {"name": "constant", "use_dark_views": force_dark, "complexity": 0, "spec": ladder[0]}
        selection.append(chosen)
        notes.append("a single usable view: no validation possible, a constant is fitted")
    for row in selection:
        row["chosen"] = row is chosen
        row.pop("_folds", None)
    spec = chosen.pop("spec")
    for row in selection:
        row.pop("spec", None)
    use_dark = bool(chosen["use_dark_views"])
    for r in rows:
        r["used"] = r["status"] == "white" or (r["status"] == "dark-only" and use_dark)
    # ---- final fit: the validated procedure on all views (same per-view sample cap)
    model = _fit(sub, spec, shape, intr, use_dark)
    fitm = sub.judge | (sub.dark_view if use_dark else False)
    supp = support_counts(sub.u[fitm], sub.v[fitm], sub.z[fitm], shape)
    zfit = sub.z[fitm]
    z_support = (float(np.percentile(zfit, 0.5)), float(np.percentile(zfit, 99.5)))
    const = float(np.mean(pool.zref[pool.judge] - pool.z[pool.judge]))
    # ---- validation tables of the chosen model
    validation, pred_by, held_out = {}, {}, {}
    res = results_by.get((spec.name, use_dark), {})
    for d in designs:
        done = _done(res[d])
        if done:
            ids = np.concatenate([x for _, x, _ in done])
            e = np.concatenate([x for _, _, x in done])
            validation[d] = {**error_stats(e), "folds": len(done), "blocked": True}
            order = np.array(used)[np.unique(ids)] if d == "time" else None
            pred_by[d] = predict_error(ids, e, view_order=order, seed=seed)
            if d == "time":
                held_out = {"view_ids": ids, "errors": e, "view_order": order}
    cv, per_pose = {}, {}
    if "time" in designs:
        fm = masks["time"]
        base = {"none": [], "constant_refit": [], "model": []}
        per_pose = {c: np.full(V, np.nan) for c in base}
        for (label, test), r in zip(fm, res["time"]):
            if r is None:
                continue
            e = r[2]
            tr = sub.take(~test & sub.judge)
            cst = float(np.mean(tr.zref - tr.z)) if tr.z.size else 0.0
            te = sub.take(test & sub.judge)
            e0 = te.z - te.zref
            for c, ee in (("none", e0), ("constant_refit", e0 + cst), ("model", e)):
                base[c].append(ee)
                for k in np.unique(te.view):
                    per_pose[c][k] = float(np.sqrt(np.mean(ee[te.view == k] ** 2)))
        cv = {c: error_stats(np.concatenate(v)) if v else error_stats([]) for c, v in base.items()}
    if nwv >= 2:
        rf = [(f"random {j}", np.isin(sub.view, f)) for j, f in
              enumerate(blocked_folds(np.arange(V), view_z, "random", k=k_folds, seed=seed))]
        rr = _done(_held_out_errors(sub, spec, shape, intr, use_dark, rf))
        if rr:
            validation["random"] = {**error_stats(np.concatenate([x for _, _, x in rr])), "folds": len(rr),
                                    "blocked": False, "label": "random k-fold over views (not blocked)"}
    prediction = pred_by.get("time") or {}
    for i, r in enumerate(rows):
        if i in vidx and per_pose:
            r["held_out_rms_mm"] = {c: float(v[vidx[i]]) for c, v in per_pose.items()}
    # final notes
    if designs and spec.identity:
        notes.append(f"no correction: on the blocked folds no model beat the raw depth ({nwv} view(s) with white "
                     "squares); the calibration leaves depth unchanged")
    elif designs and spec.complexity <= 1:
        notes.append(f"the blocked validation supports only '{spec.name}' with {nwv} view(s) holding white squares")
    if has_dark_views:
        nd = int((~white_views).sum())
        notes.append(f"{nd} view(s) with saturated white squares: " + (
            "used through their dark squares (dark-square bias measured vs amplitude on "
            f"{len(dark.contrast_mm)} views, residual {dark.residual_mm:.1f} mm)" if use_dark else
            "left out of the fit (on the blocked folds they made the held-out error worse by more than one "
            "standard error)"))
    e_fit = pool.z[pool.judge] + model.correction(pool.u[pool.judge], pool.v[pool.judge], pool.z[pool.judge]) \
        - pool.zref[pool.judge]
    return BoardCalibrationResult(
        model=model, spec=spec, use_dark_views=use_dark, intrinsics=intr, intrinsics_source=isrc,
        selection=selection, validation=validation, cv=cv, cv_per_pose=per_pose, prediction=prediction,
        prediction_by_design=pred_by, support=supp, dark_bias=dark, views=rows, grid_screen=grid_info,
        fit_residual=error_stats(e_fit), before=error_stats(pool.z[pool.judge] - pool.zref[pool.judge]), notes=notes,
        squares="white" + (" + dark (saturated views)" if use_dark else ""), k_folds=len(designs.get("time", [])),
        constant_mm=const, z_support_mm=z_support, intrinsics_fit=ifit.to_dict() if ifit is not None else None,
        samples={"u": sub.u[fitm], "v": sub.v[fitm], "z_mm": sub.z[fitm]}, held_out=held_out, grids=per_view,
    )


# ----------------------------------------------------------------------------- judging
def evaluate_views(poses: list, board: tuple[int, int], square_mm: float, intr: CameraIntrinsics,
                   corrections: dict, *, names: list[str] | None = None, sigma_px: float | None = None,
                   support: dict | None = None, model: BoardDepthModel | None = None,
                   valid_range_mm: tuple[float, float] | None = None, sample_kwargs: dict | None = None) -> dict:
    """Error of corrected depth against the board plane on views no fit has seen (white squares).

    Parameters
    ----------
    poses : list of ``(depth, ir, corners)`` (corners as in :func:`calibrate_depth_from_board`).
    intr : intrinsics giving the board planes (each case is judged against the planes of the
        intrinsics it comes with).
    corrections : {case name: callable ``(u, v, z_mm) -> correction [mm]`` or None (= none)}.
    sigma_px : corner noise for the grid test (default: measured on these views).
    support : :func:`support_counts` of a fit: judged samples outside it are counted
        (``outside["cell_and_range_bin"]``: no training sample in the same 16 px cell and 100 mm
        bin; ``outside["image_cell"]``: none in the same cell at any range).
    model : the fitted model: samples whose range variable lies outside its training range
        (where ``a`` is clamped) are counted in ``outside["range"]``.
    valid_range_mm : a DepthCalibration's valid range: samples outside it are left uncorrected
        by the calibration, counted in ``outside["uncorrected"]``.

    Returns
    -------
    dict: ``cases`` {name: error stats}, ``per_view`` list of dict (name, n, mean and RMS per
    case), ``outside`` {kind: count}, ``n_samples``, ``n_views``, ``skipped`` [(name, reason)],
    ``errors`` {name: (N,)} and ``view_ids`` (N,) (for predictions / figures).
    """
    sample_kwargs = sample_kwargs or {}
    names = list(names) if names is not None else [f"view{i:03d}" for i in range(len(poses))]
    grids, _ = collect_grids(poses, board)
    allg = [c for g in grids for c in g]
    scr = screen_grids(allg, board, square_mm, intr, sigma_px=sigma_px) if allg else None
    errs = {c: [] for c in corrections}
    ids, per_view, skipped = [], [], []
    outside = {"cell_and_range_bin": 0, "image_cell": 0, "range": 0, "uncorrected": 0}
    pos = 0
    for i, g in enumerate(grids):
        parts = []
        for c in g:
            ok = bool(scr.accepted[pos])
            pos += 1
            if not ok:
                continue
            try:
                parts.append(board_samples(poses[i][0], poses[i][1], c, board, square_mm, intr, **sample_kwargs))
            except EstimationError:
                pass
        s = BoardSamples.concat(parts).select("white") if parts else None
        if s is None or len(s.u) < 20:
            skipped.append((names[i], "no accepted board grid" if not parts else "white squares saturated"))
            continue
        row = {"name": names[i], "n": len(s.u), "z_median_mm": float(np.median(s.measured_mm))}
        e0 = s.measured_mm - s.reference_mm
        for cname, f in corrections.items():
            e = e0 if f is None else e0 + f(s.u, s.v, s.measured_mm)
            errs[cname].append(e)
            row[f"mean_{cname}_mm"] = float(np.mean(e))
            row[f"rms_{cname}_mm"] = float(np.sqrt(np.mean(e ** 2)))
        if support is not None:
            n_out = int(outside_support(support, s.u, s.v, s.measured_mm).sum())
            cells = support["counts"].sum(axis=2)
            iu = np.clip(np.searchsorted(support["u_edges"], s.u, side="right") - 1, 0, cells.shape[1] - 1)
            iv = np.clip(np.searchsorted(support["v_edges"], s.v, side="right") - 1, 0, cells.shape[0] - 1)
            row["n_outside_support"] = n_out
            outside["cell_and_range_bin"] += n_out
            outside["image_cell"] += int(np.sum(cells[iv, iu] == 0))
        if model is not None:
            x = model.range_value(s.u, s.v, s.measured_mm)
            lo, hi = model.x_support_mm
            outside["range"] += int(np.sum((x < lo) | (x > hi)))
        if valid_range_mm is not None:
            outside["uncorrected"] += int(np.sum((s.measured_mm < valid_range_mm[0]) | (s.measured_mm > valid_range_mm[1])))
        ids.append(np.full(len(s.u), i))
        per_view.append(row)
    cat = {c: np.concatenate(v) if v else np.zeros(0) for c, v in errs.items()}
    return {"cases": {c: error_stats(v) for c, v in cat.items()}, "per_view": per_view, "outside": outside,
            "n_samples": int(sum(r["n"] for r in per_view)), "n_views": len(per_view),
            "skipped": skipped, "errors": cat, "view_ids": np.concatenate(ids) if ids else np.zeros(0, int)}
