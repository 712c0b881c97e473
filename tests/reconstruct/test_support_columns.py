"""Which support points the support curve reads (tofmetry.reconstruct._support_curve.support_samples).

A floor seen by a camera pitched down 30 deg from 0.5 m, an upright box standing on it in the image's middle
columns: with ``columns`` only the floor's points in the box's own columns (widened by that much) are kept, over
the floor's whole span of depths; without, the whole floor less the box and its surroundings.
"""

from __future__ import annotations

import numpy as np

from tests.reconstruct.floor_scenes import INTR, floor_and_box
from tofmetry.reconstruct._support_curve import support_samples


def test_the_columns_keep_the_floor_below_the_object_over_its_whole_span():
    view, seg = floor_and_box(0.5, 30.0, 0.08, (-0.1, 0.05), 0.9, 0.4)  # the box in front of the floor there
    z_all, xy_all = support_samples([view], [seg], INTR, 0.01, 12.0)
    z_col, xy_col = support_samples([view], [seg], INTR, 0.01, 12.0, columns=0.05)
    x_obj = INTR.ray_table(True).reshape(-1, 2)[view.index[seg.object_mask], 0]
    lo, hi = np.percentile(x_obj, [5, 95])
    assert np.all((xy_col[0][:, 0] > lo - 0.05) & (xy_col[0][:, 0] < hi + 0.05))
    assert len(z_col[0]) < 0.5 * len(z_all[0])
    # the floor's depths on both sides of the object: the same span (within one row's depth step at the far end)
    assert z_col[0].min() <= z_all[0].min() + 5.0 and z_col[0].max() >= 0.97 * z_all[0].max()
    assert np.max(np.abs(xy_all[0][:, 0])) > 0.5
