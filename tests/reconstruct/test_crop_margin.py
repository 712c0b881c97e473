"""The crop to the object's points keeps a surface one view sees obliquely from afar: its margin grows
with the pixel footprint."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import open3d as o3d

from tests.reconstruct.test_fusion_noise import INTR, RAYS
from tofmetry.reconstruct import ReconstructionConfig
from tofmetry.reconstruct._model_build import crop_mask, crop_model, fuse_views
from tofmetry.reconstruct._pipeline import _no_progress

RANGE_M, INCIDENCE_DEG, HALF_PX = 1.3, 65.0, 20


def oblique_view() -> tuple[list, list, np.ndarray, np.ndarray]:
    """One view (camera = world) of a plane through (0, 0, 1.3 m) turned 65 deg about y, exact depth,
    on a 41 x 41 pixel window at the image's centre: (views, segmentations, poses, the plane's normal)."""
    a = np.radians(INCIDENCE_DEG)
    n = np.array([np.sin(a), 0.0, -np.cos(a)])
    p0 = np.array([0.0, 0.0, RANGE_M])
    z = (n @ p0) / (RAYS @ n)  # Z of each pixel's ray (x, y, 1) on the plane [m]
    v0, u0 = INTR.height // 2, INTR.width // 2
    win = np.zeros(z.shape, bool)
    win[v0 - HALF_PX:v0 + HALF_PX + 1, u0 - HALF_PX:u0 + HALF_PX + 1] = True
    depth = np.where(win, z * 1e3, 0.0)
    m = depth > 0
    cos_i = np.abs(RAYS[m] @ n) / np.linalg.norm(RAYS[m], axis=1)
    view = SimpleNamespace(depth_mm=depth, points=RAYS[m] * depth[m, None] * 1e-3, index=np.flatnonzero(m),
                           cos_incidence=cos_i)
    seg = SimpleNamespace(object_mask=np.ones(m.sum(), bool), ring_mask=np.zeros(m.sum(), bool))
    return [view], [seg], np.eye(4)[None], n


def covered(V: np.ndarray, F: np.ndarray, samples: np.ndarray) -> float:
    """Share of ``samples`` (N, 3) [m] within 1 mm of the mesh (V, F)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    return float((scene.compute_distance(o3d.core.Tensor(samples.astype(np.float32))).numpy() < 1e-3).mean())


def test_the_crop_margin_follows_the_pixel_footprint():
    """At 1.3 m a pixel spans 3.6 mm, and on a surface seen at 65 deg the view's points lie 8.4 mm apart
    along the slope: the fused mesh between them lies up to 0.5 sqrt(1 + 1 / cos^2 65) = 1.29
    footprints (4.6 mm) from the nearest point, beyond the 4 mm floor. With the margin of 1.6 footprints
    the crop takes nothing of the fused surface inside the window; with 4 mm alone it cuts holes in it
    (measured: 0.727 of the samples between the points within 1 mm of the fused surface, cropped or
    not; 0.398 with the floor. The single view's surface itself misses some at this incidence)."""
    cfg = ReconstructionConfig()
    views, segs, poses, _ = oblique_view()
    V, F, N, P, PN, info = fuse_views(views, segs, poses, INTR, cfg, _no_progress)
    footprint_mm = info["median_object_depth_mm"] / INTR.fx
    assert np.isclose(info["crop_margin_mm"], cfg.fusion.crop_margin_px * footprint_mm)
    assert info["crop_margin_mm"] > cfg.fusion.crop_margin_mm
    # the inside of the window: the view's points four pixels or more from its border
    z = views[0].depth_mm
    inner = np.zeros(z.shape, bool)
    v0, u0 = INTR.height // 2, INTR.width // 2
    k = HALF_PX - 4
    inner[v0 - k:v0 + k + 1, u0 - k:u0 + k + 1] = True
    # samples between the points: the midpoints of each pixel's 2 x 2 neighbourhood on the plane
    pts = RAYS * z[..., None] * 1e-3
    mid = 0.25 * (pts[:-1, :-1] + pts[1:, :-1] + pts[:-1, 1:] + pts[1:, 1:])[inner[:-1, :-1]]
    whole = covered(V, F, mid)
    kept = crop_model(V, F, N, P, PN, views[0].points, None, cfg, info["crop_margin_mm"])
    floor = crop_model(V, F, N, P, PN, views[0].points, None, cfg, cfg.fusion.crop_margin_mm)
    assert covered(kept[0], kept[1], mid) == whole > 0.5
    assert covered(floor[0], floor[1], mid) < whole - 0.2


def test_the_margin_is_the_floor_where_pixels_are_small():
    """At 0.6 m (1.6 mm pixels) 1.6 footprints are 2.6 mm: the 4 mm floor holds (the points' noise)."""
    fc = ReconstructionConfig().fusion
    assert fc.crop_margin_for(600.0, INTR.fx) == fc.crop_margin_mm
    assert np.isclose(fc.crop_margin_for(1300.0, INTR.fx), fc.crop_margin_px * 1300.0 / INTR.fx)


def test_the_wider_margin_keeps_off_the_ground_and_off_the_normal():
    """Object points on the plane x = 0 (a 28 mm square). A vertex 5 mm beyond their edge on that plane
    is kept with a 6 mm margin (not with the 4 mm floor); one 5 mm off the plane along its normal is
    not; nor one 5 mm beyond the edge but 10 mm above the ground, lower than the segmentation's
    minimum height (5 mm) plus the margin, where the fused ground ring meets the object."""
    cfg = ReconstructionConfig()
    g = np.arange(0.0, 0.0281, 0.002)
    yz = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    ground = np.array([0.0, 0.0, 1.0, 0.0])
    normal = np.array([[1.0, 0.0, 0.0]])

    def kept(vertex, low: float, margin):
        obj = np.c_[np.zeros(len(yz)), yz[:, 0], yz[:, 1] + low]  # the square from ``low`` [m] up
        return bool(crop_mask(np.array([vertex]), obj, ground, cfg, margin, normal)[0])

    assert kept([0.0, 0.033, 0.035], 0.02, 6.0)  # beside the points, 35 mm high
    assert not kept([0.0, 0.033, 0.035], 0.02, None)  # the floor alone
    assert not kept([0.005, 0.015, 0.035], 0.02, 6.0)  # off their plane
    assert not kept([0.0, 0.033, 0.010], 0.005, 6.0)  # beside them, 10 mm above the ground
