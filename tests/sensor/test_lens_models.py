"""Brown, rational and fisheye lenses against OpenCV's own functions.

Truth is OpenCV: ``cv2.projectPoints`` / ``cv2.undistortPoints`` (Brown, rational) and
``cv2.fisheye.projectPoints`` / ``cv2.fisheye.undistortPoints`` (Kannala–Brandt). Both sides are
float64 evaluations of the same closed forms, so projections agree to ~1e-9 px; the inverses are
iterations, checked by projecting the ray table back onto its pixel grid (1e-6 px) and against
OpenCV's inverse run with a tight criteria.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.sensor import LENS_MODELS, CameraIntrinsics

CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


def _random_lens(model: str, rng: np.random.Generator) -> CameraIntrinsics:
    W, H = 640, 576
    f = rng.uniform(450, 550)
    if model == "brown":
        d = (rng.uniform(0.05, 0.12), rng.uniform(-0.3, -0.2), *rng.normal(0, 3e-4, 2), rng.uniform(0.05, 0.1))
    elif model == "rational":  # Azure Kinect-like: large k1 and k4, the denominator matters
        d = (rng.uniform(0.4, 0.6), rng.uniform(-0.03, 0.0), *rng.normal(0, 1e-4, 2), rng.uniform(-0.005, 0.0),
             rng.uniform(0.8, 0.95), rng.uniform(0.05, 0.1), rng.uniform(-0.02, -0.01))
    else:
        f = rng.uniform(300, 320)  # wide angle: ~ 160 deg over the diagonal
        d = (rng.uniform(-0.05, 0.05), rng.uniform(-0.01, 0.01), rng.uniform(-0.005, 0.005), rng.uniform(-0.001, 0.001))
    return CameraIntrinsics(W, H, f, f * rng.uniform(0.995, 1.005), W / 2 - 0.5 + rng.normal(0, 3),
                            H / 2 - 0.5 + rng.normal(0, 3), d, model)


def _cv_project(intr: CameraIntrinsics, pts: np.ndarray) -> np.ndarray:
    if intr.model == "fisheye":
        out, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), intr.K, intr.dist_array)
    else:
        out, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), intr.K, intr.dist_array)
    return out.reshape(-1, 2)


def _cv_undistort(intr: CameraIntrinsics, uv: np.ndarray) -> np.ndarray:
    if intr.model == "fisheye":
        out = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), intr.K, intr.dist_array, criteria=CRIT)
    else:
        out = cv2.undistortPoints(uv.reshape(-1, 1, 2), intr.K, intr.dist_array, criteria=CRIT)
    return out.reshape(-1, 2)


@pytest.mark.parametrize("model", LENS_MODELS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_projection_matches_opencv(model, seed):
    rng = np.random.default_rng(seed)
    intr = _random_lens(model, rng)
    # points on the rays of a pixel grid over the whole image, at random depths
    uu, vv = np.meshgrid(np.linspace(0, intr.width - 1, 41), np.linspace(0, intr.height - 1, 37))
    xy = intr.pixel_to_normalized(np.column_stack([uu.ravel(), vv.ravel()]))
    assert np.isfinite(xy).all()
    z = rng.uniform(0.5, 4.0, len(xy))
    pts = np.column_stack([xy * z[:, None], z])
    ours = intr.project(pts)
    np.testing.assert_allclose(ours, _cv_project(intr, pts), atol=1e-6)
    # and back onto the pixels the rays came from
    np.testing.assert_allclose(ours, np.column_stack([uu.ravel(), vv.ravel()]), atol=1e-6)


@pytest.mark.parametrize("model", LENS_MODELS)
def test_ray_table_matches_opencv_undistort_over_whole_image(model):
    intr = _random_lens(model, np.random.default_rng(7))
    rays = intr.ray_table()
    assert rays.shape == (intr.height, intr.width, 2) and np.isfinite(rays).all()
    u, v = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    uv = np.column_stack([u.ravel(), v.ravel()])
    theirs = _cv_undistort(intr, uv)
    # compared in pixels of the ideal pinhole (f * normalised difference)
    assert np.abs(rays.reshape(-1, 2) - theirs).max() * intr.fx < 1e-3
    back = intr.project(np.column_stack([rays.reshape(-1, 2), np.ones(len(uv))]))
    assert np.abs(back - uv).max() < 1e-6


def test_brown_is_rational_with_zero_denominator():
    b = CameraIntrinsics(512, 424, 365.0, 365.0, 256.5, 207.0, (0.09, -0.27, 1e-4, -2e-4, 0.09))
    r = b.with_(model="rational")
    assert r.distortion == b.distortion + (0.0, 0.0, 0.0)
    np.testing.assert_allclose(r.ray_table(), b.ray_table(), atol=1e-14)


@pytest.mark.parametrize("model", LENS_MODELS)
def test_dict_round_trip_keeps_the_model(model):
    intr = _random_lens(model, np.random.default_rng(3))
    back = CameraIntrinsics.from_dict(json.loads(json.dumps(intr.to_dict())))
    assert back == intr and back.model == model
    assert ("model" in intr.to_dict()) == (model != "brown")  # Brown files are unchanged


@pytest.mark.parametrize("d, model, word", [
    ((0.1, 0.2, 0.0, 0.0, 0.0, 0.1), "rational", "rational"),
    ((0.1, 0.2, 0.0), "fisheye", "fisheye"),
    ((0.0,) * 5, "division", "division"),
])
def test_wrong_coefficients_are_named(d, model, word):
    with pytest.raises(InputError, match=word):
        CameraIntrinsics(640, 576, 500, 500, 320, 288, d, model)


def test_azure_factory_lens_reproduces_opencv_rational(shared_data):
    """The real device's factory lens (NFOV unbinned): our projection of the ray table against
    ``cv2.projectPoints`` with the same 8 coefficients, every pixel of the image."""
    from tofmetry.io.azure_kinect import parse_calibration

    calib = json.loads((shared_data / "azure-kinect-recording" / "calibration.json").read_text())
    cams = parse_calibration(calib, "NFOV_UNBINNED", 720)
    for name in ("depth", "color"):
        intr = cams[name].intrinsics
        assert intr.model == "rational"
        rays = intr.ray_table().reshape(-1, 2)
        u, v = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
        uv = np.column_stack([u.ravel(), v.ravel()])
        ok = np.isfinite(rays).all(axis=1)
        assert ok.mean() > 0.99, name
        pts = np.column_stack([rays[ok], np.ones(ok.sum())])
        err = np.abs(_cv_project(intr, pts) - uv[ok]).max()
        assert err < 0.01, (name, err)
