"""Which support points the support curve reads (tofmetry.reconstruct._support_curve.support_samples).

A floor seen by a camera pitched down 30 deg from 0.5 m, an upright box standing on it in the image's middle
columns: with ``columns`` only the floor's points in the box's own columns (widened by that much) are kept, over
the floor's whole span of depths; without, the whole floor less the box and its surroundings.
"""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct._preprocess import ViewData
from tofmetry.reconstruct._segment import Segmentation
from tofmetry.reconstruct._support_curve import support_samples
from tofmetry.sensor import CameraIntrinsics

INTR = CameraIntrinsics(512, 424, 365.0, 365.0, 256.0, 212.0)


def floor_and_box() -> tuple[ViewData, Segmentation]:
    H, W = INTR.shape
    rays = INTR.ray_table(True).reshape(-1, 2)
    t = np.radians(30.0)
    up = np.array([0.0, -np.cos(t), -np.sin(t)])  # world up in the camera frame
    h = 0.5
    den = -(np.c_[rays, np.ones(len(rays))] @ up)
    z = np.where(den > 1e-6, h / np.maximum(den, 1e-6), np.inf)
    floor = (z > 0.4) & (z < 2.0)
    box = (np.abs(rays[:, 0]) < 0.08) & (rays[:, 1] > -0.1) & (rays[:, 1] < 0.05)  # in front of the floor there
    z = np.where(box, 0.9, z)
    keep = floor | box
    index = np.nonzero(keep)[0]
    pts = np.c_[rays[index], np.ones(len(index))] * z[index, None]
    depth = np.zeros(H * W)
    depth[index] = z[index] * 1e3
    n = len(index)
    view = ViewData("00", depth.reshape(H, W), pts, index, np.tile(-up, (n, 1)), np.ones(n), None, {})
    obj = box[index]
    seg = Segmentation(obj, ~obj, None, np.r_[up, h], 0.9)
    return view, seg


def test_the_columns_keep_the_floor_below_the_object_over_its_whole_span():
    view, seg = floor_and_box()
    z_all, xy_all = support_samples([view], [seg], INTR, 0.01, 12.0)
    z_col, xy_col = support_samples([view], [seg], INTR, 0.01, 12.0, columns=0.05)
    x_obj = INTR.ray_table(True).reshape(-1, 2)[view.index[seg.object_mask], 0]
    lo, hi = np.percentile(x_obj, [5, 95])
    assert np.all((xy_col[0][:, 0] > lo - 0.05) & (xy_col[0][:, 0] < hi + 0.05))
    assert len(z_col[0]) < 0.5 * len(z_all[0])
    # the floor's depths on both sides of the object: the same span (within one row's depth step at the far end)
    assert z_col[0].min() <= z_all[0].min() + 5.0 and z_col[0].max() >= 0.97 * z_all[0].max()
    assert np.max(np.abs(xy_all[0][:, 0])) > 0.5
