"""Camera model: projection <-> back-projection round trips, validation, ray table."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.sensor import KINECT_V2, CameraIntrinsics, Extrinsics


@pytest.fixture(params=["kinect_typical", "strong_tangential"])
def intr(request) -> CameraIntrinsics:
    if request.param == "kinect_typical":
        return KINECT_V2.depth
    # a real device (iai_kinect2 001530565347) has k3 = 0.75 and small tangential terms
    return CameraIntrinsics(512, 424, 364.97, 365.52, 257.19, 210.77, (0.131, -0.565, -8.05e-4, 8.98e-4, 0.745))


def test_project_backproject_round_trip_subnanopixel(intr):
    rng = np.random.default_rng(1)
    uv = rng.uniform([0, 0], [intr.width - 1, intr.height - 1], size=(5000, 2))
    z = rng.uniform(0.5, 4.5, size=5000)
    pts = intr.backproject(uv, z)
    assert np.allclose(pts[:, 2], z)
    uv2 = intr.project(pts)
    assert np.abs(uv2 - uv).max() < 1e-6  # issue #2: < 1e-6 px


def test_distort_undistort_inverse(intr):
    rng = np.random.default_rng(2)
    xy = rng.uniform(-0.7, 0.7, size=(2000, 2))
    back = intr.undistort_normalized(intr.distort_normalized(xy))
    assert np.abs(back - xy).max() < 1e-10


def test_ray_table_matches_backproject_and_is_cached(intr):
    t = intr.ray_table()
    assert t.shape == (intr.height, intr.width, 2)
    assert intr.ray_table() is t
    assert not t.flags.writeable
    v, u = 17, 400
    p = intr.backproject(np.array([[u, v]], float), np.array([2.0]))[0]
    assert np.allclose(p[:2] / p[2], t[v, u], atol=1e-12)


def test_pinhole_without_undistort():
    i = KINECT_V2.depth
    t = i.ray_table(undistort=False)
    assert np.isclose(t[0, 0, 0], (0 - i.cx) / i.fx)
    assert np.isclose(t[-1, -1, 1], (i.height - 1 - i.cy) / i.fy)


def test_profile_values_are_typical_kinect_v2():
    h, v = KINECT_V2.depth.fov_deg()
    assert 68 < h < 72 and 58 < v < 62  # published 70 x 60 deg
    assert KINECT_V2.depth.shape == (424, 512)
    assert KINECT_V2.color.shape == (1080, 1920)
    assert (KINECT_V2.min_range_mm, KINECT_V2.max_range_mm, KINECT_V2.fps) == (500, 4500, 30)


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(fx=-1.0), "fx"),
        (dict(fy=float("nan")), "fy"),
        (dict(width=0), "width"),
        (dict(cx=5000.0), "cx"),
        (dict(distortion=(0.1, 0.2, 0.3)), "distortion"),
    ],
)
def test_validation_names_the_field(kwargs, word):
    base = KINECT_V2.depth.to_dict()
    base.update(kwargs)
    with pytest.raises(InputError, match=word):
        CameraIntrinsics(base["width"], base["height"], base["fx"], base["fy"], base["cx"], base["cy"], base["distortion"])


def test_dict_round_trip_and_missing_key():
    d = KINECT_V2.depth.to_dict()
    assert CameraIntrinsics.from_dict(d) == KINECT_V2.depth
    d.pop("fy")
    with pytest.raises(InputError, match="fy"):
        CameraIntrinsics.from_dict(d, source="x.json")


def test_extrinsics_inverse_and_validation():
    ang = np.radians(10)
    R = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
    e = Extrinsics(R, [0.05, 0.01, -0.02])
    p = np.random.default_rng(0).normal(size=(10, 3))
    assert np.allclose(e.inverse().apply(e.apply(p)), p)
    assert np.allclose(Extrinsics.from_dict(e.to_dict()).matrix, e.matrix)
    with pytest.raises(InputError, match="rotation"):
        Extrinsics(np.diag([1, 1, -1.0]), [0, 0, 0])
