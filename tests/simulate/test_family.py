"""The family of random sensors: deterministic draws within the documented ranges, plausible lenses."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.sensor import KINECT_V2, CameraIntrinsics
from tofmetry.simulate import ErrorModel, SensorDraw, default_sensor, random_sensor, scenes, station_tilts
from tofmetry.simulate.lens import REAL_KINECT_V2_IR, corner_rays, lens_check, random_intrinsics

SEEDS = range(40)
REAL_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kinect2-device-calibrations"


@pytest.fixture(scope="module")
def draws():
    return [random_sensor(s) for s in SEEDS]


def test_default_sensor_is_the_kinect_v2():
    d = default_sensor()
    assert d.kind == "kinect_v2" and d.seed is None
    assert d.errors == ErrorModel() and d.intrinsics == KINECT_V2.depth


def test_draws_deterministic_per_seed(draws):
    assert random_sensor(5) == draws[5]
    assert random_sensor(5).describe() == draws[5].describe()
    assert draws[5] != draws[6] and draws[5].intrinsics != draws[6].intrinsics
    with pytest.raises(InputError, match="seed"):
        random_sensor(-1)


def test_draws_within_the_documented_ranges(draws):
    for d in draws:
        i, em = d.intrinsics, d.errors
        assert (i.width, i.height) == (512, 424)
        assert abs(i.fx / 365.0 - 1) <= 0.05 and abs(i.fy / i.fx - 1) <= 0.01
        assert abs(i.cx - 255.5) <= 15 and abs(i.cy - 211.5) <= 15
        assert max(abs(i.distortion[2]), abs(i.distortion[3])) <= 2e-3
        assert 0.6 <= em.noise_sigma_mm <= 2.0 and 5.0 <= em.mounting_offset_mm <= 40.0
        assert 4.0 <= em.amp_bias_mm_per_ln <= 9.0 and 0.0 <= em.amp_bias_abs_mm_per_ln <= 3.0
        assert abs(em.wiggle_gain) <= 0.005 and 1 <= len(em.wiggle_periods_m) <= 3
        assert all(0.35 <= p <= 3.0 for p in em.wiggle_periods_m)
        assert 2.0 <= em.warmup_mm <= 8.0 and em.enabled == ErrorModel().enabled
        corner = d.describe()["deformation"]["corner_max_abs_mm_1m"]
        assert 3.0 - 1e-9 <= corner <= 15.0 + 1e-9
    desc = [d.describe() for d in draws]
    # every switch and shape is exercised by the family
    assert {(x["range_error"]["variable"], x["range_error"]["applied"]) for x in desc} == {
        ("radial", "ray"), ("radial", "z"), ("z", "ray"), ("z", "z")}
    assert {x["deformation"]["range_kind"] for x in desc} == {"linear", "constant", "decay", "quadratic"}
    assert set().union(*(x["deformation"]["kinds"] for x in desc)) == {"bowl", "tilt", "fourier", "bumps",
                                                                      "corner_falloff"}
    assert {len(x["range_error"]["components"]) for x in desc} == {1, 2, 3}
    signs = {np.sign(np.mean(x["deformation"]["corner_minus_centre_mm_1m"])) for x in desc}
    assert signs == {-1.0, 1.0}  # corners reading long and short


def test_lens_spread_covers_the_real_devices():
    rng = np.random.default_rng(0)
    k = np.array([random_intrinsics(rng).distortion for _ in range(300)])
    real = np.array(list(REAL_KINECT_V2_IR.values()))[:, 4:]  # k1, k2, p1, p2, k3
    for j in (0, 1, 4):  # k1, k2, k3: at least the real spread, k3 of either sign
        assert k[:, j].min() <= real[:, j].min() and k[:, j].max() >= real[:, j].max()
    assert k[:, 4].min() < 0 < k[:, 4].max()
    assert np.corrcoef(k[:, 1], k[:, 4])[0, 1] < -0.7  # k2 / k3 trade off as in the real devices


def test_real_calibrations_match_the_files():
    files = sorted(REAL_DIR.glob("*/calib_ir.yaml"))
    if not files:
        pytest.skip(f"real calibrations not found under {REAL_DIR}")
    from tofmetry.io.iai_kinect2 import read_calib_ir

    for f in files:
        i = read_calib_ir(f)
        np.testing.assert_allclose([i.fx, i.fy, i.cx, i.cy, *i.distortion], REAL_KINECT_V2_IR[f.parent.name], rtol=1e-5)


def test_lens_check_rejects_a_folding_lens():
    ok = {s: lens_check(CameraIntrinsics(512, 424, *v[:4], (v[4], v[5], v[6], v[7], v[8]))).ok
          for s, v in REAL_KINECT_V2_IR.items()}
    assert not ok.pop("307004735147")  # its radial map turns back before the corner
    assert all(ok.values()) and lens_check(KINECT_V2.depth).ok


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_drawn_lenses_invertible_over_the_whole_image(seed):
    intr = random_sensor(seed).intrinsics
    xy = np.asarray(intr.ray_table())
    u, v = np.meshgrid(np.arange(512.0), np.arange(424.0))
    back = intr.project(np.column_stack([xy.reshape(-1, 2), np.ones(xy.shape[0] * xy.shape[1])]))
    assert np.abs(back - np.column_stack([u.ravel(), v.ravel()])).max() < 1e-6
    assert np.all(np.diff(xy[..., 0], axis=1) > 0) and np.all(np.diff(xy[..., 1], axis=0) > 0)  # no fold
    np.testing.assert_allclose(corner_rays(intr), xy[[0, 0, -1, -1], [0, -1, 0, -1]], atol=1e-12)


def test_describe_and_record_json_round_trip(draws):
    for d in (default_sensor(), draws[3], draws[11]):
        rec = json.loads(json.dumps(d.to_dict()))
        assert SensorDraw.from_dict(rec) == d
        assert rec["describe"] == json.loads(json.dumps(d.describe()))
    assert default_sensor().describe()["range_error"]["components"][0]["amplitudes_mm"] == [4.5, 2.5, 0.8]


def test_station_tilts():
    t = station_tilts(200, 1.5, seed=3)
    assert t.shape == (200, 2)
    np.testing.assert_array_equal(t, station_tilts(200, 1.5, seed=3))
    assert not np.array_equal(t, station_tilts(200, 1.5, seed=4))
    angles = [math.degrees(math.acos(abs(scenes.wall(2.0, tuple(r)).info["plane_normal"][2]))) for r in t]
    assert max(angles) <= 1.5 + 1e-9 and max(angles) > 1.2 and min(angles) < 0.3
    np.testing.assert_array_equal(station_tilts(4, 0.0), np.zeros((4, 2)))
    with pytest.raises(InputError, match="max_tilt_deg"):
        station_tilts(3, -1.0)
