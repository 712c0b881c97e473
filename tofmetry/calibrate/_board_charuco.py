"""Where a ChArUco board is white and where it is dark, for the board depth calibration.

The board plane gives a reference depth for every pixel on it (:func:`._board_samples.board_samples`);
which of those pixels may be used is decided here from the board's design, in board coordinates
(OpenCV's frame: origin at the outer top-left corner of the squares, x along the columns, y down
the rows, millimetres):

* **dark**: the black squares (the squares without a marker), **white**: the white margin of the
  white squares around their marker. The markers themselves (black border, black and white bits
  of a module of ``marker / 6``) are never used.
* **Away from every edge** between black and white (square boundaries, the markers' outline, the
  board's outer edge): by ``margin_px`` pixels in the image, measured in the worst direction
  through the local board-to-image scale, so that no pixel mixes the two reflectances (a pixel's
  half width plus three standard deviations of the lens blur: 0.5 + 3 x 0.29 px on the Kinect v2).
* **The detected area**: the squares touching a detected corner. A partial view's pose comes from
  the corners it saw, so the plane is used where it was measured, not extrapolated over squares
  whose corners were not found (outside the image, or hidden by something in front of the board;
  a square touching a found corner is used even if part of it is hidden: the gross-outlier gate
  of :func:`._board_samples.board_samples` is what removes such pixels). A view that sees the
  whole board uses all of it.

The white margin is ``(square - marker) / 2`` wide (12 mm on the default 80 / 56 mm board: 4.4 px
at 1 m on the Kinect v2), so far views keep few white pixels: they enter the depth calibration
through their dark squares, with the dark-square bias measured on the nearer views, as views
with saturated white squares do (:mod:`tofmetry.calibrate.board`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from tofmetry.calibrate._charuco import CharucoBoard, _black_squares

#: Distance [px] of a used pixel's centre from the nearest black/white edge of the board: half a
#: pixel plus three standard deviations of the Kinect v2's IR lens blur (0.29 px).
CHARUCO_EDGE_MARGIN_PX = 1.5


@lru_cache(maxsize=8)
def _black(board: CharucoBoard) -> np.ndarray:
    out = _black_squares(board)
    out.setflags(write=False)
    return out


def _max_singular(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Largest singular value of the 2 x 2 matrices ``[[a, b], [c, d]]`` (element-wise arrays)."""
    s = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return np.sqrt(0.5 * (s + np.sqrt(np.maximum(s * s - 4.0 * det * det, 0.0))))


def charuco_square_masks(bx_mm: np.ndarray, by_mm: np.ndarray, board: CharucoBoard, seen: np.ndarray,
                         margin_px: float = CHARUCO_EDGE_MARGIN_PX) -> tuple[np.ndarray, np.ndarray]:
    """White and dark pixels of a ChArUco board for depth sampling (see the module docstring).

    Parameters
    ----------
    bx_mm, by_mm : (h, w) float, board coordinates [mm] of the centres of a block of consecutive
        image pixels (rows along v, columns along u; NaN where the ray misses the plane)
    board : the ChArUco board
    seen : (n_corners,) bool, the corners detected in this view (by corner id)
    margin_px : least distance [px] of a used pixel's centre from a black/white edge

    Returns
    -------
    white, dark : (h, w) bool
    """
    bx = np.asarray(bx_mm, np.float64)
    by = np.asarray(by_mm, np.float64)
    s, m = float(board.square_mm), float(board.marker_mm)
    sx, sy = int(board.squares_x), int(board.squares_y)
    cols, rows = board.inner
    fin = np.isfinite(bx) & np.isfinite(by)
    on = fin & (bx >= 0) & (bx < sx * s) & (by >= 0) & (by < sy * s)
    i = np.clip(np.floor(np.where(on, bx, 0.0) / s).astype(int), 0, sx - 1)
    j = np.clip(np.floor(np.where(on, by, 0.0) / s).astype(int), 0, sy - 1)
    # the squares touching a detected corner (corner id k sits at grid point (k % cols + 1, k // cols + 1))
    g = np.zeros((sy + 1, sx + 1), bool)
    g[1:sy, 1:sx] = np.asarray(seen, bool).reshape(rows, cols)
    cell = g[:-1, :-1] | g[:-1, 1:] | g[1:, :-1] | g[1:, 1:]
    black = _black(board)[j, i]
    fx, fy = bx - i * s, by - j * s
    d_sq = np.minimum(np.minimum(fx, s - fx), np.minimum(fy, s - fy))
    mx = np.maximum(np.abs(fx - 0.5 * s) - 0.5 * m, 0.0)
    my = np.maximum(np.abs(fy - 0.5 * s) - 0.5 * m, 0.0)
    d_mk = np.hypot(mx, my)                                  # 0 on the marker
    d_mm = np.where(black, d_sq, np.minimum(d_sq, d_mk))
    # board millimetres per image pixel in the worst direction (the image-to-board Jacobian)
    with np.errstate(invalid="ignore"):
        gxv, gxu = np.gradient(bx) if min(bx.shape) > 1 else (np.full_like(bx, np.nan),) * 2
        gyv, gyu = np.gradient(by) if min(by.shape) > 1 else (np.full_like(by, np.nan),) * 2
        mm_per_px = _max_singular(gxu, gxv, gyu, gyv)
        ok = on & cell[j, i] & np.isfinite(mm_per_px) & (d_mm >= margin_px * mm_per_px)
    return ok & ~black & (d_mk > 0), ok & black
