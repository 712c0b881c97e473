"""Board samples and board finding: reference depth from the board plane for every board pixel
(:class:`BoardSamples`, :func:`board_samples`), every board of an IR image (:func:`find_boards`,
:func:`collect_grids`) and the grid test from the measured corner noise (:func:`corner_noise_px`,
:func:`grid_threshold_px`, :func:`screen_grids`). Part of :mod:`tofmetry.calibrate.board`.

A board is a checkerboard ``(cols, rows)`` or a :class:`~tofmetry.calibrate._charuco.CharucoBoard`
(partial views: a grid holds NaN for the corners not seen, :mod:`._board_pose`; which of its pixels
are white and dark: :mod:`._board_charuco`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import gammaincinv

from tofmetry.calibrate._board_charuco import CHARUCO_EDGE_MARGIN_PX, charuco_square_masks
from tofmetry.calibrate._board_pose import board_object_points, check_corners, is_charuco, solve_board_pose
from tofmetry.calibrate._charuco import detect_charuco
from tofmetry.calibrate._corners import detect_corners, normalize_ir
from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics

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


def board_samples(depth: np.ndarray, ir: np.ndarray, corners: np.ndarray, board, square_mm: float,
                  intr: CameraIntrinsics, edge_margin: float = 0.2, board_margin: float = 0.25,
                  max_abs_dev_mm: float = 100.0, saturation: float = IR_SATURATION,
                  edge_margin_px: float = CHARUCO_EDGE_MARGIN_PX) -> BoardSamples:
    """Reference depth from the board plane for every board pixel of one board.

    Parameters
    ----------
    depth : (H, W) uint16 [mm], Z; 0 = invalid.
    ir : (H, W) IR amplitude (checkerboard: decides which square parity is white; saturated
        pixels are dropped).
    corners : (cols*rows, 2) inner corners [px] (ChArUco: by corner id, NaN where not seen).
    board : (cols, rows) inner corners of a checkerboard, or a ChArUco board; square_mm : square
        size [mm].
    intr : IR/depth intrinsics.
    edge_margin : checkerboard: fraction of a square kept away from square boundaries (mixed pixels).
    board_margin : checkerboard: fraction of a square kept away from the outer edge of the outer squares.
    edge_margin_px : ChArUco: distance [px] kept from every black/white edge (squares, markers, the
        board's outline); only the squares touching a detected corner are used
        (:func:`~tofmetry.calibrate._board_charuco.charuco_square_masks`).
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
    charuco = is_charuco(board)
    if charuco:
        s, (sx, sy) = float(board.square_mm), (board.squares_x, board.squares_y)
        outline = np.array([[0, 0, 0], [sx * s, 0, 0], [sx * s, sy * s, 0], [0, sy * s, 0]], float)
    else:
        cols, rows = board
        s = float(square_mm)
        outline = np.array([[-s, -s, 0], [cols * s, -s, 0], [cols * s, rows * s, 0], [-s, rows * s, 0]], float)
    p_out = outline @ R.T + t
    H, W = intr.shape
    if charuco and not np.all(p_out[:, 2] > 0):
        u0, v0, u1, v1 = 0, 0, W - 1, H - 1          # the board plane reaches behind the camera: whole image
    else:
        uv = intr.project(p_out)
        u0, v0 = np.clip(np.floor(np.nanmin(uv, 0)).astype(int) - 2, 0, [W - 1, H - 1])
        u1, v1 = np.clip(np.ceil(np.nanmax(uv, 0)).astype(int) + 2, 0, [W - 1, H - 1])
    vv, uu = np.mgrid[v0:v1 + 1, u0:u1 + 1]
    r = rays[v0:v1 + 1, u0:u1 + 1]
    denom = n[0] * r[..., 0] + n[1] * r[..., 1] + n[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        zref = d / denom
    X = np.stack([r[..., 0] * zref, r[..., 1] * zref, zref], -1)
    pb = (X - t) @ R            # board coordinates [mm]
    meas = depth[v0:v1 + 1, u0:u1 + 1].astype(np.float64)
    irs = ir[v0:v1 + 1, u0:u1 + 1].astype(np.float64)
    if charuco:
        seen = np.isfinite(check_corners(corners, board, "board_samples")).all(axis=1)
        with np.errstate(invalid="ignore"):
            wm, dm = charuco_square_masks(pb[..., 0], pb[..., 1], board, seen, edge_margin_px)
        wm &= zref > 0
        dm &= zref > 0
    else:
        bx, by = pb[..., 0] / s, pb[..., 1] / s   # in squares; inner corners at integers 0..cols-1
        inside = (bx > -1 + board_margin) & (bx < cols - board_margin) & (by > -1 + board_margin) & (by < rows - board_margin)
        fx, fy = bx - np.floor(bx), by - np.floor(by)
        away = (fx > edge_margin) & (fx < 1 - edge_margin) & (fy > edge_margin) & (fy < 1 - edge_margin)
        parity = (np.floor(np.nan_to_num(bx)).astype(int) + np.floor(np.nan_to_num(by)).astype(int)) & 1
        area = inside & away & (zref > 0)
        # which parity is white: brighter IR over the whole board area (valid depth or not: white
        # squares saturate and lose their depth at close range)
        m0, m1 = area & (parity == 0), area & (parity == 1)
        white_par = 0 if (np.median(irs[m0]) if m0.any() else 0) >= (np.median(irs[m1]) if m1.any() else 0) else 1
        wm, dm = area & (parity == white_par), area & (parity != white_par)
    area = wm | dm
    ok = area & (meas > 0) & (irs < saturation)
    dev = meas - zref
    med = float(np.median(dev[ok])) if ok.any() else 0.0
    gross = ok & (np.abs(dev - med) > max_abs_dev_mm)
    keep = ok & ~gross
    if keep.sum() < 20:
        raise EstimationError(f"fewer than 20 valid board pixels in this view ({int(keep.sum())})")
    white = keep & wm
    dark = keep & dm
    n_sat = int(np.sum(wm & ~ok))
    dmw = float(np.median(dev[dark]) - np.median(dev[white])) if dark.sum() >= 10 and white.sum() >= 10 else float("nan")
    k = keep.ravel()
    return BoardSamples(uu.ravel()[k], vv.ravel()[k], meas.ravel()[k], zref.ravel()[k], white.ravel()[k],
                        dark.ravel()[k], rms, dmw, int(gross.sum()), n_sat, irs.ravel()[k])


# ----------------------------------------------------------------------------- grids
def _chi2_ppf(q: float, dof: int) -> float:
    """Quantile of the chi-square law (scipy.special, lighter than scipy.stats)."""
    return float(2.0 * gammaincinv(0.5 * dof, q))


def corner_noise_px(rms_px: np.ndarray, n_corners) -> float:
    """Corner noise sigma [px] (per axis) from per-grid PnP reprojection RMS values.

    Under isotropic Gaussian corner noise, ``RMS^2 * 2N / sigma^2`` follows a chi-square law with
    ``2N - 6`` degrees of freedom (6 pose parameters); the median grid gives
    ``sigma = median(RMS) sqrt(2N / chi2_median(2N - 6))`` (robust to a few wrong grids).
    ``n_corners`` is one count for all grids, or (M,) counts (partial ChArUco views): then each
    grid's RMS is turned into a sigma so, and their median is taken.
    Floored at :data:`MIN_CORNER_NOISE_PX`.
    """
    r = np.asarray(rms_px, float)
    n_arr = np.asarray(n_corners)
    if n_arr.ndim:
        fin = np.isfinite(r)
        if not fin.any():
            return float("nan")
        n2 = 2 * n_arr[fin].astype(int)
        sig = [x * np.sqrt(k / _chi2_ppf(0.5, max(k - 6, 1))) for x, k in zip(r[fin], n2)]
        return max(MIN_CORNER_NOISE_PX, float(np.median(sig)))
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
    threshold_px : rejection threshold [px] (partial ChArUco views: of a grid with the median
        number of corners).
    thresholds_px : (M,) each grid's threshold [px] (it depends on the grid's number of corners).
    """

    rms_px: np.ndarray
    accepted: np.ndarray
    sigma_px: float
    threshold_px: float
    thresholds_px: np.ndarray | None = None


def screen_grids(grids: list[np.ndarray], board, square_mm: float, intr: CameraIntrinsics,
                 sigma_px: float | None = None, allowance: float = GRID_ALLOWANCE) -> GridScreen:
    """Accept or reject corner grids by their reprojection error with the board pose.

    Parameters
    ----------
    grids : list of (cols*rows, 2) corner arrays [px] (ChArUco: NaN where a corner was not seen).
    board : (cols, rows) inner corners, or a ChArUco board.
    sigma_px : corner noise [px]; None = measured from these grids (:func:`corner_noise_px`;
        with fewer than 3 grids the noise cannot be measured and 0.1 px is assumed, said in
        ``sigma_px``'s provenance by the caller).
    """
    if is_charuco(board):
        ns = np.array([int(np.isfinite(np.asarray(c, float).reshape(-1, 2)).all(axis=1).sum()) for c in grids], int)
    else:
        ns = np.full(len(grids), board[0] * board[1], int)
    rms = np.full(len(grids), np.inf)
    for j, c in enumerate(grids):
        try:
            rms[j] = solve_board_pose(c, board, square_mm, intr)[2]
        except EstimationError:
            pass
    if sigma_px is None:
        fin = np.isfinite(rms)
        if fin.sum() >= 3:
            sigma_px = corner_noise_px(rms[fin], ns[fin] if is_charuco(board) else int(ns[0]))
        else:
            sigma_px = 0.1
    thr = np.array([grid_threshold_px(sigma_px, k, allowance=allowance) for k in ns])
    n_typ = int(np.median(ns)) if len(ns) else (board.n_corners if is_charuco(board) else board[0] * board[1])
    return GridScreen(rms, np.isfinite(rms) & (rms <= thr), float(sigma_px),
                      grid_threshold_px(sigma_px, n_typ, allowance=allowance), thr)


def find_boards(ir: np.ndarray, board, max_boards: int = 4) -> list[np.ndarray]:
    """Every ``cols x rows`` board of an IR (or grey) image.

    The detector (:func:`detect_corners`) finds one board; its area (the grid extended by one
    square and a half on every side, through the board-to-image homography) is then filled with
    the image's median grey and the detector runs again, until it finds nothing. A ChArUco board
    (its corners identified by its markers: one per image) is found by
    :func:`~tofmetry.calibrate._charuco.detect_charuco`, partial views included.

    Returns
    -------
    list of (cols*rows, 2) float64 corner arrays [px] (possibly empty; ChArUco: by corner id, NaN
    where a corner was not found).
    """
    if is_charuco(board):
        det = detect_charuco(ir, board)
        if det is None:
            return []
        g = np.full((board.n_corners, 2), np.nan)
        g[det.ids] = det.corners
        return [g]
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


def _as_grid_list(corners) -> list[np.ndarray] | None:
    if corners is None:
        return None
    if isinstance(corners, (list, tuple)):
        return [np.asarray(c, float) for c in corners]
    return [np.asarray(corners, float)]


def collect_grids(poses: list, board, max_boards: int = 4) -> tuple[list[list[np.ndarray]], list[str]]:
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
