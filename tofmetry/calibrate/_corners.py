"""Checkerboard corners in IR and grey images: find the grid, refine every corner, check it.

1. **Grid** (:func:`find_grid`): robust percentile stretch of the (dark, 16-bit) IR image to
   8 bit (:func:`normalize_ir`) -> ``cv2.findChessboardCornersSB`` (``NORMALIZE_IMAGE |
   EXHAUSTIVE | ACCURACY``), falling back to ``cv2.findChessboardCorners`` and to a gamma-0.5
   stretch. This step only *finds and orders* the corners (error about 0.1-0.3 px).
2. **Corners** (:func:`refine_corners`): the X-junction fit of :mod:`._corner_fit`; corners where
   it is not trustworthy fall back to ``cornerSubPix`` (window 0.5 x the cell height, no zero
   zone, 100 iterations / 1e-6 px). Every corner is then checked against a polynomial through its
   grid neighbours (:func:`grid_consistency_px`): the grid finder can misplace a corner by pixels
   (fitted again from the neighbours' prediction), and a junction that really is off the grid (a
   reflection) makes the view unusable (:attr:`CornerDetection.usable`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tofmetry.calibrate._board_pose import check_corners
from tofmetry.calibrate._corner_fit import CornerRefinement, _xjunction_fit
from tofmetry.errors import InputError


#: ``findChessboardCornersSB`` flags used to find the grid.
SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
#: Corner-fit disc radius as a fraction of the smallest local grid-cell height, and its bounds [px].
FIT_RADIUS_FRAC, FIT_RADIUS_MAX_PX, FIT_RADIUS_MIN_PX = 0.7, 15.0, 3.0


# ----------------------------------------------------------------------------- images
def normalize_ir(img: np.ndarray, lo_pct: float = 0.5, hi_pct: float = 99.5, gamma: float = 1.0) -> np.ndarray:
    """Robust percentile stretch of an IR/grey image to uint8 (the one IR normalisation).

    Parameters
    ----------
    img : (H, W) uint8/uint16/float or (H, W, 3) colour (converted to grey)
    lo_pct, hi_pct : percentiles mapped to 0 and 255 (computed over non-zero pixels)
    gamma : optional gamma (< 1 brightens dark IR)

    Returns
    -------
    (H, W) uint8
    """
    f = gray_float(img, "normalize_ir").astype(np.float64)
    nz = f[f > 0]
    if nz.size == 0:
        return np.zeros(f.shape, np.uint8)
    lo, hi = np.percentile(nz, [lo_pct, hi_pct])
    if hi <= lo:
        hi = lo + 1.0
    x = np.clip((f - lo) / (hi - lo), 0.0, 1.0)
    if gamma != 1.0:
        x = x ** gamma
    return np.round(x * 255.0).astype(np.uint8)


def gray_float(img: np.ndarray, what: str = "image") -> np.ndarray:
    """The image's own intensities as (H, W) float32 (colour converted to grey luminance).

    Parameters
    ----------
    img : (H, W) or (H, W, 1) any numeric dtype, or (H, W, 3) / (H, W, 4) colour (RGB order)
    what : name used in the error message

    Returns
    -------
    (H, W) float32, same scale as the input (no stretching).
    """
    a = np.asarray(img)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim == 3 and a.shape[2] in (3, 4):
        f = a[..., :3].astype(np.float32)
        if np.array_equal(f[..., 0], f[..., 1]) and np.array_equal(f[..., 0], f[..., 2]):
            return np.ascontiguousarray(f[..., 0])
        return (0.299 * f[..., 0] + 0.587 * f[..., 1] + 0.114 * f[..., 2]).astype(np.float32)
    if a.ndim != 2 or a.size == 0:
        raise InputError(f"{what}: expected an (H, W) grey or (H, W, 3) colour image, found shape {a.shape}")
    if not (np.issubdtype(a.dtype, np.number) or a.dtype == bool):
        raise InputError(f"{what}: expected a numeric image, found dtype {a.dtype}")
    f = a.astype(np.float32)
    if not np.all(np.isfinite(f)):
        f = np.nan_to_num(f, nan=0.0, posinf=0.0, neginf=0.0)
    return f


def _to_uint8(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    return a if (a.dtype == np.uint8 and a.ndim == 2) else normalize_ir(a)


# ----------------------------------------------------------------------------- grid
def find_grid(img: np.ndarray, board: tuple[int, int]) -> tuple[np.ndarray, str] | None:
    """Find and order the inner corners of a ``cols x rows`` checkerboard (pixel accuracy).

    ``findChessboardCornersSB`` (:data:`SB_FLAGS`) on the 8-bit image (uint8 grey used as is,
    anything else stretched with :func:`normalize_ir`), then ``findChessboardCorners``
    (adaptive threshold + normalisation), then both again on a gamma-0.5 stretch (very dark IR).

    Returns
    -------
    (corners, detector) with corners (cols*rows, 2) float64 [px] in OpenCV order and detector
    ``"sb"``, ``"classic"``, ``"sb-gamma"`` or ``"classic-gamma"``; None when not found.
    """
    cols, rows = int(board[0]), int(board[1])
    a = np.asarray(img)
    tries = [("", _to_uint8(a))]
    if not (a.dtype == np.uint8 and a.ndim == 2):
        tries.append(("-gamma", None))
    for suffix, img8 in tries:
        if img8 is None:
            img8 = normalize_ir(a, gamma=0.5)
        ok, c = cv2.findChessboardCornersSB(img8, (cols, rows), flags=SB_FLAGS)
        if ok and c is not None and len(c) == cols * rows:
            return np.asarray(c, np.float64).reshape(-1, 2), "sb" + suffix
        ok, c = cv2.findChessboardCorners(img8, (cols, rows),
                                          flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok and c is not None and len(c) == cols * rows:
            return np.asarray(c, np.float64).reshape(-1, 2), "classic" + suffix
    return None


def grid_geometry(corners: np.ndarray, board: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Local geometry of a detected grid.

    Parameters
    ----------
    corners : (cols*rows, 2) [px], OpenCV order
    board : (cols, rows)

    Returns
    -------
    dirs : (N, 2, 2) unit vectors along the grid's columns (``dirs[:, 0]``) and rows
        (``dirs[:, 1]``) at each corner (central differences).
    height : (N,) [px] smallest height of the (up to four) grid cells touching each corner:
        the distance from the corner to the nearest grid line that does not pass through it.
    """
    cols, rows = board
    g = np.asarray(corners, np.float64).reshape(rows, cols, 2)
    ex, ey = np.gradient(g, axis=1), np.gradient(g, axis=0)
    dirs = np.stack([ex / np.linalg.norm(ex, axis=2, keepdims=True),
                     ey / np.linalg.norm(ey, axis=2, keepdims=True)], axis=2).reshape(-1, 2, 2)
    nan = np.full((rows, 1, 2), np.nan)
    dx = np.diff(g, axis=1)
    a_f, a_b = np.concatenate([dx, nan], axis=1), np.concatenate([nan, dx], axis=1)
    nan = np.full((1, cols, 2), np.nan)
    dy = np.diff(g, axis=0)
    b_f, b_b = np.concatenate([dy, nan], axis=0), np.concatenate([nan, dy], axis=0)
    h = np.full((rows, cols), np.inf)
    for a in (a_f, a_b):
        for b in (b_f, b_b):
            cr = np.abs(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])
            la, lb = np.linalg.norm(a, axis=2), np.linalg.norm(b, axis=2)
            with np.errstate(invalid="ignore", divide="ignore"):
                hh = np.minimum(cr / la, cr / lb)
            h = np.where(np.isfinite(hh), np.minimum(h, hh), h)
    return dirs, h.ravel()


def refine_corners_subpix(img: np.ndarray, corners: np.ndarray, board: tuple[int, int],
                          window_frac: float = 0.5) -> np.ndarray:
    """``cv2.cornerSubPix`` set up as OpenCV intends: on the image's own intensities (float32),
    half-window ``window_frac`` x the local grid-cell height (2-15 px), no zero zone, stop after
    100 iterations or a move below 1e-6 px.

    Returns
    -------
    (N, 2) float64 [px]
    """
    f = gray_float(img, "refine_corners_subpix")
    c = np.asarray(corners, np.float64).reshape(-1, 2)
    _, h = grid_geometry(c, board)
    win = np.clip(np.round(window_frac * h), 2, 15).astype(int)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-6)
    out = c.copy()
    for w in np.unique(win):
        m = win == w
        r = cv2.cornerSubPix(f, c[m].astype(np.float32).reshape(-1, 1, 2), (int(w), int(w)), (-1, -1), crit)
        out[m] = r.reshape(-1, 2)
    return out


def grid_consistency_px(corners: np.ndarray, board: tuple[int, int], exclude: np.ndarray | None = None,
                        reach: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """How well each corner agrees with its neighbours on the board grid.

    Each corner is predicted from the corners within ``reach`` cells of it (itself and
    ``exclude`` left out) by a polynomial in the grid indices of total degree <= 3 (lower along
    an axis with fewer distinct indices), fitted by least squares. On exact projections of the
    family of Kinect-like lenses this prediction is within 0.13 px (p99 0.06 px) of the corner:
    a larger disagreement is a mis-located corner.

    Parameters
    ----------
    corners : (cols*rows, 2) [px]; board : (cols, rows); exclude : optional (N,) bool

    Returns
    -------
    residual : (N,) [px] distance corner - prediction (NaN where too few neighbours);
    predicted : (N, 2) [px]
    """
    cols, rows = int(board[0]), int(board[1])
    c = check_corners(corners, (cols, rows), "grid_consistency_px")
    n = len(c)
    return grid_consistency_ids(c, np.arange(n) % cols, np.arange(n) // cols, exclude, reach)


def grid_consistency_ids(corners: np.ndarray, gi: np.ndarray, gj: np.ndarray, exclude: np.ndarray | None = None,
                         reach: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """:func:`grid_consistency_px` for any subset of a board's corners (e.g. a partial ChArUco view).

    Parameters
    ----------
    corners : (N, 2) [px]; gi, gj : (N,) int grid column and row of each corner
    exclude : optional (N,) bool, corners not used to predict the others

    Returns
    -------
    residual : (N,) [px] (NaN where too few neighbours); predicted : (N, 2) [px]
    """
    c = np.asarray(corners, np.float64).reshape(-1, 2)
    n = len(c)
    gi, gj = np.asarray(gi, np.int64), np.asarray(gj, np.int64)
    ex = np.zeros(n, bool) if exclude is None else np.asarray(exclude, bool)
    pred = np.full((n, 2), np.nan)
    for k in range(n):
        dx, dy = gi - gi[k], gj - gj[k]
        m = (np.abs(dx) <= reach) & (np.abs(dy) <= reach) & ~ex
        m[k] = False
        x, y = dx[m].astype(float), dy[m].astype(float)
        px, py = min(3, len(np.unique(x)) - 1), min(3, len(np.unique(y)) - 1)
        terms = [(a, b) for a in range(px + 1) for b in range(py + 1) if a + b <= 3]
        if len(x) < len(terms) + 2:
            continue
        A = np.column_stack([x ** a * y ** b for a, b in terms])
        coef = np.linalg.lstsq(A, c[m], rcond=None)[0]
        pred[k] = coef[0]           # the (0, 0) term: the polynomial at the corner itself
    return np.linalg.norm(c - pred, axis=1), pred


#: A corner farther than this from its neighbours' prediction (and 8x the view's median) is suspect [px].
GRID_OUTLIER_PX = 0.5


def refine_corners(img: np.ndarray, corners: np.ndarray, board: tuple[int, int], *,
                   radius_frac: float = FIT_RADIUS_FRAC, max_radius_px: float = FIT_RADIUS_MAX_PX) -> CornerRefinement:
    """Sub-pixel corners by an X-junction model fit on the image's own intensities.

    Parameters
    ----------
    img : (H, W) IR/grey (any dtype) or (H, W, 3) colour; the fit uses its intensities
        unstretched (16-bit IR keeps its resolution)
    corners : (cols*rows, 2) [px], OpenCV order, within about 1 px (e.g. :func:`find_grid`)
    board : (cols, rows) inner corners
    radius_frac, max_radius_px : fit disc radius = ``radius_frac`` x the local cell height
        (:func:`grid_geometry`), clipped to [3 px, ``max_radius_px``]

    Returns
    -------
    CornerRefinement. A corner's fit is rejected (``cornerSubPix`` used instead, see
    :func:`refine_corners_subpix`) when it moved more than half the local cell height from the
    start (it would be nearer a neighbouring junction), when the blur is outside
    0.05 px - radius / 2, the two edges are within 15 deg of parallel, or the residual exceeds
    35 % of the contrast. Then every corner is checked against its grid neighbours
    (:func:`grid_consistency_px`); one off by more than ``max(GRID_OUTLIER_PX, 8 x the view's
    median)`` (the grid finder can misplace a corner by pixels) is fitted again from its
    neighbours' prediction, and marked ``suspect`` if it still disagrees.
    """
    cols, rows = int(board[0]), int(board[1])
    f = gray_float(img, "refine_corners")
    c0 = check_corners(corners, (cols, rows), "refine_corners")
    dirs, h = grid_geometry(c0, (cols, rows))
    h = np.where(np.isfinite(h), h, 2 * FIT_RADIUS_MIN_PX)
    radius = np.clip(radius_frac * h, FIT_RADIUS_MIN_PX, max(max_radius_px, FIT_RADIUS_MIN_PX))

    def fit(start, idx):
        q, blur, std, res_rel, dth, ok = _xjunction_fit(f, start[idx], dirs[idx], radius[idx])
        moved = np.linalg.norm(q - start[idx], axis=1)
        ok &= (moved < 0.5 * h[idx]) & (blur > 0.051) & (blur < 0.5 * radius[idx] - 1e-6)
        ok &= (dth > np.sin(np.deg2rad(15.0))) & (res_rel < 0.35)
        return q, blur, std, res_rel, ok

    idx = np.arange(len(c0))
    q, blur, std, res_rel, ok = fit(c0, idx)
    out = q.copy()
    if not ok.all():
        out[~ok] = refine_corners_subpix(f, c0, (cols, rows))[~ok]
    # grid consistency: re-fit the worst disagreeing corner from its neighbours' prediction, in turn
    suspect = np.zeros(len(c0), bool)
    tried = np.zeros(len(c0), bool)
    for _ in range(max(1, len(c0) // 4)):
        res, pred = grid_consistency_px(out, (cols, rows), exclude=suspect)
        fin = np.isfinite(res) & ~suspect
        if not fin.any():
            break
        k = int(np.flatnonzero(fin)[np.argmax(res[fin])])
        # the view's typical agreement, without the worst corner (it spoils its neighbours' predictions)
        wo = suspect.copy()
        wo[k] = True
        res_wo, _ = grid_consistency_px(out, (cols, rows), exclude=wo)
        typ = res_wo[np.isfinite(res_wo) & ~wo]
        thr = max(GRID_OUTLIER_PX, 8.0 * float(np.median(typ))) if typ.size else GRID_OUTLIER_PX
        if res[k] <= thr:
            break
        if tried[k]:
            suspect[k] = True
            continue
        tried[k] = True
        start = out.copy()
        start[k] = pred[k]
        q1, b1, s1, r1, ok1 = fit(start, np.array([k]))
        cand = q1[0] if ok1[0] else refine_corners_subpix(f, start, (cols, rows))[k]
        trial = out.copy()
        trial[k] = cand
        if np.linalg.norm(cand - pred[k]) <= thr:
            out, ok[k] = trial, bool(ok1[0])
            blur[k], std[k], res_rel[k] = b1[0], s1[0], r1[0]
        else:
            suspect[k] = True
    grid_res, _ = grid_consistency_px(out, (cols, rows))
    nan = np.full(len(c0), np.nan)
    return CornerRefinement(out, c0, ok, np.where(ok, blur, nan), np.where(ok, std, nan), res_rel, radius,
                            suspect, grid_res)


@dataclass(eq=False)
class CornerDetection:
    """Result of :func:`detect_board`.

    Attributes
    ----------
    corners : (N, 2) float64 [px]
    detector : which OpenCV grid finder succeeded (see :func:`find_grid`)
    refine : the refinement method
    refinement : CornerRefinement, None unless ``refine="model"``
    """

    corners: np.ndarray
    detector: str
    refine: str
    refinement: CornerRefinement | None = None

    @property
    def n_suspect(self) -> int:
        """Corners that disagree with their grid neighbours (0 unless ``refine="model"``)."""
        r = self.refinement
        return int(np.count_nonzero(r.suspect)) if r is not None and len(r.suspect) else 0

    @property
    def usable(self) -> bool:
        """True when no corner is suspect (the view can enter a calibration)."""
        return self.n_suspect == 0


REFINE_METHODS = ("model", "cornersubpix", "none")


def detect_board(img: np.ndarray, board: tuple[int, int], *, refine: str = "model") -> CornerDetection | None:
    """Find a ``cols x rows`` checkerboard and its sub-pixel inner corners.

    Parameters
    ----------
    img : (H, W) uint8 grey, (H, W) uint16/float IR, or (H, W, 3) colour (RGB)
    board : (cols, rows) inner corners
    refine : ``"model"`` (X-junction fit, :func:`refine_corners`, the default and the most
        accurate measured), ``"cornersubpix"`` (:func:`refine_corners_subpix`) or ``"none"``
        (the grid finder's own corners)

    Returns
    -------
    CornerDetection (check ``usable``: False when a corner disagrees with its grid neighbours),
    or None when no board was found.
    """
    if refine not in REFINE_METHODS:
        raise InputError(f"detect_board: refine must be one of {REFINE_METHODS}, found {refine!r}")
    cols, rows = int(board[0]), int(board[1])
    if cols < 2 or rows < 2:
        raise InputError(f"detect_board: board needs >= 2x2 inner corners, found {cols}x{rows}")
    found = find_grid(img, (cols, rows))
    if found is None:
        return None
    c, det = found
    if refine == "model":
        ref = refine_corners(img, c, (cols, rows))
        return CornerDetection(ref.corners, det, refine, ref)
    if refine == "cornersubpix":
        return CornerDetection(refine_corners_subpix(img, c, (cols, rows)), det, refine)
    return CornerDetection(c, det, refine)


def detect_corners(img: np.ndarray, board: tuple[int, int], *, refine: str = "model") -> np.ndarray | None:
    """Sub-pixel inner corners of a ``cols x rows`` checkerboard, or None (the one detector).

    :func:`detect_board` without the diagnostics.

    Parameters
    ----------
    img : (H, W) uint8 grey (used as is), (H, W) uint16/float IR (stretched with
        :func:`normalize_ir` for finding the grid, refined on its own intensities) or
        (H, W, 3) colour.
    board : (cols, rows) inner corners
    refine : see :func:`detect_board`

    Returns
    -------
    (cols*rows, 2) float64 [px] in OpenCV order, or None when not found or when a corner
    disagrees with its grid neighbours (``CornerDetection.usable``).
    """
    det = detect_board(img, board, refine=refine)
    return None if det is None or not det.usable else det.corners


# ----------------------------------------------------------------------------- board geometry
