"""IR–colour (two-camera) extrinsic calibration from paired board views.

The extrinsics ``p_color = R p_ir + t`` come from ``cv2.stereoCalibrate`` with both cameras'
intrinsics held fixed (calibrate them first: they are better determined from each camera's own
views). Their uncertainty is the jackknife over views (leave one view out, refit): it needs no
noise model and includes the board's flatness and detection errors as they are. The result is
validated on held-out pairs the fit never saw: the board pose is solved from the IR corners alone,
carried through the extrinsics into the colour camera and projected; the distance to the corners
detected in the colour image is the held-out reprojection error [px].

Frames: camera x right, y down, z forward; board object points in mm (the translation is returned
in metres).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from tofmetry._shared.opencv_threads import one_opencv_thread
from tofmetry.errors import InputError
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics

_CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@dataclass
class StereoResult:
    """IR -> colour extrinsics with uncertainty and held-out validation.

    Attributes
    ----------
    extrinsics : Extrinsics ``ir`` -> ``color``, translation [m]
    rotation_std_deg : (3,) jackknife standard deviation of the rotation vector [deg]
    translation_std_mm : (3,) jackknife standard deviation of the translation [mm]
    rms_px : RMS reprojection error of the fit over both cameras [px]
    per_view_rms_px : (V, 2) RMS per training view, IR and colour [px]
    heldout_rms_px : RMS held-out reprojection error in the colour image [px] (NaN: no held-out pairs)
    heldout_max_px : largest held-out corner error [px]
    n_train, n_heldout : pairs used for the fit and for validation
    """

    extrinsics: Extrinsics
    rotation_std_deg: np.ndarray
    translation_std_mm: np.ndarray
    rms_px: float
    per_view_rms_px: np.ndarray
    heldout_rms_px: float
    heldout_max_px: float
    n_train: int
    n_heldout: int
    diagnostics: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"extrinsics": self.extrinsics.to_dict(),
                "rotation_std_deg": self.rotation_std_deg.tolist(),
                "translation_std_mm": self.translation_std_mm.tolist(),
                "rms_px": self.rms_px, "per_view_rms_px": self.per_view_rms_px.tolist(),
                "heldout_rms_px": self.heldout_rms_px, "heldout_max_px": self.heldout_max_px,
                "n_train": self.n_train, "n_heldout": self.n_heldout, "diagnostics": self.diagnostics}


def _flags(ir: CameraIntrinsics, color: CameraIntrinsics) -> int:
    for name, c in (("IR", ir), ("colour", color)):
        if c.model == "fisheye":
            raise InputError(f"calibrate_stereo: the {name} intrinsics have a fisheye lens; "
                             "stereo calibration supports the brown and rational models")
    flags = cv2.CALIB_FIX_INTRINSIC
    if "rational" in (ir.model, color.model):
        flags |= cv2.CALIB_RATIONAL_MODEL
    return flags


def _dist8(c: CameraIntrinsics) -> np.ndarray:
    d = np.zeros(8)
    d[:c.dist_array.size] = c.dist_array
    return d


def _stereo(obj, a, b, ir, color, flags):
    with one_opencv_thread():  # the same numbers on every run
        out = cv2.stereoCalibrateExtended(
            obj, a, b, ir.K, _dist8(ir), color.K, _dist8(color), ir.shape[::-1], np.eye(3), np.zeros(3),
            flags=flags, criteria=_CRIT)
    rms, R, T, per_view = out[0], out[5], out[6], out[-1]
    return float(rms), R, T.reshape(3), np.asarray(per_view).reshape(-1, 2)


def common_corners(ids_a: np.ndarray, points_a: np.ndarray, ids_b: np.ndarray,
                   points_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The corners two cameras both detected in one view of an identified (ChArUco) board.

    Parameters
    ----------
    ids_a, ids_b : (N_a,), (N_b,) int corner ids (unique) detected by camera a and b
    points_a, points_b : (N_a, 2), (N_b, 2) the corners [px], in the order of their ids

    Returns
    -------
    ids : (M,) int64, sorted ids found by both
    pa, pb : (M, 2) float64 [px], camera a's and b's corners of ``ids``
    """
    ia, ib = np.asarray(ids_a, np.int64).ravel(), np.asarray(ids_b, np.int64).ravel()
    pa, pb = np.asarray(points_a, np.float64).reshape(-1, 2), np.asarray(points_b, np.float64).reshape(-1, 2)
    if len(ia) != len(pa) or len(ib) != len(pb):
        raise InputError(f"common_corners: {len(ia)} / {len(ib)} ids for {len(pa)} / {len(pb)} corners; "
                         "expected one id per corner")
    ids, ka, kb = np.intersect1d(ia, ib, assume_unique=True, return_indices=True)
    return ids, pa[ka], pb[kb]


def heldout_reprojection(obj_points, ir_points, color_points, ir: CameraIntrinsics, color: CameraIntrinsics,
                         extrinsics: Extrinsics) -> np.ndarray:
    """Colour-image errors of held-out pairs [px], (sum of corners,) float64.

    The board pose is solved from the IR corners (``cv2.solvePnP``, IR intrinsics), carried into
    the colour camera by ``extrinsics`` and projected with the colour intrinsics.
    """
    errs = []
    for o, a, b in zip(obj_points, ir_points, color_points):
        o = np.asarray(o, np.float64).reshape(-1, 3)
        ok, rv, tv = cv2.solvePnP(o, np.asarray(a, np.float64).reshape(-1, 1, 2), ir.K, ir.dist_array,
                                  flags=cv2.SOLVEPNP_IPPE)
        rv, tv = cv2.solvePnPRefineLM(o, np.asarray(a, np.float64).reshape(-1, 1, 2), ir.K, ir.dist_array, rv, tv)
        Rb = cv2.Rodrigues(rv)[0]
        pc = extrinsics.apply((o @ Rb.T + tv.reshape(3)) * 1e-3)
        uv = color.project(pc)
        errs.append(np.linalg.norm(uv - np.asarray(b, np.float64).reshape(-1, 2), axis=1))
    return np.concatenate(errs) if errs else np.zeros(0)


def calibrate_stereo(obj_points: list, ir_points: list, color_points: list, ir: CameraIntrinsics,
                     color: CameraIntrinsics, heldout: list[int] | None = None) -> StereoResult:
    """IR -> colour extrinsics from paired board views, with fixed intrinsics.

    Parameters
    ----------
    obj_points : list of (N_i, 3) board corners [mm] (board frame, z = 0), one per pair
    ir_points, color_points : lists of (N_i, 2) the same corners detected in the IR and colour images [px]
    ir, color : intrinsics of the two cameras (Brown or rational lens)
    heldout : indices of the pairs kept out of the fit for validation (default: every 4th pair
        when there are at least 8, else none)

    Returns
    -------
    StereoResult

    Raises
    ------
    InputError
        Fewer than 3 training pairs, lists of different lengths, or a fisheye lens.
    """
    n = len(obj_points)
    if not (len(ir_points) == len(color_points) == n):
        raise InputError(f"calibrate_stereo: {n} object point sets, {len(ir_points)} IR and "
                         f"{len(color_points)} colour corner sets; expected one of each per pair")
    if heldout is None:
        heldout = list(range(3, n, 4)) if n >= 8 else []
    hset = set(int(i) for i in heldout)
    train = [i for i in range(n) if i not in hset]
    if len(train) < 3:
        raise InputError(f"calibrate_stereo: need at least 3 training pairs, found {len(train)} "
                         f"({n} pairs, {len(hset)} held out)")
    flags = _flags(ir, color)
    obj = [np.asarray(obj_points[i], np.float32).reshape(-1, 1, 3) for i in train]
    a = [np.asarray(ir_points[i], np.float32).reshape(-1, 1, 2) for i in train]
    b = [np.asarray(color_points[i], np.float32).reshape(-1, 1, 2) for i in train]
    rms, R, T, per_view = _stereo(obj, a, b, ir, color, flags)
    ext = Extrinsics(R, T * 1e-3, "ir", "color")
    # jackknife over training views
    rv0 = cv2.Rodrigues(R)[0].reshape(3)
    reps = []
    for k in range(len(train)):
        keep = [j for j in range(len(train)) if j != k]
        _, Rk, Tk, _ = _stereo([obj[j] for j in keep], [a[j] for j in keep], [b[j] for j in keep], ir, color, flags)
        reps.append(np.concatenate([cv2.Rodrigues(Rk @ R.T)[0].reshape(3) + rv0, Tk]))
    reps = np.asarray(reps)
    m = len(reps)
    jstd = np.sqrt((m - 1) / m * ((reps - reps.mean(axis=0)) ** 2).sum(axis=0))
    hidx = sorted(hset)
    herr = heldout_reprojection([obj_points[i] for i in hidx], [ir_points[i] for i in hidx],
                                [color_points[i] for i in hidx], ir, color, ext)
    return StereoResult(
        extrinsics=ext, rotation_std_deg=np.degrees(jstd[:3]), translation_std_mm=jstd[3:], rms_px=rms,
        per_view_rms_px=per_view, heldout_rms_px=float(np.sqrt(np.mean(herr ** 2))) if herr.size else float("nan"),
        heldout_max_px=float(herr.max()) if herr.size else float("nan"), n_train=len(train), n_heldout=len(hidx),
        diagnostics={"train": train, "heldout": hidx, "rotation_deg": float(np.degrees(np.linalg.norm(rv0)))})
