"""Board geometry: object points, corner checks and the board pose from its corners.

A board is a checkerboard, given as ``(cols, rows)`` inner corners (every corner seen: a corner
grid is ``(cols*rows, 2)`` pixels), or a :class:`~tofmetry.calibrate._charuco.CharucoBoard`, whose
views may see part of it: its corner grid is ``(n_corners, 2)`` pixels in corner-id order, NaN
where the corner was not detected (at least :data:`MIN_CHARUCO_CORNERS` seen).
"""

from __future__ import annotations


import cv2
import numpy as np

from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor import CameraIntrinsics

#: Fewest detected corners of a ChArUco view (as :func:`~tofmetry.calibrate._charuco.detect_charuco`).
MIN_CHARUCO_CORNERS = 6


def is_charuco(board) -> bool:
    """Whether ``board`` is a :class:`~tofmetry.calibrate._charuco.CharucoBoard` (not a ``(cols, rows)``
    checkerboard); by its attributes (``_charuco`` imports ``_corners``, which imports this module)."""
    return hasattr(board, "squares_x") and hasattr(board, "object_points")


def board_inner(board) -> tuple[int, int]:
    """(cols, rows) inner corners of a checkerboard ``(cols, rows)`` or a :class:`~tofmetry.calibrate._charuco.CharucoBoard`."""
    return board.inner if is_charuco(board) else (int(board[0]), int(board[1]))


def board_object_points(board, square_mm: float) -> np.ndarray:
    """(cols*rows, 3) float64 inner-corner coordinates [mm]: ``(i s, j s, 0)``, OpenCV corner
    order (i fastest, along the columns); a :class:`~tofmetry.calibrate._charuco.CharucoBoard`'s own (origin at the outer corner
    of its squares, ``square_mm`` taken from the board)."""
    if is_charuco(board):
        return board.object_points()
    cols, rows = board
    gx, gy = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.column_stack([gx.ravel() * float(square_mm), gy.ravel() * float(square_mm),
                            np.zeros(cols * rows)]).astype(np.float64)


def check_corners(corners: np.ndarray, board, what: str) -> np.ndarray:
    """(cols*rows, 2) float64 corners, or InputError naming ``what``. ChArUco: NaN rows are corners
    not seen; at least :data:`MIN_CHARUCO_CORNERS` must be finite."""
    c = np.asarray(corners, dtype=np.float64)
    if c.ndim == 3 and c.shape[1] == 1:
        c = c.reshape(-1, 2)
    if is_charuco(board):
        n = board.n_corners
        if c.ndim != 2 or c.shape != (n, 2):
            raise InputError(f"{what}: {c.shape} corners do not match the ChArUco board {board.squares_x}x"
                             f"{board.squares_y} squares (expected ({n}, 2) pixel coordinates by corner id, NaN "
                             "where not seen)")
        seen = np.isfinite(c).all(axis=1)
        half = np.isnan(c).any(axis=1) & ~np.isnan(c).all(axis=1)
        if np.isinf(c).any() or half.any() or seen.sum() < MIN_CHARUCO_CORNERS:
            raise InputError(f"{what}: expected at least {MIN_CHARUCO_CORNERS} seen corners (both coordinates "
                             f"finite; NaN pairs for corners not seen), found {int(seen.sum())}, "
                             f"{int(half.sum())} half-NaN and {int(np.isinf(c).any(axis=1).sum())} with inf")
        return c
    if c.ndim != 2 or c.shape[1] != 2 or len(c) != board[0] * board[1]:
        raise InputError(
            f"{what}: {c.shape} corners do not match the board {board[0]}x{board[1]} "
            f"(expected ({board[0] * board[1]}, 2) pixel coordinates)"
        )
    if not np.all(np.isfinite(c)):
        raise InputError(f"{what}: corners contain NaN/inf (expected finite pixel coordinates)")
    return c


def seen_corners(corners: np.ndarray, board, square_mm: float, what: str = "corners") -> tuple[np.ndarray, np.ndarray]:
    """The corners a grid holds and their board coordinates: ``(object points (N, 3) [mm], corners
    (N, 2) [px])`` (a checkerboard's all; a ChArUco grid's finite rows)."""
    c = check_corners(corners, board, what)
    obj = board_object_points(board, square_mm)
    m = np.isfinite(c).all(axis=1)
    return obj[m], c[m]


def solve_board_pose(corners: np.ndarray, board, square_mm: float,
                     intr: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray, float]:
    """Board pose from its (seen) corners with fixed intrinsics (IPPE + Levenberg-Marquardt refinement).

    Returns
    -------
    R : (3, 3) board -> camera rotation; t : (3,) [mm]; rms : reprojection RMS [px].
    """
    obj, c = seen_corners(corners, board, square_mm, "solve_board_pose")
    ok, rvec, tvec = cv2.solvePnP(obj, c, intr.K, intr.dist_array, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise EstimationError("solvePnP failed for this pose")
    rvec, tvec = cv2.solvePnPRefineLM(obj, c, intr.K, intr.dist_array, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, intr.K, intr.dist_array)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - c) ** 2, axis=1))))
    R, _ = cv2.Rodrigues(rvec)
    return R, tvec.ravel(), rms


def reprojection_rms_with(intr: CameraIntrinsics, corners: list[np.ndarray], board,
                          square_mm: float) -> np.ndarray:
    """(V,) per-view reprojection RMS [px] with *fixed* intrinsics (pose solved per view)."""
    return np.array([solve_board_pose(c, board, square_mm, intr)[2] for c in corners])


# ----------------------------------------------------------------------------- ray error
