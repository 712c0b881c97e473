"""The printed dot mat: its layout is the seed's, its description round-trips, its image is the layout."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry._shared.dot_mat import DotMat, dot_mask, dot_mat_image
from tofmetry.errors import InputError


def test_the_layout_is_the_seeds_and_covers_what_it_says():
    a, b = DotMat(seed=3), DotMat(seed=3, yaw_deg=40.0)
    ca, ra = a.dots()
    cb, rb = b.dots()
    np.testing.assert_array_equal(ca, cb)  # the yaw is where it lies, not what is printed
    np.testing.assert_array_equal(ra, rb)
    assert not np.array_equal(ca, DotMat(seed=4).dots()[0])
    w, h = a.size_m
    assert np.all(np.abs(ca) <= [w / 2, h / 2]) and np.all((ra >= 0.008) & (ra <= 0.025))
    # dots dropped at random cover 1 - exp(-cover) of the sheet (they overlap)
    img = dot_mat_image(a, dpi=60)
    assert abs((img == 0).mean() - (1 - np.exp(-a.cover))) < 0.05


def test_description_round_trips_and_bad_ones_say_what_is_wrong():
    m = DotMat(seed=7, size_m=(0.42, 0.594), yaw_deg=12.5)
    assert DotMat.from_dict(m.to_dict()) == m
    with pytest.raises(InputError, match="unknown dot-mat field"):
        DotMat.from_dict({"seed": 1, "colour": "red"}, "mat.json")
    with pytest.raises(InputError, match="dot radii"):
        DotMat(dot_radius_m=(0.02, 0.01))


def test_the_mask_is_the_image():
    m = DotMat(seed=11, yaw_deg=30.0)
    img = dot_mat_image(m, dpi=100)  # rows from +v down, columns from -u
    px = 0.0254 / 100
    rng = np.random.default_rng(0)
    i, j = rng.integers(0, img.shape[0], 500), rng.integers(0, img.shape[1], 500)
    u = (j + 0.5) * px - m.size_m[0] / 2
    v = m.size_m[1] / 2 - (i + 0.5) * px
    a = np.radians(m.yaw_deg)  # sheet (u, v) -> world (x, y)
    x, y = np.cos(a) * u - np.sin(a) * v, np.sin(a) * u + np.cos(a) * v
    on, dot = dot_mask(m, x, y, pixel_m=px)
    assert on.all()
    assert (dot == (img[i, j] == 0)).mean() > 0.98  # cells on a dot's rim may fall either way


def test_overlapping_dots_are_those_whose_discs_meet():
    """Against every pair by brute force, on the default layout (a third of the sheet covered at
    random: most dots touch another) and on a sparse one."""
    for mat in (DotMat(seed=4), DotMat(seed=9, cover=0.05)):
        c, r = mat.dots()
        gap = np.linalg.norm(c[:, None] - c[None], axis=2) - r[:, None] - r[None]
        np.fill_diagonal(gap, np.inf)
        np.testing.assert_array_equal(mat.overlapping(), (gap < 0).any(1))
    assert 0 < DotMat(seed=9, cover=0.05).overlapping().mean() < DotMat(seed=4).overlapping().mean()
