"""The IR albedo chooses the yaw of two views of a surface of revolution (issue 16)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy.spatial import cKDTree

from tofmetry.reconstruct._photometric import ir_yaw_sweep, peak_lobe

R_M, AXIS_Z_M = 0.05, 1.0  # a cylinder of radius 50 mm about the vertical, its axis 1 m ahead


def _cylinder_view(rng, turn_deg: float, albedo, n: int = 4000):
    """Half a vertical cylinder seen by a camera turned by ``turn_deg`` about its axis (y down, z forward):
    points (camera frame) at azimuths within 80 deg of the camera's, with the log albedo ``albedo(azimuth_deg)``
    of the object's surface there (plus noise)."""
    phi = rng.uniform(-80.0, 80.0, n) + turn_deg  # object azimuth, deg
    local = np.radians(phi - turn_deg)
    h = rng.uniform(-0.1, 0.1, n)
    pts = np.c_[R_M * np.sin(local), h, AXIS_Z_M - R_M * np.cos(local)] + rng.normal(0, 0.0005, (n, 3))
    nrm = np.c_[np.sin(local), np.zeros(n), -np.cos(local)]
    return pts, nrm, albedo(phi) + rng.normal(0, 0.05, n)


def _views(rng, turn_deg, albedo):
    sp, _, si = _cylinder_view(rng, turn_deg, albedo)
    tp, tn, ti = _cylinder_view(rng, 0.0, albedo)
    src = SimpleNamespace(obj_points=sp, obj_ir=si)
    tgt = SimpleNamespace(icp_points=tp, icp_normals=tn, icp_ir=ti, tree=cKDTree(tp),
                          plane=np.array([0.0, -1.0, 0.0, 0.3]))  # the table: normal up (-y)
    return src, tgt


def _azimuth_error_deg(T, turn_deg):
    """Where T puts the source point facing its camera, as an object-azimuth error against the truth."""
    p = T[:3, :3] @ np.array([0.0, 0.0, AXIS_Z_M - R_M]) + T[:3, 3]
    got = np.degrees(np.arctan2(p[0], AXIS_Z_M - p[2]))
    return abs((got - turn_deg + 180.0) % 360.0 - 180.0)


def _blob(centre_deg, width_deg):
    return lambda phi: 0.6 * np.exp(-(((phi - centre_deg + 180.0) % 360.0 - 180.0) / width_deg) ** 2)


def test_wide_paint_blobs_decide_the_yaw_their_own_flank_is_not_a_rival():
    # three blobs 50 deg wide (two light, one dark): the correlation falls slowly on either side of
    # the right yaw, and 15-30 deg away it is still within 0.2 of the peak; that flank belongs to
    # the same peak, it is not another yaw the pattern allows (it left the yaw undecided before).
    # The peak is broad: the sweep's yaw is good to a few degrees, the ICP that follows refines it
    rng = np.random.default_rng(3)
    src, tgt = _views(rng, 40.0, lambda phi: _blob(0, 50)(phi) + 0.8 * _blob(70, 50)(phi) - 0.7 * _blob(-60, 50)(phi))
    out = ir_yaw_sweep(src, tgt, np.eye(4), 0.004)
    assert out["decided"] and out["correlation"] > 0.9, out
    assert _azimuth_error_deg(out["transform"], 40.0) < 5.0, out


def test_a_pattern_repeating_round_the_axis_leaves_two_candidates_for_the_loops():
    # a pattern repeating every half turn: the right yaw and the one half a turn away line it up
    # alike; the sweep stays undecided and hands both on as hypotheses for the views' loops
    rng = np.random.default_rng(4)
    src, tgt = _views(rng, 40.0, lambda phi: 0.6 * np.cos(np.radians(2.0 * phi)))
    out = ir_yaw_sweep(src, tgt, np.eye(4), 0.004)
    assert not out["decided"] and len(out["candidates"]) == 2, out
    errs = sorted(_azimuth_error_deg(T, 40.0) for T in out["candidates"])
    assert errs[0] < 1.5 and errs[1] > 150.0, (errs, out)  # the rival: near the other half turn


def test_peak_lobe_follows_the_slope_down_and_stops_where_another_peak_rises():
    sc = np.array([0.1, 0.3, 0.6, 0.9, 0.7, 0.5, 0.45, 0.46, 0.7, 0.8, 0.4, 0.2])
    lobe = peak_lobe(sc, 3, tol=0.02)
    assert lobe[[1, 2, 3, 4, 5, 6, 7]].all() and not lobe[8] and not lobe[9]
    # invalid samples (too few matches) end a side
    sc2 = sc.copy()
    sc2[1] = -1.0
    assert not peak_lobe(sc2, 3)[1] and not peak_lobe(sc2, 3)[0]
