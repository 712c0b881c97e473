"""Brown-model lens calibration from detected checkerboard corners (study §4.1).

``cv2.calibrateCameraExtended`` (fx, fy, cx, cy, k1, k2, p1, p2, k3), outlier-view rejection
(RMS above ``max(1 px, 5 x median)``) and refit, leave-one-out stability, the **full parameter
covariance** (the Gauss-Newton normal equations OpenCV's standard deviations come from; its
diagonal equals them) and from it the **predicted ray-error map** over the whole image
(:func:`tofmetry.calibrate._ray_error.predicted_ray_error_px`), the board coverage of the image
and of its four corner regions (:mod:`._coverage`; warnings where no board reached them).
:func:`~._lens_cv.cross_validate_intrinsics` (in :mod:`._lens_cv`) gives the k-fold pose-wise held-out
reprojection error.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import cv2
import numpy as np

from tofmetry.calibrate._board_pose import board_object_points, check_corners
from tofmetry.calibrate._coverage import (  # noqa: F401  (CORNER_COVERED_FRAC re-exported: _lens_fit.X as before)
    CORNER_COVERED_FRAC, corner_coverage, corner_region_corners, corner_region_coverage, coverage_mask,
    uncovered_corner_regions,
)
from tofmetry.calibrate._ray_error import (
    CORNER_FRAC, PARAMS, RayError, predicted_ray_error_px,
)
from tofmetry._shared.opencv_threads import one_opencv_thread
from tofmetry.errors import DegenerateFitError, EstimationError, InputError
from tofmetry.sensor import CameraIntrinsics

# ----------------------------------------------------------------------------- calibration


@dataclass(eq=False)
class IntrinsicsResult:
    """Result of :func:`calibrate_intrinsics`.

    Attributes
    ----------
    intrinsics : CameraIntrinsics
    rms_px : float, overall reprojection RMS of the kept views [px]
    std : dict param -> standard uncertainty (OpenCV ``stdDeviationsIntrinsics``)
    cov : (9, 9) covariance of :data:`PARAMS` (Gauss-Newton normal equations of the fit, with
        the intrinsics' correlations; its diagonal is ``std**2``)
    cov_matches_opencv : bool, whether ``sqrt(diag(cov))`` reproduced OpenCV's ``std`` (to 1 %);
        when not (unusual flags), ``cov`` is diagonal from ``std``
    predicted_ray : RayError or None, the ray-error map predicted from ``cov``
        (:func:`predicted_ray_error_px`, 4 px grid)
    per_image_rms_px : dict image name -> reprojection RMS [px] (kept views)
    loo : dict param -> std of the leave-one-out estimates (how much it varies)
    loo_range : dict param -> max - min over the leave-one-out folds
    influence : dict image -> max over params of |change on removal| / std
    flagged : list of images whose removal changes a parameter beyond its uncertainty
    coverage : float, fraction of the image area inside the boards' corner hulls
    cell_coverage : float, fraction of 8x8 image cells holding a detected corner
    corner_regions_coverage : dict region -> fraction of that image-corner region
        (:data:`CORNER_FRAC` of width and height) inside the boards' corner hulls
    corner_regions_corners : dict region -> detected corners in that region (all views)
    uncovered_corners : list of corner regions no board reached (:func:`uncovered_corner_regions`:
        covered below :data:`CORNER_COVERED_FRAC` by the hulls and without a detected corner; a
        partial view's detected corners count where its hull, cut by the image border, does not)
    warnings : list of str
    used : list of image names used
    rejected_views : list of image names rejected as outliers (RMS > threshold in the first fit)
    rejected_rms_px : dict rejected name -> its RMS in the first fit [px]
    reject_threshold_px : the threshold applied (NaN when rejection was off)
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
    rejected_views: list = field(default_factory=list)
    rejected_rms_px: dict = field(default_factory=dict)
    reject_threshold_px: float = float("nan")
    cov: np.ndarray | None = None
    cov_matches_opencv: bool = False
    predicted_ray: RayError | None = None
    corner_regions_coverage: dict = field(default_factory=dict)
    uncovered_corners: list = field(default_factory=list)
    corner_regions_corners: dict = field(default_factory=dict)

    @property
    def per_view_rms_px(self) -> np.ndarray:
        """(V,) RMS of the kept views [px], in ``used`` order."""
        return np.array([self.per_image_rms_px[n] for n in self.used])

    def to_dict(self, with_map: bool = True) -> dict:
        """JSON-able summary; ``with_map`` adds the predicted ray-error map on a 16 px grid."""
        d = {
            "intrinsics": self.intrinsics.to_dict(), "rms_px": self.rms_px, "std": self.std,
            "per_image_rms_px": self.per_image_rms_px, "leave_one_out_std": self.loo,
            "leave_one_out_range": self.loo_range, "influence": self.influence, "flagged": self.flagged,
            "coverage": self.coverage, "cell_coverage": self.cell_coverage, "warnings": self.warnings,
            "images_used": self.used, "rejected_views": self.rejected_views, "rejected_rms_px": self.rejected_rms_px,
            "reject_threshold_px": self.reject_threshold_px,
            "corner_regions": {"fraction_of_size": CORNER_FRAC, "covered_fraction": self.corner_regions_coverage,
                               "detected_corners": self.corner_regions_corners, "uncovered": self.uncovered_corners},
            "covariance": {"params": list(PARAMS), "matrix": None if self.cov is None else self.cov.tolist(),
                           "diagonal_matches_opencv_std": self.cov_matches_opencv},
        }
        pr = self.predicted_ray
        if pr is not None:
            pd = pr.to_dict()
            pd["meaning"] = ("first-order propagation of the parameter covariance to the rays over the full image "
                             "grid: expected (RMS) angle between the estimated and the true ray, in px at the focal "
                             "length")
            if with_map:
                coarse = predicted_ray_error_px(self.intrinsics, self.cov, step=16)
                pd["map16_px"] = np.round(coarse.map_px, 4).tolist()
                pd["map16_u_px"], pd["map16_v_px"] = coarse.u_px.tolist(), coarse.v_px.tolist()
            d["predicted_ray_error"] = pd
        return d


#: Restarts of the fit from its own solution while they lower the RMS by more than this fraction.
RESTART_GAIN = 0.01
MAX_RESTARTS = 3


def _cv_reason(exc: Exception) -> str:
    """The message of a ``cv2.error`` without OpenCV's source location (``... error: (-211:...) X in function``)."""
    msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
    m = re.search(r"error: \(-?\d+:[^)]*\)\s*(.*?)(?: in function .*)?$", msg)
    return (m.group(1) if m and m.group(1) else msg).strip()


def opencv_refused(exc: EstimationError) -> bool:
    """Whether ``exc`` is :func:`_calib`'s failure inside OpenCV (its ``__cause__`` a ``cv2.error``),
    not a failure of the input (too few views) that every fit would share."""
    return isinstance(exc.__cause__, cv2.error)


def _calib(obj, img, size, flags):
    """:func:`_calib_restarted` on one OpenCV thread: the same numbers on every run
    (:mod:`tofmetry._shared.opencv_threads`)."""
    with one_opencv_thread():
        return _calib_restarted(obj, img, size, flags)


def _calib_restarted(obj, img, size, flags):
    """One ``calibrateCameraExtended`` fit, restarted from its own solution while that helps.
    Returns rms, (9,) values, (9,) std, (V,) per-view RMS, K, dist, rvecs, tvecs.

    OpenCV's Levenberg-Marquardt can stop short of the minimum from its closed-form start: on a
    random lens of the family (k1 0.14, k2 -0.60, k3 0.65, three image corners without a board)
    it stopped at 0.125 px RMS on *exact* corners (2.8 px ray error), whatever the iteration
    limit; one restart from that solution (``CALIB_USE_INTRINSIC_GUESS``) reached 1e-5 px. The
    restart is kept only where it lowers the RMS."""
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    try:
        out = cv2.calibrateCameraExtended(obj, img, size, np.eye(3), np.zeros(5), flags=flags, criteria=crit)
    except cv2.error as exc:
        raise EstimationError(
            f"the Brown-model fit of {len(obj)} views failed in OpenCV ({_cv_reason(exc)}); corners that do not "
            "match the board's geometry (a wrong board size or square size, mis-detected corners) usually cause "
            "this") from exc
    for _ in range(MAX_RESTARTS):
        try:
            again = cv2.calibrateCameraExtended(obj, img, size, out[1].copy(), out[2].copy(),
                                                flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=crit)
        except cv2.error:
            break  # OpenCV refuses a guess whose principal point is outside the image: keep the fit
        before = out[0]
        if again[0] < before:
            out = again
        if not before - again[0] > RESTART_GAIN * before:
            break
    rms, K, dist, rv, tv, std_i, _std_e, per_view = out
    d = np.asarray(dist, float).ravel()
    d = np.concatenate([d, np.zeros(max(0, 5 - len(d)))])[:5]
    vals = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d])
    return (float(rms), vals, np.asarray(std_i, float).ravel()[:9], np.asarray(per_view, float).ravel(), K, d,
            rv, tv)


def intrinsic_covariance(obj: list[np.ndarray], img: list[np.ndarray], K: np.ndarray, dist: np.ndarray,
                         rvecs, tvecs, free: np.ndarray) -> np.ndarray:
    """(9, 9) covariance of :data:`PARAMS` at a calibration solution.

    Gauss-Newton normal equations over the intrinsics and every view's pose (``cv2.projectPoints``
    Jacobians), the poses eliminated (Schur complement), scaled by the residual variance per
    coordinate ``sum r^2 / (2 N - n_params)``: the matrix whose diagonal OpenCV reports as
    ``stdDeviationsIntrinsics``. Parameters with ``free = False`` (fixed) get zero rows/columns.

    Parameters
    ----------
    obj : list of (N_v, 3) object points [mm]; img : list of (N_v, 2) corners [px]
    K : (3, 3); dist : (5,); rvecs, tvecs : per-view poses of the solution; free : (9,) bool
    """
    A = np.zeros((9, 9))
    S = np.zeros((9, 9))
    ss, n_pts = 0.0, 0
    for o, c, r, t in zip(obj, img, rvecs, tvecs):
        p, jac = cv2.projectPoints(np.asarray(o, np.float64).reshape(-1, 3), r, t, K, dist)
        Je, Ji = jac[:, :6], jac[:, 6:15]
        res = (p.reshape(-1, 2) - np.asarray(c, np.float64).reshape(-1, 2)).ravel()
        ss += float(res @ res)
        n_pts += len(o)
        A += Ji.T @ Ji
        B = Ji.T @ Je
        S += B @ np.linalg.solve(Je.T @ Je, B.T)
    free = np.asarray(free, bool)
    N = (A - S)[np.ix_(free, free)]
    dof = 2 * n_pts - (int(free.sum()) + 6 * len(obj))
    cov = np.zeros((9, 9))
    cov[np.ix_(free, free)] = np.linalg.pinv(N) * ss / max(dof, 1)
    return 0.5 * (cov + cov.T)


def _prepare(corners, names, board, square_mm, object_points=None):
    """Names, per-view object points (float32 (N_v, 3) [mm]) and corners (float32 (N_v, 1, 2))."""
    if names is None:
        names = [f"view{k:03d}" for k in range(len(corners))]
    names = list(names)
    if len(corners) != len(names):
        raise InputError(f"calibrate_intrinsics: {len(corners)} corner sets for {len(names)} names")
    if object_points is None:
        obj = board_object_points(board, square_mm).astype(np.float32)
        imgs = [check_corners(c, board, str(nm)).astype(np.float32).reshape(-1, 1, 2) for nm, c in zip(names, corners)]
        return names, [obj] * len(imgs), imgs
    if len(object_points) != len(corners):
        raise InputError(f"calibrate_intrinsics: {len(object_points)} object-point sets for {len(corners)} corner sets")
    objs, imgs = [], []
    for nm, o, c in zip(names, object_points, corners):
        o = np.asarray(o, np.float64).reshape(-1, 3)
        c = np.asarray(c, np.float64).reshape(-1, 2)
        if len(o) != len(c) or len(c) < 6 or not (np.all(np.isfinite(o)) and np.all(np.isfinite(c))):
            raise InputError(f"calibrate_intrinsics: view {nm}: expected >= 6 finite corners with as many object "
                             f"points, found {len(c)} corners and {len(o)} object points")
        objs.append(o.astype(np.float32))
        imgs.append(c.astype(np.float32).reshape(-1, 1, 2))
    return names, objs, imgs


def calibrate_intrinsics(corners: list[np.ndarray], names: list[str] | None, board: tuple[int, int], square_mm: float,
                         image_size: tuple[int, int], leave_one_out: bool = True, fix_k3: bool = False,
                         min_coverage: float = 0.5, advance=None, *, reject_px: float | None = 1.0,
                         reject_factor: float = 5.0, flags: int = 0,
                         object_points: list[np.ndarray] | None = None) -> IntrinsicsResult:
    """Brown-model calibration from detected checkerboard corners, with outlier-view rejection.

    Parameters
    ----------
    corners : list of (cols*rows, 2) float [px], one per image where detection succeeded
    names : image names (same length), or None (``view000`` ...)
    board : (cols, rows) inner corners
    square_mm : square size [mm]
    image_size : (width, height) [px]
    leave_one_out : refit without each kept image in turn (stability analysis)
    fix_k3 : keep k3 = 0 (advisable when coverage is poor)
    min_coverage : below this fraction of the image area covered by the boards (union of
        the corner hulls) a warning is issued
    advance : optional progress callable, called once per leave-one-out refit
    reject_px, reject_factor : views whose RMS exceeds ``max(reject_px, reject_factor x median
        view RMS)`` in the first fit are rejected (mis-detected corners) and the fit repeated
        once; ``reject_px=None`` keeps every view
    flags : extra OpenCV calibration flags
    object_points : optional list of (N_v, 3) board coordinates [mm], one per view, for views
        that see only part of the board (ChArUco): ``corners[v]`` is then (N_v, 2) and ``board``
        / ``square_mm`` are not used for the object points

    Returns
    -------
    IntrinsicsResult, with the parameter covariance, the predicted ray-error map and the
    coverage of the four image-corner regions (a warning names those no board reached).

    Raises
    ------
    EstimationError
        Fewer than 3 usable images.
    DegenerateFitError
        The fit converged to values no camera has (a principal point far outside the image ...),
        as a wrong board size can make it; ``reason`` and ``rms`` (the reprojection RMS [px]) say so.
    """
    if len(corners) < 3:
        raise EstimationError(f"intrinsic calibration needs at least 3 images with a detected board, found {len(corners)}")
    names, objs, imgs = _prepare(corners, names, board, square_mm, object_points)
    corners = [c.reshape(-1, 2).astype(np.float64) for c in imgs]
    flags = int(flags) | (cv2.CALIB_FIX_K3 if fix_k3 else 0)
    size = (int(image_size[0]), int(image_size[1]))
    rms, vals, std, per_view, K, dist, rv, tv = _calib(objs, imgs, size, flags)
    rejected, rej_rms, thr = [], {}, float("nan")
    if reject_px is not None:
        thr = max(float(reject_px), reject_factor * float(np.median(per_view)))
        bad = [j for j, r in enumerate(per_view) if r > thr]
        if bad and len(imgs) - len(bad) >= 3:
            rejected = [names[j] for j in bad]
            rej_rms = {names[j]: float(per_view[j]) for j in bad}
            keep = [j for j in range(len(imgs)) if j not in set(bad)]
            names, imgs, corners = [names[j] for j in keep], [imgs[j] for j in keep], [corners[j] for j in keep]
            objs = [objs[j] for j in keep]
            rms, vals, std, per_view, K, dist, rv, tv = _calib(objs, imgs, size, flags)
    w, h = size
    try:
        intr = CameraIntrinsics(w, h, vals[0], vals[1], vals[2], vals[3], tuple(vals[4:]))
    except InputError as e:
        reason = str(e).removeprefix("intrinsics: ")
        raise DegenerateFitError(f"the lens fit converged to no camera ({reason}; reprojection RMS {rms:.2f} px)",
                                 reason, rms) from None
    res = IntrinsicsResult(
        intrinsics=intr, rms_px=rms, std=dict(zip(PARAMS, std.tolist())),
        per_image_rms_px=dict(zip(names, per_view.tolist())), used=list(names),
        rejected_views=rejected, rejected_rms_px=rej_rms, reject_threshold_px=thr,
    )
    if rejected:
        res.warnings.append(f"rejected {len(rejected)} view(s) with reprojection RMS above {thr:.2f} px "
                            f"(mis-detected corners?): " + ", ".join(f"{n} {r:.2f} px" for n, r in rej_rms.items()))
    # covariance (with correlations) and the ray error it predicts over the whole image
    free = std > 0
    cov = intrinsic_covariance(objs, corners, K, dist, rv, tv, free)
    ok = bool(np.allclose(np.sqrt(np.diag(cov)), std, rtol=0.01, atol=1e-12))
    if not ok:
        cov = np.diag(std ** 2)
    res.cov, res.cov_matches_opencv = cov, ok
    res.predicted_ray = predicted_ray_error_px(intr, cov, step=4)
    mask = coverage_mask(corners, (h, w))
    res.cell_coverage = corner_coverage(corners, (h, w))
    res.coverage = float(mask.mean())
    res.corner_regions_coverage = corner_region_coverage(mask)
    res.corner_regions_corners = corner_region_corners(corners, (h, w))
    res.uncovered_corners = uncovered_corner_regions(res.corner_regions_coverage, res.corner_regions_corners)
    if res.coverage < min_coverage:
        res.warnings.append(
            f"the boards cover only {100 * res.coverage:.0f} % of the image area ({100 * res.cell_coverage:.0f} % of "
            "8x8 cells): distortion and focal length are poorly constrained where there are no corners; add "
            "images with larger or closer boards reaching the image borders and corners"
        )
    if res.uncovered_corners:
        pr = res.predicted_ray
        res.warnings.append(
            f"no board reached the image corner region(s) {', '.join(res.uncovered_corners)} "
            f"({100 * CORNER_FRAC:.0f} % of width and height): the lens model is extrapolated there; predicted ray "
            "error there up to " + ", ".join(f"{pr.per_corner_max_px[k]:.2f}" for k in res.uncovered_corners)
            + f" px (image RMS {pr.rms_px:.2f} px); add images with the board pushed into those corners"
        )
    if leave_one_out and len(imgs) >= 4:
        folds = []
        for j in range(len(imgs)):
            others = imgs[:j] + imgs[j + 1:]
            try:
                folds.append(_calib(objs[:j] + objs[j + 1:], others, size, flags)[1])
            except EstimationError as exc:  # the fit without view j fails: j holds the lens up alone
                if not opencv_refused(exc):
                    raise
                folds.append(np.full(len(PARAMS), np.nan))
                res.warnings.append(f"{names[j]}: without it the fit fails ({_cv_reason(exc.__cause__)}); the lens "
                                    "rests on this view")
            if advance is not None:
                advance()
        folds = np.array(folds)
        ok_f = np.isfinite(folds).all(axis=1)
        if ok_f.sum() >= 2:
            res.loo = dict(zip(PARAMS, folds[ok_f].std(axis=0, ddof=1).tolist()))
            res.loo_range = dict(zip(PARAMS, (folds[ok_f].max(axis=0) - folds[ok_f].min(axis=0)).tolist()))
        safe = np.where(std > 0, std, np.inf)
        for j, nm in enumerate(names):
            if not ok_f[j]:
                res.influence[nm] = float("inf")
                res.flagged.append(nm)
                continue
            ratio = np.abs(folds[j] - vals) / safe
            res.influence[nm] = float(np.max(ratio))
            if res.influence[nm] > 1.0:
                worst = PARAMS[int(np.argmax(ratio))]
                res.flagged.append(nm)
                res.warnings.append(f"{nm}: removing it moves {worst} by {ratio.max():.1f} standard uncertainties")
    return res
