"""A rig of 3 random virtual sensors around a common board: geometry -> corners projected through
each sensor's true lens with 0.1 px noise -> ``calibrate_rig`` -> every sensor's extrinsics within
1 mm / 0.1° of the truth, and a point seen by two sensors lands on itself in the rig frame."""

from __future__ import annotations

import numpy as np
import pytest

from tests.calibrate.test_stereo import BOARD, SQUARE_MM, rotation_error_deg
from tofmetry.calibrate import board_object_points, calibrate_rig
from tofmetry.errors import InputError
from tofmetry.sensor import KINECT_V2, Extrinsics
from tofmetry.simulate.scenes import rotation_xyz


def _rig(seed: int):
    rng = np.random.default_rng(seed)
    d = KINECT_V2.depth
    intr = [d.with_(fx=d.fx + rng.normal(0, 3), fy=d.fy + rng.normal(0, 3), cx=d.cx + rng.normal(0, 2))
            for _ in range(3)]
    # sensors 0.4 m apart on an arc, each turned towards a point 1.5 m ahead of sensor 0
    exts = [Extrinsics.identity("sensor0", "sensor0")]
    for i, x in ((1, -0.4), (2, 0.4)):
        yaw = np.degrees(np.arctan2(x, 1.5)) + rng.normal(0, 2)
        R = rotation_xyz(rng.normal(0, 2), yaw, rng.normal(0, 2))  # sensor0 -> sensor i rotation
        c = np.array([x, rng.normal(0, 0.05), rng.normal(0, 0.05)])  # sensor i's centre in sensor 0
        exts.append(Extrinsics(R, -R @ c, "sensor0", f"sensor{i}"))
    return intr, exts


def _views(intr, exts, n, rng, noise_px=0.1):
    obj = board_object_points(BOARD, SQUARE_MM)
    centre = obj.mean(axis=0)
    O, C = [], [[] for _ in intr]
    while len(O) < n:
        R = rotation_xyz(*rng.uniform(-25, 25, 2), rng.uniform(-15, 15))
        t = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.15, 0.15), rng.uniform(1.2, 1.8)]) * 1e3
        p0 = (obj - centre) @ R.T + t
        uvs = [k.project(e.apply(p0 * 1e-3)) for k, e in zip(intr, exts)]
        ok = [((uv[:, 0] > 5) & (uv[:, 0] < k.width - 5) & (uv[:, 1] > 5) & (uv[:, 1] < k.height - 5)).all()
              for uv, k in zip(uvs, intr)]
        if not all(ok):
            continue
        O.append(obj)
        for s, uv in enumerate(uvs):
            C[s].append(uv + rng.normal(0, noise_px, uv.shape))
    return O, C


@pytest.mark.parametrize("seed", [0, 1])
def test_rig_of_three_sensors_within_1mm_and_0_1deg(seed):
    intr, truth = _rig(seed)
    obj, corners = _views(intr, truth, 20, np.random.default_rng(50 + seed))
    corners[2][0] = None  # sensor 2 missed the board once: that view is not shared
    res = calibrate_rig(obj, corners, intr)
    assert res.shared_views == [20, 20, 19]
    for i in (1, 2):
        e = res.extrinsics[i]
        dt_mm = np.linalg.norm(e.translation - truth[i].translation) * 1e3
        dr = rotation_error_deg(e.rotation, truth[i].rotation)
        assert dt_mm < 1.0 and dr < 0.1, (i, dt_mm, dr)
        assert res.pairs[i].heldout_rms_px < 0.5
    # fusion in the rig frame: the same world point seen by sensor 2 maps back onto itself
    p0 = np.array([[0.1, -0.05, 1.5]])
    back = res.to_rig(2, truth[2].apply(p0))
    assert np.linalg.norm(back - p0) * 1e3 < 1.5


def test_rig_needs_shared_views():
    intr, truth = _rig(0)
    obj, corners = _views(intr, truth, 4, np.random.default_rng(0))
    corners[1][:2] = [None, None]
    with pytest.raises(InputError, match="sensor 1 shares 2"):
        calibrate_rig(obj, corners, intr)
    with pytest.raises(InputError, match="at least 2 sensors"):
        calibrate_rig(obj, corners[:1], intr[:1])
