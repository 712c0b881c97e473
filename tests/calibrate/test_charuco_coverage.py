"""The image-corner coverage of ChArUco sets is judged on the corners actually detected.

A ChArUco board pushed past an image corner gives only the corners whose four neighbouring
squares are in the image (their markers must be decoded), so its detected corners stop about a
square from the border: they lie in the image-corner region (10 % of width and height), while
the hull of the view's corners, cut there, covers only a sliver of it. The lens is measured there
all the same: no warning. Where no view's corners reach a region, the warning names it.

Views: the virtual sensor's ChArUco poses (aimed at the centre, corners and edges, overhanging)
of the default 13 x 10 board on the Kinect v2 lens; a corner counts as detected when its four
neighbouring squares project inside the image; 0.03 px of corner noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.calibrate import CharucoBoard, calibrate_intrinsics
from tofmetry.sensor import KINECT_V2
from tofmetry.simulate.poses import charuco_poses

BOARD = CharucoBoard(13, 10, 80.0, 56.0, "DICT_4X4_100")
LENS = KINECT_V2.depth
REGIONS = ["top-left", "top-right", "bottom-left", "bottom-right"]


def _detected(T: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
    """(corners [px], object points [mm]) a ChArUco detector finds in the view of pose ``T`` [m]."""
    obj = BOARD.object_points() / 1000.0
    s = BOARD.square_mm / 1000.0
    ok = np.ones(len(obj), bool)
    for dx in (-s, s):
        for dy in (-s, s):
            q = LENS.project((obj + [dx, dy, 0.0]) @ T[:3, :3].T + T[:3, 3])
            ok &= (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] <= LENS.width - 1) & (q[:, 1] <= LENS.height - 1)
    c = LENS.project(obj[ok] @ T[:3, :3].T + T[:3, 3])
    return c + rng.normal(0.0, 0.03, c.shape), obj[ok] * 1000.0


@pytest.fixture(scope="module")
def views():
    rng = np.random.default_rng(2)
    poses = charuco_poses(18, LENS, 13 * 0.08, 10 * 0.08, rng, dist_range=(0.7, 1.2))
    return [_detected(T, rng) for T in poses]


def _calibrate(views):
    cs, objs = [v[0] for v in views], [v[1] for v in views]
    return calibrate_intrinsics(cs, None, BOARD.inner, BOARD.square_mm, (LENS.width, LENS.height),
                                leave_one_out=False, object_points=objs)


def test_partial_views_reaching_the_corners_are_not_warned(views):
    assert sum(len(c) < BOARD.n_corners for c, _ in views) >= 12          # mostly partial views
    res = _calibrate(views)
    # every region holds detected corners, while no view's hull covers 10 % of any of them (the
    # hull criterion alone would have warned for all four)
    assert all(res.corner_regions_corners[k] >= 1 for k in REGIONS), res.corner_regions_corners
    assert all(res.corner_regions_coverage[k] < 0.1 for k in REGIONS), res.corner_regions_coverage
    assert res.uncovered_corners == []
    assert not any("no board reached" in w for w in res.warnings), res.warnings
    assert res.to_dict(with_map=False)["corner_regions"]["detected_corners"] == res.corner_regions_corners


def test_corners_no_view_reached_are_warned(views):
    res0 = _calibrate(views)
    gone = ["top-left", "bottom-right"]
    # leave out every view with a corner in those two regions
    keep = [v for v in views if not any(_in_region(v[0], k) for k in gone)]
    assert len(keep) >= 8
    res = _calibrate(keep)
    assert res.uncovered_corners == gone
    w = [x for x in res.warnings if "no board reached" in x]
    assert len(w) == 1 and "top-left, bottom-right" in w[0]
    # the regions still reached are not named; the extrapolated corners are predicted worse than before
    assert all(res.corner_regions_corners[k] >= 1 for k in ("top-right", "bottom-left"))
    pr, pr0 = res.predicted_ray, res0.predicted_ray
    assert all(pr.per_corner_max_px[k] > pr0.per_corner_max_px[k] for k in gone)


def _in_region(c: np.ndarray, name: str) -> bool:
    from tofmetry.calibrate._ray_error import corner_regions

    return bool(corner_regions(c[:, 0], c[:, 1], LENS.width, LENS.height)[name].any())
