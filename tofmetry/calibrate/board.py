"""Board-based depth calibration: a printed chessboard as the depth reference.

Method
------
1. Per pose, the chessboard corners (given, or found in the IR image) and the IR/depth
   intrinsics give the board pose (``cv2.solvePnP``). Depth and IR share one lens and one
   pixel grid, so the board plane yields a *reference Z* for every board pixel:
   ``Z_ref = d / (n . r)`` with ``r = (x, y, 1)`` the undistorted ray, ``n . X = d`` the plane.
2. Deviation ``measured - reference`` over the board area only (inner corners' grid extended
   to the outer row of squares, minus a margin from the board edge).
3. The board pattern biases ToF depth: dark squares return less light and read longer. We use
   **white squares only** (pixels at least ``edge_margin`` squares away from any square
   boundary); the dark-minus-white difference is reported as a diagnostic.
4. Correction model (same shape as the wall mode): ``c(u, v, Z) = a(Z) + s(u, v)`` added to
   the measured depth; ``a`` piecewise-linear in Z (knots over the data's range, constant
   beyond), ``s`` a bilinear grid over the image with a membrane (first-difference)
   smoothness penalty and zero mean. Where the board never was, the penalty makes ``s``
   the smooth (harmonic) continuation of the observed border: no extrapolated polynomials.
5. Leave-poses-out cross-validation (k folds over poses).

All functions are pure (arrays in, results out); file access is in :mod:`tofmetry.io`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tofmetry.calibrate._board_model import BoardDepthModel, fit_board_model, to_depth_calibration
from tofmetry.calibrate._intrinsics import (
    _folds, board_object_points, calibrate_intrinsics, check_corners, cross_validate_intrinsics, detect_corners,
    normalize_ir, reprojection_rms_with, solve_board_pose,
)
from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics

# intrinsics helpers (board_object_points, calibrate_intrinsics, cross_validate_intrinsics, detect_corners,
# normalize_ir, reprojection_rms_with, solve_board_pose) live in tofmetry.calibrate._intrinsics and are
# re-exported here for convenience.
__all__ = [
    "BoardCalibrationResult", "BoardDepthModel", "BoardSamples", "board_object_points", "board_samples",
    "calibrate_depth_from_board", "calibrate_intrinsics", "check_corners", "constant_shift_calibration",
    "core_correction", "cross_validate_intrinsics", "detect_corners", "error_stats", "fit_board_model",
    "normalize_ir", "reprojection_rms_with", "samples_to_depth_samples", "solve_board_pose", "to_depth_calibration",
]


# ----------------------------------------------------------------------------- samples
@dataclass
class BoardSamples:
    """Board-pixel depth samples of one pose.

    Attributes
    ----------
    u, v : (N,) int pixel coordinates.
    measured_mm, reference_mm : (N,) float64 [mm] (Z).
    white : (N,) bool, pixel on a white square (away from square edges).
    dark : (N,) bool, pixel on a dark square (away from square edges).
    pose_rms_px : reprojection RMS of the board pose [px].
    dark_minus_white_mm : median(measured - ref) on dark minus on white [mm] (pattern bias).
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

    def select(self, squares: str = "white") -> "BoardSamples":
        m = self.white if squares == "white" else (self.dark if squares == "dark" else self.white | self.dark)
        return BoardSamples(self.u[m], self.v[m], self.measured_mm[m], self.reference_mm[m], self.white[m],
                            self.dark[m], self.pose_rms_px, self.dark_minus_white_mm, self.n_rejected)


def board_samples(depth: np.ndarray, ir: np.ndarray, corners: np.ndarray, board: tuple[int, int], square_mm: float,
                  intr: CameraIntrinsics, edge_margin: float = 0.2, board_margin: float = 0.25,
                  max_abs_dev_mm: float = 150.0) -> BoardSamples:
    """Reference depth from the board plane for every board pixel of one pose.

    Parameters
    ----------
    depth : (H, W) uint16 [mm], Z; 0 = invalid.
    ir : (H, W) IR amplitude (decides which square parity is white).
    corners : (cols*rows, 2) inner corners [px].
    edge_margin : fraction of a square kept away from square boundaries (mixed pixels).
    board_margin : fraction of a square kept away from the outer edge of the outer squares.
    max_abs_dev_mm : gross-outlier gate on ``measured - reference`` (holes, flying pixels).
    """
    depth = np.asarray(depth)
    if depth.shape != intr.shape or np.asarray(ir).shape != intr.shape:
        raise InputError(f"board_samples: depth {depth.shape} / IR {np.asarray(ir).shape} do not match intrinsics {intr.shape}")
    R, t, rms = solve_board_pose(corners, board, square_mm, intr)
    n = R[:, 2]
    d = float(n @ t)
    rays = intr.ray_table()
    cols, rows = board
    s = square_mm
    # pixel bounding box of the outer squares (project the extended board outline)
    outline = np.array([[-s, -s, 0], [cols * s, -s, 0], [cols * s, rows * s, 0], [-s, rows * s, 0]], float)
    uv = intr.project(outline @ R.T + t)
    H, W = intr.shape
    u0, v0 = np.clip(np.floor(np.nanmin(uv, 0)).astype(int) - 2, 0, [W - 1, H - 1])
    u1, v1 = np.clip(np.ceil(np.nanmax(uv, 0)).astype(int) + 2, 0, [W - 1, H - 1])
    vv, uu = np.mgrid[v0:v1 + 1, u0:u1 + 1]
    r = rays[v0:v1 + 1, u0:u1 + 1]
    denom = n[0] * r[..., 0] + n[1] * r[..., 1] + n[2]
    zref = d / denom
    X = np.stack([r[..., 0] * zref, r[..., 1] * zref, zref], -1)
    pb = (X - t) @ R            # board coordinates [mm]
    bx, by = pb[..., 0] / s, pb[..., 1] / s   # in squares; inner corners at integers 0..cols-1
    inside = (bx > -1 + board_margin) & (bx < cols - board_margin) & (by > -1 + board_margin) & (by < rows - board_margin)
    fx, fy = bx - np.floor(bx), by - np.floor(by)
    away = (fx > edge_margin) & (fx < 1 - edge_margin) & (fy > edge_margin) & (fy < 1 - edge_margin)
    parity = (np.floor(bx).astype(int) + np.floor(by).astype(int)) & 1
    meas = depth[v0:v1 + 1, u0:u1 + 1].astype(np.float64)
    keep = inside & away & (meas > 0) & (zref > 0)
    dev = meas - zref
    gross = keep & (np.abs(dev) > max_abs_dev_mm)
    keep &= ~gross
    if keep.sum() < 20:
        raise EstimationError(f"fewer than 20 valid board pixels in this pose ({int(keep.sum())})")
    irs = np.asarray(ir, dtype=np.float64)[v0:v1 + 1, u0:u1 + 1]
    # which parity is white: brighter IR over the whole board area (valid depth or not: white
    # squares may saturate and lose their depth at close range)
    area = inside & away
    m0, m1 = area & (parity == 0), area & (parity == 1)
    white_par = 0 if (np.median(irs[m0]) if m0.any() else 0) >= (np.median(irs[m1]) if m1.any() else 0) else 1
    white = keep & (parity == white_par)
    dark = keep & (parity != white_par)
    dmw = float(np.median(dev[dark]) - np.median(dev[white])) if dark.any() and white.any() else float("nan")
    k = keep.ravel()
    return BoardSamples(uu.ravel()[k], vv.ravel()[k], meas.ravel()[k], zref.ravel()[k], white.ravel()[k],
                        dark.ravel()[k], rms, dmw, int(gross.sum()))


# ----------------------------------------------------------------------------- evaluation
def error_stats(err_mm: np.ndarray) -> dict:
    """mean, std, RMS and 95th percentile of |e| [mm] of an error sample."""
    e = np.asarray(err_mm, float)
    if e.size == 0:
        return {"n": 0, "mean_mm": float("nan"), "std_mm": float("nan"), "rms_mm": float("nan"), "p95_abs_mm": float("nan")}
    return {"n": int(e.size), "mean_mm": float(e.mean()), "std_mm": float(e.std()),
            "rms_mm": float(np.sqrt(np.mean(e ** 2))), "p95_abs_mm": float(np.percentile(np.abs(e), 95))}


@dataclass
class BoardCalibrationResult:
    """Board-based depth calibration.

    Attributes
    ----------
    model : BoardDepthModel fitted on all poses.
    squares : which pixels were used ("white": white squares only).
    cv : {"none", "constant_refit", "iai_shift" (if given), "model"} -> error stats [mm] of
        ``corrected - reference`` on held-out poses (k-fold over poses).
    cv_per_pose : per held-out pose RMS [mm] per case.
    fit_residual : error stats of the final model on its own samples.
    dark_minus_white_mm : median pattern bias per pose [mm].
    pose_rms_px : board-pose reprojection RMS per pose [px].
    n_samples : samples used per pose.
    """

    model: object
    squares: str
    cv: dict
    cv_per_pose: dict
    fit_residual: dict
    before: dict
    dark_minus_white_mm: np.ndarray
    pose_rms_px: np.ndarray
    n_samples: np.ndarray
    k_folds: int
    skipped: list = field(default_factory=list)
    pose_index: list = field(default_factory=list)

    def depth_calibration(self, intrinsics: CameraIntrinsics, sensor: str = "kinect_v2", provenance: dict | None = None):
        """The fitted model as a core ``DepthCalibration`` (save with ``tofmetry.io.calibration_file.save_calibration``)."""
        if isinstance(self.model, BoardDepthModel):
            return to_depth_calibration(self.model, intrinsics, sensor, provenance=provenance,
                                        diagnostics={"board": self.summary()})
        return self.model

    def summary(self) -> dict:
        return {"squares": self.squares, "k_folds": self.k_folds, "cv_held_out": self.cv,
                "fit_residual": self.fit_residual, "before": self.before,
                "dark_minus_white_mm_median": float(np.nanmedian(self.dark_minus_white_mm)),
                "pose_rms_px_median": float(np.median(self.pose_rms_px)),
                "n_poses": int(len(self.n_samples)), "n_samples": int(np.sum(self.n_samples)),
                "skipped_poses": self.skipped,
                "model": type(self.model).__name__,
                "unsupported_surface_nodes": int(np.sum(self.model.support == 0)) if hasattr(self.model, "support") else None}


def samples_to_depth_samples(samples: list[BoardSamples], shape: tuple[int, int], names: list[str] | None = None) -> list:
    """Board samples -> the calibration core's ``DepthSample`` (NaN off the selected pixels)."""
    from tofmetry.calibrate._fit import DepthSample

    out = []
    for j, s in enumerate(samples):
        m = np.full(shape, np.nan)
        r = np.full(shape, np.nan)
        m[s.v, s.u] = s.measured_mm
        r[s.v, s.u] = s.reference_mm
        out.append(DepthSample(m, r, None, names[j] if names else f"pose{j}"))
    return out


def core_correction(cal, u: np.ndarray, v: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
    """Correction [mm] (to add to measured Z) of a core ``DepthCalibration`` at pixels (u, v)."""
    z = np.asarray(z_mm, float)
    k0, k1, w = cal.surface_weights(z)
    surf = cal.surfaces
    S = (1 - w) * surf[k0, v, u] + w * surf[k1, v, u]
    c = -(cal.range_error(z) + S)
    lo, hi = cal.valid_range_mm
    return np.where((z >= lo) & (z <= hi), c, 0.0)


def default_core_config(z_mm: np.ndarray):
    """Core fit configuration for board data: 4 surface nodes over the data's range, spline surfaces."""
    from tofmetry.calibrate._fit import DepthFitConfig

    lo, hi = np.percentile(z_mm, [5, 95])
    return DepthFitConfig(nodes_mm=tuple(np.linspace(lo, hi, 4).round(1)), center_pixels=400)


def constant_shift_calibration(shift_mm: float, intrinsics: CameraIntrinsics, sensor: str = "kinect_v2",
                               provenance: dict | None = None):
    """A core ``DepthCalibration`` equal to a constant shift (iai_kinect2 ``depthShift``):
    zero surfaces and a constant range curve ``R = -shift`` (corrected = measured + shift)."""
    from tofmetry.calibrate._model import DepthCalibration

    s = float(shift_mm)
    return DepthCalibration(
        sensor=sensor, intrinsics=intrinsics, range_knots=np.array([1.0, 1.0, 65535.0, 65535.0]),
        range_coeffs=np.array([-s, -s]), range_degree=1, range_data_mm=np.array([1.0, 65535.0]),
        valid_range_mm=np.array([1.0, 65535.0]), node_mm=np.array([1000.0]),
        surfaces=np.zeros((1, *intrinsics.shape), np.float32), offset_mm=-s, surface_model="none",
        provenance={"method": "constant depth shift", **(provenance or {})},
    )


def calibrate_depth_from_board(poses: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]], board: tuple[int, int],
                               square_mm: float, intrinsics: CameraIntrinsics, *, squares: str = "white",
                               k_folds: int = 5, iai_shift_mm: float | None = None, seed: int = 0,
                               model: str = "grid", core_config=None, sensor: str = "kinect_v2", min_samples: int = 200,
                               fit_kwargs: dict | None = None, sample_kwargs: dict | None = None) -> BoardCalibrationResult:
    """Board-based depth calibration with leave-poses-out validation.

    Parameters
    ----------
    poses : list of ``(depth (H,W) uint16 mm, ir (H,W), corners (cols*rows,2) px or None)``;
        corners None -> detected in the IR image (poses where detection fails are skipped).
    board : (cols, rows) inner corners; square_mm : square size [mm].
    intrinsics : IR/depth intrinsics (the board plane's accuracy depends on them).
    squares : "white" (default, dark squares read longer) or "all".
    model : "grid" (this module's range + membrane-grid model, :class:`BoardDepthModel`) or
        "core" (the calibration core's ``fit_depth_model`` -> ``DepthCalibration``).
    min_samples : poses with fewer usable pixels are skipped (e.g. white squares saturated at close range).
    iai_shift_mm : an iai_kinect2 ``depthShift`` to evaluate alongside (corrected = measured + shift).

    Returns
    -------
    BoardCalibrationResult
    """
    if squares not in ("white", "all"):
        raise InputError(f"squares must be 'white' or 'all', found {squares!r}")
    fit_kwargs = fit_kwargs or {}
    sample_kwargs = sample_kwargs or {}
    samples: list[BoardSamples] = []
    skipped = []
    kept: list[int] = []
    for i, (depth, ir, corners) in enumerate(poses):
        if corners is None:
            corners = detect_corners(ir, board)
            if corners is None:
                skipped.append((i, "board not found in IR"))
                continue
        try:
            s = board_samples(depth, ir, corners, board, square_mm, intrinsics, **sample_kwargs)
        except EstimationError as exc:
            skipped.append((i, str(exc)))
            continue
        sel = s.select(squares)
        if len(sel.u) < min_samples:
            skipped.append((i, f"only {len(sel.u)} usable {squares}-square pixels (< {min_samples})"))
            continue
        samples.append(sel)
        kept.append(i)
    if len(samples) < 3:
        raise EstimationError(f"only {len(samples)} usable board poses (need >= 3); skipped: {skipped}")

    def cat(ids, attr):
        return np.concatenate([getattr(samples[i], attr) for i in ids])

    if model not in ("grid", "core"):
        raise InputError(f"model must be 'grid' or 'core', found {model!r}")

    def fit(ids):
        if model == "core":
            from tofmetry.calibrate._fit import fit_depth_model

            cfg = core_config or default_core_config(cat(ids, "measured_mm"))
            try:
                res = fit_depth_model(samples_to_depth_samples([samples[i] for i in ids], intrinsics.shape),
                                      intrinsics, cfg, sensor=sensor, provenance={"method": "board", "squares": squares})
            except ValueError as exc:   # e.g. two poses at the same central distance (smoothing spline)
                raise EstimationError(f"core depth model failed on board samples: {exc}") from None
            cal = res.calibration
            return cal, (lambda u, v, z, _c=cal: core_correction(_c, u, v, z))
        m = fit_board_model(cat(ids, "u"), cat(ids, "v"), cat(ids, "measured_mm"), cat(ids, "reference_mm"),
                            intrinsics.shape, **fit_kwargs)
        return m, m.correction

    cases = ["none", "constant_refit", "model"] + (["iai_shift"] if iai_shift_mm is not None else [])
    errs = {c: [] for c in cases}
    per_pose = {c: np.full(len(samples), np.nan) for c in cases}
    folds = _folds(len(samples), k_folds, seed)
    for test in folds:
        train = np.setdiff1d(np.arange(len(samples)), test)
        _, corr = fit(train)
        const = float(np.mean(cat(train, "reference_mm") - cat(train, "measured_mm")))
        for i in test:
            s = samples[i]
            e0 = s.measured_mm - s.reference_mm
            es = {"none": e0, "constant_refit": e0 + const, "model": e0 + corr(s.u, s.v, s.measured_mm)}
            if iai_shift_mm is not None:
                es["iai_shift"] = e0 + iai_shift_mm
            for c, e in es.items():
                errs[c].append(e)
                per_pose[c][i] = np.sqrt(np.mean(e ** 2))
    cv = {c: error_stats(np.concatenate(errs[c])) for c in cases}
    all_ids = np.arange(len(samples))
    model_obj, corr = fit(all_ids)
    u, v, zm, zr = cat(all_ids, "u"), cat(all_ids, "v"), cat(all_ids, "measured_mm"), cat(all_ids, "reference_mm")
    return BoardCalibrationResult(
        model=model_obj, squares=squares, cv=cv, cv_per_pose=per_pose,
        fit_residual=error_stats(zm + corr(u, v, zm) - zr), before=error_stats(zm - zr),
        dark_minus_white_mm=np.array([s.dark_minus_white_mm for s in samples]),
        pose_rms_px=np.array([s.pose_rms_px for s in samples]), n_samples=np.array([len(s.u) for s in samples]),
        k_folds=len(folds), skipped=skipped, pose_index=kept,
    )
