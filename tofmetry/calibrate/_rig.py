"""Rig calibration: the extrinsics of two or more sensors that see a common board.

Sensor 0 is the rig frame. Each other sensor is calibrated against it from the views where both
see the whole board, or for an identified (ChArUco) board the corners both detected (:func:`~tofmetry.calibrate.calibrate_stereo`, intrinsics held fixed), with
its jackknife uncertainty and held-out validation; the transform of a point from the rig frame to
sensor ``i`` is ``p_i = R_i p_0 + t_i``. Clouds of sensor ``i`` go into the rig frame with
``extrinsics[i].inverse().apply(points)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofmetry.calibrate._stereo import StereoResult, calibrate_stereo, common_corners
from tofmetry.errors import InputError
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics


@dataclass
class RigResult:
    """Extrinsics of every sensor of a rig.

    Attributes
    ----------
    extrinsics : list of Extrinsics, rig frame (sensor 0) -> sensor ``i`` [m]; identity for 0
    pairs : list of StereoResult (None for sensor 0): residuals, uncertainty, held-out error of each
    shared_views : list of int, views each sensor shares with sensor 0
    """

    extrinsics: list
    pairs: list
    shared_views: list

    def to_rig(self, i: int, points: np.ndarray) -> np.ndarray:
        """(N, 3) points of sensor ``i`` [m] -> the rig frame (sensor 0) [m]."""
        return self.extrinsics[i].inverse().apply(points)

    def to_dict(self) -> dict:
        return {"extrinsics": [e.to_dict() for e in self.extrinsics],
                "pairs": [None if p is None else p.to_dict() for p in self.pairs],
                "shared_views": self.shared_views}


def calibrate_rig(obj_points: list, corners: list, intrinsics: list[CameraIntrinsics], ids: list | None = None,
                  min_common: int = 6) -> RigResult:
    """Extrinsics of ``S >= 2`` sensors from board views they share.

    Parameters
    ----------
    obj_points : list over views of (N_v, 3) board corners [mm]; with ``ids``: of the board's
        corners indexed by id, (N_board, 3) [mm]
    corners : list over sensors of lists over views of (N_v, 2) corners [px], or None where that
        sensor did not see the whole board (with ``ids``: enough of it) in that view
    intrinsics : list over sensors of CameraIntrinsics (held fixed)
    ids : optional, list over sensors of lists over views of (N_sv,) int corner ids (ChArUco:
        partial views): sensor ``i`` and sensor 0 are then calibrated from the corners both found
        (:func:`~tofmetry.calibrate._stereo.common_corners`), each pair with its own object points
    min_common : with ``ids``, a view counts as shared when at least this many corners are common

    Returns
    -------
    RigResult

    Raises
    ------
    InputError
        Fewer than 2 sensors, lists of different lengths, or a sensor sharing fewer than 3 views
        with sensor 0.
    """
    S, V = len(intrinsics), len(obj_points)
    if S < 2:
        raise InputError(f"calibrate_rig: need at least 2 sensors, found {S}")
    if len(corners) != S or any(len(c) != V for c in corners):
        raise InputError(f"calibrate_rig: expected corners for {S} sensors x {V} views, "
                         f"found {[len(c) for c in corners]} views for {len(corners)} sensors")
    if ids is not None and (len(ids) != S or any(len(x) != V for x in ids)):
        raise InputError(f"calibrate_rig: expected corner ids for {S} sensors x {V} views, "
                         f"found {[len(x) for x in ids]} views for {len(ids)} sensors")
    exts: list = [Extrinsics.identity("sensor0", "sensor0")]
    pairs: list = [None]
    shared = [sum(c is not None for c in corners[0])]
    for i in range(1, S):
        views = [v for v in range(V) if corners[0][v] is not None and corners[i][v] is not None]
        O, A, B = [np.asarray(obj_points[v]) for v in views], [corners[0][v] for v in views], \
            [corners[i][v] for v in views]
        if ids is not None:
            O, A, B, keep = [], [], [], []
            for v in views:
                k, a, b = common_corners(ids[0][v], corners[0][v], ids[i][v], corners[i][v])
                if len(k) >= min_common:
                    O.append(np.asarray(obj_points[v], np.float64)[k])
                    A.append(a)
                    B.append(b)
                    keep.append(v)
            views = keep
        if len(views) < 3:
            raise InputError(f"calibrate_rig: sensor {i} shares {len(views)} board views with sensor 0; need at least 3")
        res: StereoResult = calibrate_stereo(O, A, B, intrinsics[0], intrinsics[i])
        e = res.extrinsics
        exts.append(Extrinsics(e.rotation, e.translation, "sensor0", f"sensor{i}"))
        pairs.append(res)
        shared.append(len(views))
    return RigResult(exts, pairs, shared)
