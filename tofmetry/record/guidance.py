"""The guidance of the recording protocols: pure functions on arrays.

* :func:`warmup_status` — has the drift of a warm-up series settled (stop the recording)?
* :func:`wall_check` — does the wall fill the view, and is the camera square to it?
* :func:`board_cells`, :func:`missing_cells`, :func:`describe_cells` — coverage of image regions
  and range bins by board poses (the calibration support map, coarse, filled live)
* :func:`view_overlap` — share of a new view that overlaps the previous one (object scans)

Conventions: pixels ``(u, v)``, camera ``x`` right, ``y`` down, ``z`` forward; depth is Z [mm].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tofmetry.assess import local_linear_smooth
from tofmetry.errors import InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics


# ----------------------------------------------------------------------------- warm-up
@dataclass
class WarmupStatus:
    """Where a warm-up series stands.

    Attributes
    ----------
    stable : the smoothed patch distance stayed within ``tolerance_mm`` over the last ``confirm_s``
    elapsed_s : time since the first frame [s]
    level_mm : current smoothed distance [mm] (NaN before 3 frames)
    drift_mm : smoothed distance now minus at the first frame [mm]
    window_range_mm : peak-to-peak of the smoothed curve over the last ``confirm_s`` [mm]
    stable_since_s : start of the stable window [s since the first frame] (None when not stable)
    message : one line for the operator
    """

    stable: bool
    elapsed_s: float
    level_mm: float
    drift_mm: float
    window_range_mm: float
    stable_since_s: float | None
    message: str


def warmup_status(time_s: np.ndarray, distance_mm: np.ndarray, tolerance_mm: float = 1.0, confirm_s: float = 600.0,
                  smooth_window_s: float | None = None) -> WarmupStatus:
    """Decide whether a warm-up series has settled.

    Parameters
    ----------
    time_s : (T,) frame times [s], increasing
    distance_mm : (T,) mean depth of the followed patch [mm] (NaN: frame skipped)
    tolerance_mm : the smoothed curve must stay within this peak-to-peak band [mm]
    confirm_s : ... over this last stretch of time [s]; the series must be at least this long
    smooth_window_s : kernel of the local-linear smoothing [s] (default as
        :func:`tofmetry.assess.assess_warmup`: ``max(120 s, 5 x median frame interval)``)

    Returns
    -------
    WarmupStatus
    """
    t = np.asarray(time_s, np.float64).ravel()
    d = np.asarray(distance_mm, np.float64).ravel()
    if t.shape != d.shape:
        raise InputError(f"warmup_status: {t.size} times for {d.size} distances")
    if not tolerance_mm > 0 or not confirm_s > 0:
        raise InputError("warmup_status: tolerance_mm and confirm_s must be positive")
    if t.size < 3 or np.isfinite(d).sum() < 3:
        return WarmupStatus(False, float(t[-1] - t[0]) if t.size else 0.0, float("nan"), 0.0, float("nan"), None,
                            "collecting the first frames")
    t = t - t[0]
    if smooth_window_s is None:
        smooth_window_s = max(120.0, 5.0 * float(np.median(np.diff(t))))
    sm = local_linear_smooth(t, d, smooth_window_s)
    ok = np.isfinite(sm)
    level = float(sm[ok][-1])
    drift = level - float(sm[ok][0])
    win = ok & (t >= t[-1] - confirm_s)
    rng = float(np.ptp(sm[win])) if win.sum() >= 2 else float("nan")
    long_enough = t[-1] >= confirm_s
    stable = bool(long_enough and win.sum() >= 3 and rng <= tolerance_mm)
    if stable:
        msg = (f"stable: within {rng:.2f} mm over the last {confirm_s / 60:.0f} min "
               f"(drift since start {drift:+.2f} mm)")
    elif not long_enough:
        msg = f"warming up: {t[-1] / 60:.1f} of at least {confirm_s / 60:.0f} min; drift so far {drift:+.2f} mm"
    else:
        msg = (f"still drifting: {rng:.2f} mm over the last {confirm_s / 60:.0f} min "
               f"(tolerance {tolerance_mm:g} mm); drift since start {drift:+.2f} mm")
    return WarmupStatus(stable, float(t[-1]), level, drift, rng, float(t[-1] - confirm_s) if stable else None, msg)


def patch_distance_mm(depth: np.ndarray, patch: tuple[int, int, int]) -> float:
    """Mean valid depth [mm] of the square patch ``(u0, v0, size)``; NaN when less than half is valid."""
    u0, v0, s = patch
    p = np.asarray(depth[v0:v0 + s, u0:u0 + s], np.float64)
    good = p > 0
    return float(p[good].mean()) if good.sum() >= max(1, p.size // 2) else float("nan")


# ----------------------------------------------------------------------------- wall
@dataclass
class WallCheck:
    """Fronto-parallel and fill check of one frame of a wall.

    Attributes
    ----------
    ok : every check passed
    fill : share of the image [0, 1] whose depth lies on the fitted wall plane
    yaw_deg : angle of the wall about the camera's vertical axis [deg]; positive: its right side is farther
    pitch_deg : angle about the horizontal axis [deg]; positive: its lower side is farther
    distance_mm : distance of the plane along the optical axis [mm] (NaN without a plane)
    residual_mm : robust std of the plane residuals [mm]
    messages : what to fix, for the operator (empty when ok)
    """

    ok: bool
    fill: float
    yaw_deg: float
    pitch_deg: float
    distance_mm: float
    residual_mm: float
    messages: list[str] = field(default_factory=list)


def _grid_points(depth: np.ndarray, intr: CameraIntrinsics, stride: int) -> tuple[np.ndarray, int]:
    """Back-projected points [m] of every ``stride``-th pixel with depth, and the number of grid pixels."""
    h, w = depth.shape
    vv, uu = np.mgrid[stride // 2:h:stride, stride // 2:w:stride]
    z = depth[vv, uu].astype(np.float64).ravel() / 1000.0
    good = z > 0
    uv = np.column_stack([uu.ravel()[good], vv.ravel()[good]]).astype(np.float64)
    xy = intr.pixel_to_normalized(uv)
    pts = np.column_stack([xy * z[good, None], z[good]])
    return pts, uu.size


def wall_check(depth: np.ndarray, intr: CameraIntrinsics, *, max_tilt_deg: float = 1.0, min_fill: float = 0.9,
               stride: int = 4, inlier_mm: float | None = None) -> WallCheck:
    """Check that a flat wall fills the view and that the camera is square to it.

    Parameters
    ----------
    depth : (H, W) uint16 depth Z [mm] of one frame
    intr : intrinsics of the depth camera (rays undistorted)
    max_tilt_deg : largest yaw or pitch accepted [deg]
    min_fill : smallest share of the image on the wall plane
    stride : pixel step of the grid the plane is fitted on [px]
    inlier_mm : distance to the plane counted as "on the wall" [mm] (default ``max(15, 1 % of the distance)``)

    Returns
    -------
    WallCheck
    """
    if depth.shape != intr.shape:
        raise InputError(f"wall_check: depth {depth.shape[1]}x{depth.shape[0]} does not match the intrinsics "
                         f"{intr.width}x{intr.height}")
    pts, n_grid = _grid_points(depth, intr, stride)
    if len(pts) < 50:
        return WallCheck(False, 0.0, float("nan"), float("nan"), float("nan"), float("nan"),
                         ["no depth in view: point the camera at the wall"])
    inl = np.ones(len(pts), bool)
    normal, c = np.array([0.0, 0.0, -1.0]), pts.mean(0)
    for _ in range(4):                                  # plane fit, then refit on the inliers
        q = pts[inl]
        c = q.mean(0)
        normal = np.linalg.svd(q - c, full_matrices=False)[2][2]
        if normal[2] > 0:
            normal = -normal                            # toward the camera
        r = (pts - c) @ normal
        dist_c = float(c @ -normal / max(-normal[2], 1e-9))
        tol = (inlier_mm if inlier_mm is not None else max(15.0, 0.01 * dist_c * 1000)) / 1000.0
        inl = np.abs(r) <= tol
        if inl.sum() < 3:
            inl = np.ones(len(pts), bool)
            break
    resid = (pts[inl] - c) @ normal
    mad = float(np.median(np.abs(resid - np.median(resid))) * 1.4826 * 1000)
    yaw = float(np.degrees(np.arctan2(-normal[0], -normal[2])))
    pitch = float(np.degrees(np.arctan2(-normal[1], -normal[2])))
    dist = float((c @ normal) / normal[2] * 1000.0)
    fill = float(inl.sum() / n_grid)
    msgs = []
    if fill < min_fill:
        msgs.append(f"the wall fills {100 * fill:.0f} % of the view (need {100 * min_fill:.0f} %): move closer or clear "
                    "the view of other objects")
    if abs(yaw) > max_tilt_deg:
        msgs.append(f"not square about the vertical axis: the wall's {'right' if yaw > 0 else 'left'} side is "
                    f"{abs(yaw):.1f}° farther (limit {max_tilt_deg:g}°): turn the camera "
                    f"{'right' if yaw > 0 else 'left'}")
    if abs(pitch) > max_tilt_deg:
        msgs.append(f"not square about the horizontal axis: the wall's {'lower' if pitch > 0 else 'upper'} part is "
                    f"{abs(pitch):.1f}° farther (limit {max_tilt_deg:g}°): tilt the camera "
                    f"{'down' if pitch > 0 else 'up'}")
    return WallCheck(not msgs, fill, yaw, pitch, dist, mad, msgs)


# ----------------------------------------------------------------------------- board coverage
REGION_NAMES_3 = (("top-left", "top", "top-right"), ("left", "centre", "right"),
                  ("bottom-left", "bottom", "bottom-right"))


def board_cells(mask: np.ndarray, depth: np.ndarray, grid: tuple[int, int], range_edges_mm: np.ndarray) -> np.ndarray:
    """Pixels of one board view per image region and range bin.

    Parameters
    ----------
    mask : (H, W) bool, the board's pixels in the image
    depth : (H, W) uint16 depth Z [mm]
    grid : (rows, cols) of image regions
    range_edges_mm : (Nr + 1,) increasing edges of the measured-depth bins [mm]

    Returns
    -------
    (rows, cols, Nr) int64 counts of valid board pixels
    """
    h, w = depth.shape
    edges = np.asarray(range_edges_mm, np.float64)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise InputError(f"range edges must be at least two increasing depths [mm], found {edges.tolist()}")
    sel = mask & (depth > 0)
    vv, uu = np.nonzero(sel)
    z = depth[vv, uu].astype(np.float64)
    ve = np.linspace(0, h, grid[0] + 1)
    ue = np.linspace(0, w, grid[1] + 1)
    counts, _ = np.histogramdd(np.column_stack([vv + 0.5, uu + 0.5, z]), bins=(ve, ue, edges))
    return counts.astype(np.int64)


def board_mask(corners: np.ndarray, board: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the quadrilateral spanned by the outer inner corners of a ``cols x rows`` grid."""
    import cv2

    cols, rows = board
    c = np.asarray(corners, np.float64).reshape(rows, cols, 2)
    quad = np.array([c[0, 0], c[0, -1], c[-1, -1], c[-1, 0]])
    m = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(m, np.rint(quad).astype(np.int32), 1)
    return m.astype(bool)


def missing_cells(counts: np.ndarray, min_pixels: int) -> list[tuple[int, int, int]]:
    """``(row, col, range bin)`` of the cells with fewer than ``min_pixels`` board pixels, nearest range first."""
    r, c, b = np.nonzero(np.asarray(counts) < min_pixels)
    return sorted(zip(r.tolist(), c.tolist(), b.tolist()), key=lambda x: (x[2], x[0], x[1]))


def region_name(row: int, col: int, grid: tuple[int, int]) -> str:
    """Plain name of an image region (``top-left`` ... for a 3x3 grid, ``row r, column c`` otherwise)."""
    if grid == (3, 3):
        return REGION_NAMES_3[row][col]
    if grid == (2, 2):
        return (("top-left", "top-right"), ("bottom-left", "bottom-right"))[row][col]
    return f"row {row + 1}, column {col + 1}"


def describe_cells(cells: list[tuple[int, int, int]], grid: tuple[int, int], range_edges_mm, limit: int = 6) -> str:
    """The poses still missing as one sentence: ``"at 0.50–0.80 m: top-left, centre; at ..."``."""
    if not cells:
        return "every region and range is covered"
    e = np.asarray(range_edges_mm, np.float64)
    by_bin: dict[int, list[str]] = {}
    for r, c, b in cells:
        by_bin.setdefault(b, []).append(region_name(r, c, grid))
    parts = []
    for b in sorted(by_bin):
        names = by_bin[b]
        more = f" (+{len(names) - limit} more)" if len(names) > limit else ""
        parts.append(f"at {e[b] / 1000:.2f}–{e[b + 1] / 1000:.2f} m: {', '.join(names[:limit])}{more}")
    return "; ".join(parts)


# ----------------------------------------------------------------------------- object views
def view_overlap(new_points: np.ndarray, prev_points: np.ndarray, init: np.ndarray, max_dist_m: float = 0.01,
                 iterations: int = 30) -> tuple[float, np.ndarray, float]:
    """How much of a new view overlaps the previous one, after aligning it (point-to-plane ICP).

    Parameters
    ----------
    new_points : (N, 3) points of the new view, its camera frame [m]
    prev_points : (M, 3) points of the previous view, its camera frame [m]
    init : (4, 4) first guess of the transform new camera -> previous camera [m]
    max_dist_m : a new point overlaps when a previous point lies within this distance after alignment [m]

    Returns
    -------
    overlap : share of the new points that overlap [0, 1]
    transform : (4, 4) refined transform new -> previous
    rmse_mm : RMS distance of the overlapping points [mm]
    """
    import open3d as o3d

    if len(new_points) < 10 or len(prev_points) < 10:
        return 0.0, np.asarray(init, np.float64), float("nan")
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(new_points, np.float64)))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(prev_points, np.float64)))
    dst.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=4 * max_dist_m, max_nn=20))
    reg = o3d.pipelines.registration
    res = reg.registration_icp(src, dst, 3 * max_dist_m, np.asarray(init, np.float64),
                               reg.TransformationEstimationPointToPlane(),
                               reg.ICPConvergenceCriteria(max_iteration=iterations))
    ev = reg.evaluate_registration(src, dst, max_dist_m, res.transformation)
    return float(ev.fitness), np.asarray(res.transformation), float(ev.inlier_rmse * 1000.0)


def depth_points(depth: np.ndarray, intr: CameraIntrinsics, stride: int = 4) -> np.ndarray:
    """(N, 3) camera-frame points [m] of every ``stride``-th pixel with depth (undistorted rays)."""
    return _grid_points(depth, intr, stride)[0]
