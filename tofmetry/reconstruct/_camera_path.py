"""Whether a choice of registrations walks the cameras around the object in scan order.

A scan is taken in order: on a turntable the object turns one way by a step at a time; by hand
the user walks around it one way, the steps uneven. So the azimuths of successive cameras about
the vertical through the object advance one way, each by a step of the same order. A nearly
symmetric object (a box, a baluster, a plaque, a pebble) matches itself turned by a half or a
quarter turn, and a choice of hypotheses that turns a run of views over can still close every loop:
the cameras then step back, or leap, where the run begins and ends. Measured on twelve runs of the
family that ended 25-180 deg off (draws 43-53): every one whose path was wrong stepped back by
49-163 deg against steps of 22-64 deg, or leapt 82 or 128 deg against a median of 25 or 46 deg;
the true paths stepped the same way, each step within 0.6-1.7 x their median.

Frames: ``poses`` camera-to-world (any common frame), the object centre and the vertical in that
frame. The azimuth of a camera is the angle of its centre about the vertical through the object
centre; a camera within ``zenith_deg`` of the vertical has none (a zenithal view), and a step
between views whose elevations differ by more than ``ring_deg`` is not a step of one ring (a
second, higher ring of the plan's proposal starts where it starts).
"""

from __future__ import annotations

import numpy as np


def path_steps(poses: np.ndarray, centre: np.ndarray, up: np.ndarray, zenith_deg: float = 20.0,
               ring_deg: float = 20.0) -> np.ndarray:
    """Azimuth steps of successive cameras about the vertical through the object centre.

    Parameters
    ----------
    poses : (N, 4, 4) camera-to-world [m]; NaN rows for views not placed
    centre : (3,) the object centre in the same frame [m]
    up : (3,) the vertical in the same frame (either sign)

    Returns
    -------
    (N - 1,) float64: the step from view k to k + 1 [deg], in (-180, 180]; NaN where either view is
    not placed, is zenithal, or the two are on different rings (module docstring)
    """
    up = np.asarray(up, np.float64)
    up = up / np.linalg.norm(up)
    c = np.asarray(poses, np.float64)[:, :3, 3] - np.asarray(centre, np.float64)
    h = np.einsum("ij,j->i", c, up)
    flat = c - h[:, None] * up
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    az = np.degrees(np.arctan2(flat @ e2, flat @ e1))
    el = np.degrees(np.arctan2(h, np.linalg.norm(flat, axis=1)))
    steps = (np.diff(az) + 180.0) % 360.0 - 180.0
    bad = ~np.isfinite(steps) | (np.abs(el[:-1]) > 90 - zenith_deg) | (np.abs(el[1:]) > 90 - zenith_deg) | \
        (np.abs(np.diff(el)) > ring_deg)
    steps[bad] = np.nan
    return steps


def path_anomalies(steps: np.ndarray, max_ratio: float = 3.0, min_steps: int = 3,
                   gaps: np.ndarray | None = None) -> list[int]:
    """Indices ``k`` of the steps (view k -> k + 1) that do not walk the path (module docstring).

    A step is an anomaly when it goes against the path's direction (the sign of its median step)
    by more than half the median step, or along it by more than ``max_ratio`` times the median
    step. ``gaps``: (N - 1,) how many scan steps each spans (views left out between), 1 if None;
    each step is taken per scan step. Fewer than ``min_steps`` steps with an azimuth: no verdict.
    """
    s = np.asarray(steps, np.float64)
    if gaps is not None:
        s = s / np.asarray(gaps, np.float64)
    ok = np.isfinite(s)
    if ok.sum() < min_steps:
        return []
    med = float(np.median(s[ok]))
    if abs(med) < 1e-6:
        return []
    a = s * np.sign(med) / abs(med)  # in units of the median step, along the path's direction
    return [int(k) for k in np.flatnonzero(ok & ((a < -0.5) | (a > max_ratio)))]


def path_frame(poses: np.ndarray, views: list[int], centres: np.ndarray,
               up: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
    """The object centre and the vertical of a set of placed views, in their common frame.

    Parameters
    ----------
    poses : (M, 4, 4) camera-to-world of the views ``views`` [m]
    views : their indices into ``centres``
    centres : (n, 3) object centre of each view, in its camera frame [m] (the mean of the views'
        object points: each is pulled toward its camera, the mean over the views is not)
    up : (3,) the vertical in the common frame (the support plane's normal); None or non-finite:
        the normal of the plane through the camera centres (a ring about the object)

    Returns
    -------
    (centre (3,), up (3,)), or None where there is no vertical (fewer than 3 cameras and none given)
    """
    P = np.asarray(poses, np.float64)
    c = np.mean([T[:3, :3] @ centres[v] + T[:3, 3] for T, v in zip(P, views)], axis=0)
    if up is None or not np.all(np.isfinite(up)):
        if len(P) < 3:
            return None
        cam = P[:, :3, 3] - P[:, :3, 3].mean(0)
        up = np.linalg.svd(cam, full_matrices=False)[2][-1]
    return c, np.asarray(up, np.float64)


def path_walk(poses: np.ndarray, views: list[int], centres: np.ndarray, up: np.ndarray | None,
              max_ratio: float) -> tuple[np.ndarray, list[int]]:
    """The azimuth steps of placed views in scan order and those that do not walk.

    Parameters
    ----------
    poses : (M, 4, 4) camera-to-world of the views ``views`` [m], in scan order (``views`` ascending)
    views, centres, up : as :func:`path_frame`
    max_ratio : :func:`path_anomalies`' leap bound (a step across views left out counts per scan step)

    Returns
    -------
    steps : (M - 1,) :func:`path_steps` [deg] (all NaN where there is no vertical)
    bad : :func:`path_anomalies` (indices into ``steps``)
    """
    frame = path_frame(poses, views, centres, up)
    if frame is None:
        return np.full(max(len(views) - 1, 0), np.nan), []
    steps = path_steps(poses, *frame)
    return steps, path_anomalies(steps, max_ratio, gaps=np.diff(views))


def closes_once(poses: np.ndarray, views: list[int], n_views: int, centres: np.ndarray, up: np.ndarray | None,
                max_ratio: float) -> bool:
    """Whether the placed cameras walk once around the object, back to the first: every step of the
    scan order and the closing step from the last view to the first walk (:func:`path_anomalies`),
    each has an azimuth, and together they turn by one full turn.

    Where a successive pair failed, the scan's closing pair (its last view and its first, registered
    as successive views, the path being a loop) is the only link between the two parts, and no loop
    verifies it. Matched wrongly, it cannot close the path this way: a scan that does not go round
    (a half arc whose ends a symmetric object matched) would have to leap where the pair failed.

    Parameters
    ----------
    poses : (M, 4, 4) camera-to-world of ``views`` [m], in scan order (``views`` ascending, the
        first and the last view of the scan among them)
    views : their indices in the scan; n_views : the scan's number of views
    centres, up : as :func:`path_frame`
    max_ratio : :func:`path_anomalies`' leap bound

    Returns
    -------
    bool
    """
    frame = path_frame(poses, views, centres, up)
    if frame is None or len(views) < 4:
        return False
    P = np.asarray(poses, np.float64)
    steps = path_steps(np.concatenate([P, P[:1]]), *frame)
    gaps = np.diff(list(views) + [views[0] + n_views])
    if not np.isfinite(steps).all() or path_anomalies(steps, max_ratio, gaps=gaps):
        return False
    return bool(abs(abs(float(steps.sum())) - 360.0) < 1.0)
