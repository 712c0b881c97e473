"""The dark blobs a view sees on its mat, filled and checked all at once, as one by one."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from tofmetry.reconstruct._mat_dots import _filled_blobs


def _speckled(rng: np.random.Generator, shape=(90, 110)) -> np.ndarray:
    """Dark dots, rings (with a dot inside some), pairs of arcs closing a patch between them, and
    noise, some touching the image's border."""
    H, W = shape
    v, u = np.mgrid[:H, :W]
    dark = rng.random(shape) < 0.04
    for _ in range(14):
        cu, cv, r = rng.uniform(-3, W + 3), rng.uniform(-3, H + 3), rng.uniform(1.5, 7.0)
        d = np.hypot(u - cu, v - cv)
        kind = rng.integers(4)
        if kind == 0:  # a dot, with holes where the depth is missing
            dark |= (d <= r) & (rng.random(shape) > 0.15)
        elif kind == 1:  # a ring
            dark |= np.abs(d - r) <= 0.8
        elif kind == 2:  # a ring with a dot inside
            dark |= (np.abs(d - r - 2.5) <= 0.8) | (d <= r - 1.0)
        else:  # two arcs that together close a patch: neither alone does
            a = np.arctan2(v - cv, u - cu)
            ring = np.abs(d - r - 1.0) <= 0.8
            dark |= ring & (a > 0.15) & (a < np.pi - 0.15)
            dark |= ring & (a < -0.15) & (a > -np.pi + 0.15)
    return dark


def test_the_blobs_filled_at_once_are_those_filled_one_by_one():
    """Where a blob's holes are its alone, they are what scipy's fill gives on the blob by itself;
    the others (a patch next to more than one blob) are left to be filled one by one."""
    rng = np.random.default_rng(5)
    tested = left = 0
    for _ in range(40):
        dark = _speckled(rng)
        lab, n = ndimage.label(dark)
        filled, alone = _filled_blobs(dark, lab, n)
        assert filled.shape == dark.shape and alone.shape == (n + 1,)
        np.testing.assert_array_equal(filled[dark], lab[dark])  # a dark pixel keeps its own blob
        for k, sl in enumerate(ndimage.find_objects(lab), start=1):
            r0, r1 = max(sl[0].start - 1, 0), min(sl[0].stop + 1, dark.shape[0])
            c0, c1 = max(sl[1].start - 1, 0), min(sl[1].stop + 1, dark.shape[1])
            if r0 == 0 or c0 == 0 or r1 == dark.shape[0] or c1 == dark.shape[1]:
                continue  # seen_dots leaves a blob at the image's border out
            one = ndimage.binary_fill_holes(lab[r0:r1, c0:c1] == k)
            if alone[k]:
                np.testing.assert_array_equal(filled[r0:r1, c0:c1] == k, one)
                assert (filled == k).sum() == one.sum()  # and nothing of it outside that window
                tested += 1
            else:
                left += 1
    assert tested > 300 and left > 10  # both kinds were met
