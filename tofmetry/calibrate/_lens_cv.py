"""k-fold pose-wise cross-validation of the Brown-model lens calibration (:func:`cross_validate_intrinsics`).

Each fold's views are held out, the lens is fitted on the others (:func:`~._lens_fit.calibrate_intrinsics`)
and each held-out view's reprojection RMS [px] is measured with its pose solved under that lens.
"""

from __future__ import annotations

import cv2
import numpy as np

from tofmetry.calibrate._board_pose import reprojection_rms_with
from tofmetry.calibrate._lens_fit import calibrate_intrinsics, opencv_refused
from tofmetry.errors import DegenerateFitError, EstimationError
from tofmetry.sensor import CameraIntrinsics


def _pnp_rms(intr: CameraIntrinsics, obj: np.ndarray, corners: np.ndarray) -> float:
    """Reprojection RMS [px] of one view with fixed intrinsics, its pose solved (IPPE + LM)."""
    o = np.asarray(obj, np.float64).reshape(-1, 3)
    c = np.asarray(corners, np.float64).reshape(-1, 2)
    ok, rv, tv = cv2.solvePnP(o, c, intr.K, intr.dist_array, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise EstimationError("solvePnP failed for a held-out view")
    rv, tv = cv2.solvePnPRefineLM(o, c, intr.K, intr.dist_array, rv, tv)
    p, _ = cv2.projectPoints(o, rv, tv, intr.K, intr.dist_array)
    return float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - c) ** 2, axis=1))))


def _folds(n: int, k: int, seed: int) -> list[np.ndarray]:
    if n < 2:
        raise EstimationError(f"cross-validation needs at least 2 poses, found {n}")
    k = max(2, min(k, n))
    perm = np.random.default_rng(seed).permutation(n)
    return [np.sort(perm[i::k]) for i in range(k)]


def cross_validate_intrinsics(corners: list[np.ndarray], board: tuple[int, int], square_mm: float,
                              image_size: tuple[int, int], k: int = 5, seed: int = 0, fix_k3: bool = False,
                              exclude: list[int] | None = None, object_points: list[np.ndarray] | None = None) -> dict:
    """k-fold pose-wise cross-validation of the intrinsics.

    Calibrate on k-1 folds of views (no rejection inside the folds), then solve each held-out
    view's pose with the fitted intrinsics (``solvePnP``) and measure its reprojection RMS
    (6 pose dof for ``2 cols rows`` values: the held-out error mostly reflects the intrinsics).

    Parameters
    ----------
    corners : list of (cols*rows, 2) [px]
    k : number of folds (clamped to [2, n views]); seed : fold assignment
    exclude : view indices left out entirely (e.g. the views rejected by :func:`calibrate_intrinsics`)
    object_points : optional per-view (N_v, 3) board coordinates [mm] (partial views, ChArUco),
        as in :func:`calibrate_intrinsics`

    Returns
    -------
    dict: ``per_view_rms_px`` (V,) [px], ``rms_px``, ``median_px``, ``max_px``, ``k``, ``views``
    (indices used), ``failed_views`` (indices whose fold's fit failed in OpenCV; their error is
    ``inf``, and so is ``rms_px``).
    """
    keep = [i for i in range(len(corners)) if i not in set(exclude or [])]
    cs = [corners[i] for i in keep]
    os_ = None if object_points is None else [object_points[i] for i in keep]
    held = np.full(len(cs), np.nan)
    failed: list[int] = []
    folds = _folds(len(cs), k, seed)
    for test in folds:
        tset = set(test.tolist())
        train = [c for i, c in enumerate(cs) if i not in tset]
        train_o = None if os_ is None else [o for i, o in enumerate(os_) if i not in tset]
        try:
            fit = calibrate_intrinsics(train, None, board, square_mm, image_size, leave_one_out=False,
                                       fix_k3=fix_k3, min_coverage=0.0, reject_px=None, object_points=train_o)
        except EstimationError as exc:
            if not (opencv_refused(exc) or isinstance(exc, DegenerateFitError)):
                raise
            held[test] = np.inf  # the lens fitted without these views fails: they are not predicted at all
            failed += [keep[i] for i in test]
            continue
        if os_ is None:
            held[test] = reprojection_rms_with(fit.intrinsics, [cs[i] for i in test], board, square_mm)
        else:
            held[test] = [_pnp_rms(fit.intrinsics, os_[i], cs[i]) for i in test]
    return {"per_view_rms_px": held, "rms_px": float(np.sqrt(np.mean(held ** 2))),
            "median_px": float(np.median(held)), "max_px": float(np.max(held)), "k": len(folds), "views": keep,
            "failed_views": failed}
