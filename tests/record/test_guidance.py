"""The guidance functions on plain arrays (no device)."""

from __future__ import annotations

import numpy as np

from tofmetry.record import guidance as G
from tofmetry.sensor import KINECT_V2


def _plane_depth(distance_mm: float, yaw_deg: float = 0.0) -> np.ndarray:
    """Z [mm] of a plane at ``distance_mm`` on the axis, rotated by ``yaw_deg`` about the vertical."""
    intr = KINECT_V2.depth
    vv, uu = np.mgrid[0:intr.height, 0:intr.width]
    x = (uu - intr.cx) / intr.fx
    n = np.array([np.sin(np.radians(yaw_deg)), 0.0, -np.cos(np.radians(yaw_deg))])   # toward the camera
    z = -distance_mm * n[2] / (-(n[0] * x) - n[2])                                    # n.p = n.(0,0,d)
    return np.rint(z).astype(np.uint16)


def test_wall_check_square_and_tilted():
    intr = KINECT_V2.depth
    ok = G.wall_check(_plane_depth(1500.0), intr)
    assert ok.ok and ok.fill > 0.99 and abs(ok.yaw_deg) < 0.1 and abs(ok.distance_mm - 1500) < 2
    bad = G.wall_check(_plane_depth(1500.0, 5.0), intr)
    assert not bad.ok and abs(abs(bad.yaw_deg) - 5.0) < 0.2
    assert any("vertical axis" in m for m in bad.messages)
    holed = _plane_depth(1500.0)
    holed[:, :200] = 0                                   # the wall fills only part of the view
    h = G.wall_check(holed, intr)
    assert not h.ok and h.fill < 0.7 and any("fills" in m for m in h.messages)


def test_warmup_status_stops_only_when_settled():
    t = np.arange(0, 3600.0, 15.0)
    drift = 5.0 * (1 - np.exp(-t / 600.0))               # settles with tau 10 min
    early = G.warmup_status(t[:40], drift[:40])
    assert not early.stable
    late = G.warmup_status(t, drift)
    assert late.stable and late.window_range_mm <= 1.0
    flat = G.warmup_status(t[:41], np.full(41, 1000.0))   # exactly 10 min of a warm sensor
    assert flat.stable


def test_board_cells_and_missing_description():
    depth = np.full((424, 512), 700, np.uint16)
    mask = np.zeros((424, 512), bool)
    mask[10:100, 10:100] = True                          # top-left region only
    c = G.board_cells(mask, depth, (3, 3), [500, 800, 1100])
    assert c.shape == (3, 3, 2) and c[0, 0, 0] == 90 * 90 and c.sum() == 90 * 90
    miss = G.missing_cells(c, 200)
    assert (0, 0, 0) not in miss and len(miss) == 17
    text = G.describe_cells(miss, (3, 3), [500, 800, 1100])
    assert text.startswith("at 0.50–0.80 m: top, top-right") and "at 0.80–1.10 m: top-left" in text


def test_view_overlap_of_shifted_clouds():
    # a wavy surface seen twice, the second view shifted by 0.2 m: half of it overlaps
    x, y = np.meshgrid(np.linspace(-0.2, 0.4, 121), np.linspace(-0.2, 0.2, 81))
    w = np.column_stack([x.ravel(), y.ravel(), 1.0 + 0.03 * np.sin(15 * x.ravel()) * np.cos(12 * y.ravel())])
    a = w[w[:, 0] <= 0.2 + 1e-9]                             # first camera: x in [-0.2, 0.2]
    b = w[w[:, 0] >= -1e-9] - [0.2, 0.0, 0.0]                # second camera, moved 0.2 m: x in [0, 0.4]
    init = np.eye(4)
    init[0, 3] = 0.2 + 0.004                                # the planned move, 4 mm off
    ov, T, rmse = G.view_overlap(b, a, init, 0.01)
    assert 0.45 < ov < 0.56 and abs(T[0, 3] - 0.2) < 1e-3 and rmse < 1.0
    ov2, _, _ = G.view_overlap(a, a, np.eye(4), 0.01)
    assert ov2 > 0.99
