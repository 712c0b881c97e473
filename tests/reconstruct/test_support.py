"""The support surface as measured: a table whose depth bends out of the plane's tolerance stays table."""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct import SegmentConfig, segment_object
from tofmetry.reconstruct._support import support_region

H, W, F = 160, 200, 365.0  # ~2.2 mm pixels at 0.8 m, as a Kinect v2


def _table_view(bend_mm: float, rng):
    """A camera 0.8 m from a table, looking down 35 deg; the table's depth reads up to ``bend_mm``
    short toward the bottom rows (near range), so it rises out of the plane's tolerance there; a
    10 mm flat tile and a 60 mm block stand on it."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    rays = np.stack([(u - W / 2) / F, (v - H / 2) / F, np.ones_like(u)], -1).reshape(-1, 3)
    tilt = np.radians(35.0)
    n = np.array([0.0, -np.cos(tilt), -np.sin(tilt)])  # table normal toward the camera (camera y down)
    d = -n @ np.array([0.0, 0.0, 0.8])  # through the point 0.8 m along the optical axis
    t = -d / (rays @ n)
    p = rays * t[:, None]
    row = np.repeat(np.arange(H), W)
    bend = bend_mm * 1e-3 * np.clip((row - 0.7 * H) / (0.3 * H), 0, 1) ** 2  # bottom 30 % of the image
    p = p * (1 - bend / p[:, 2])[:, None]  # read short along the rays: the table rises out of the plane
    p = p + rng.normal(0, 0.3e-3, p.shape)
    nrm = np.tile(n, (len(p), 1))
    col = np.tile(np.arange(W), H)
    tile = (row > 20) & (row < 40) & (col > 20) & (col < 60)
    block = (row > 70) & (row < 115) & (col > 80) & (col < 120)
    p[tile] += 0.010 * n
    p[block] += 0.060 * n
    nrm[block] = [0.0, np.sin(tilt), -np.cos(tilt)]  # a vertical flank facing the camera
    return p, nrm, np.arange(H * W), tile, block, np.r_[n, d], bend > 8e-3


def test_a_bent_table_is_support_and_what_stands_on_it_is_not():
    rng = np.random.default_rng(1)
    p, nrm, idx, tile, block, plane, bent = _table_view(20.0, rng)
    assert bent.sum() > 1000  # the table reads more than the plane's 6 mm off there
    sup = support_region(p, nrm, idx, (H, W), plane, 6e-3, band_m=0.03)
    assert sup[bent].mean() > 0.99
    assert not sup[tile].any() and not sup[block].any()  # cut off by the 10 mm step and the flank


def test_segmentation_keeps_the_bent_table_out_of_the_object():
    """Without the normals and the image grid the bent band stands on the plane and joins the
    block (measured: 83 % of it); with them none of it does and the block stays whole."""
    rng = np.random.default_rng(2)
    p, nrm, idx, tile, block, plane, bent = _table_view(20.0, rng)
    cfg = SegmentConfig(cluster_eps_mm=12.0)
    plain = segment_object(p, cfg)
    assert plain.object_mask[bent].mean() > 0.5
    seg = segment_object(p, cfg, normals=nrm, grid=(idx, (H, W)))
    assert not seg.object_mask[bent].any()
    assert seg.object_mask[block].mean() > 0.9
