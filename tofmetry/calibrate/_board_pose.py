"""Board geometry: object points, corner checks and the board pose from its corners."""

from __future__ import annotations


import cv2
import numpy as np

from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor import CameraIntrinsics


def board_object_points(board: tuple[int, int], square_mm: float) -> np.ndarray:
    """(cols*rows, 3) float64 inner-corner coordinates [mm]: ``(i s, j s, 0)``, OpenCV corner
    order (i fastest, along the columns)."""
    cols, rows = board
    gx, gy = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.column_stack([gx.ravel() * float(square_mm), gy.ravel() * float(square_mm),
                            np.zeros(cols * rows)]).astype(np.float64)


def check_corners(corners: np.ndarray, board: tuple[int, int], what: str) -> np.ndarray:
    """(cols*rows, 2) float64 corners, or InputError naming ``what``."""
    c = np.asarray(corners, dtype=np.float64)
    if c.ndim == 3 and c.shape[1] == 1:
        c = c.reshape(-1, 2)
    if c.ndim != 2 or c.shape[1] != 2 or len(c) != board[0] * board[1]:
        raise InputError(
            f"{what}: {c.shape} corners do not match the board {board[0]}x{board[1]} "
            f"(expected ({board[0] * board[1]}, 2) pixel coordinates)"
        )
    if not np.all(np.isfinite(c)):
        raise InputError(f"{what}: corners contain NaN/inf (expected finite pixel coordinates)")
    return c


def solve_board_pose(corners: np.ndarray, board: tuple[int, int], square_mm: float,
                     intr: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray, float]:
    """Board pose from its corners with fixed intrinsics (IPPE + Levenberg-Marquardt refinement).

    Returns
    -------
    R : (3, 3) board -> camera rotation; t : (3,) [mm]; rms : reprojection RMS [px].
    """
    c = check_corners(corners, board, "solve_board_pose")
    obj = board_object_points(board, square_mm)
    ok, rvec, tvec = cv2.solvePnP(obj, c, intr.K, intr.dist_array, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise EstimationError("solvePnP failed for this pose")
    rvec, tvec = cv2.solvePnPRefineLM(obj, c, intr.K, intr.dist_array, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, intr.K, intr.dist_array)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - c) ** 2, axis=1))))
    R, _ = cv2.Rodrigues(rvec)
    return R, tvec.ravel(), rms


def reprojection_rms_with(intr: CameraIntrinsics, corners: list[np.ndarray], board: tuple[int, int],
                          square_mm: float) -> np.ndarray:
    """(V,) per-view reprojection RMS [px] with *fixed* intrinsics (pose solved per view)."""
    return np.array([solve_board_pose(c, board, square_mm, intr)[2] for c in corners])


# ----------------------------------------------------------------------------- ray error
