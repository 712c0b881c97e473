"""ChArUco boards: the rendered pattern is OpenCV's, partial views give their corners with ids,
the refined corners and the lens recovered from rendered views match the truth, the command runs.

Tolerances: the X-junction fit reaches 0.02-0.03 px RMS on rendered Kinect-v2-like corners
(``_corner_fit``); OpenCV's own ChArUco corners (``cornerSubPix``) about 0.1 px. The lens is judged
by ray error against its own prediction from the parameter covariance."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from tofmetry.calibrate import CharucoBoard, calibrate_intrinsics, detect_charuco, ray_error_px
from tofmetry.errors import InputError

BOARD = CharucoBoard(13, 10, 80.0, 56.0, "DICT_4X4_100")


def test_rendered_pattern_is_opencvs():
    from tofmetry.simulate import scenes

    sx, sy, s, m, px = 6, 5, 0.08, 0.056, 0.0005
    tex = scenes.charuco(sx, sy, s, m, "DICT_4X4_50").surfaces[0].texture
    u, v = np.meshgrid(np.arange(sx * s / px) * px + px / 2, np.arange(sy * s / px) * px + px / 2)
    a = tex(u.ravel(), v.ravel())[0].reshape(u.shape)
    ref = CharucoBoard(sx, sy, 80.0, 56.0, "DICT_4X4_50").cv().generateImage(u.shape[::-1], marginSize=0, borderBits=1)
    # OpenCV resamples its markers to whole pixels: they differ only on module edges
    assert np.mean((a > 0.5) != (ref > 127)) < 0.01
    det = cv2.aruco.CharucoDetector(CharucoBoard(sx, sy, 80.0, 56.0, "DICT_4X4_50").cv())
    _, ids, _, _ = det.detectBoard(np.pad(((a > 0.5) * 255).astype(np.uint8), 40, constant_values=255))
    assert sorted(ids.ravel().tolist()) == list(range((sx - 1) * (sy - 1)))


def test_board_validation():
    with pytest.raises(InputError, match="marker"):
        CharucoBoard(9, 7, 50.0, 60.0)
    with pytest.raises(InputError, match="DICT_4X4_50 has 50 markers"):
        CharucoBoard(13, 10, 80.0, 56.0, "DICT_4X4_50")
    with pytest.raises(InputError, match="dictionary"):
        CharucoBoard(9, 7, 80.0, 56.0, "NOPE")
    assert CharucoBoard.from_dict(BOARD.to_dict()) == BOARD


@pytest.fixture(scope="module")
def views(tmp_path_factory):
    """8 rendered IR views of the default ChArUco board on a random lens (partial views included)."""
    from tofmetry.simulate import datasets, random_sensor

    out = datasets.charuco_images(tmp_path_factory.mktemp("ch") / "ch", n_images=8, seed=4, sensor=random_sensor(4))
    return out


def _truth(out):
    from tofmetry.sensor import CameraIntrinsics

    t = json.loads((out / "truth.json").read_text())
    return CameraIntrinsics.from_dict(t["true_intrinsics"]), [np.asarray(i["board_to_camera"]) for i in t["images"]]


def test_partial_views_corners_and_lens(views):
    from tofmetry.io.images import read_gray_image

    lens, poses = _truth(views)
    cs, objs, errs, err_cv, partial = [], [], [], [], 0
    for k, T in enumerate(poses):
        det = detect_charuco(read_gray_image(views / f"ir_{k:03d}.png"), BOARD)
        assert det is not None
        partial += len(det.ids) < BOARD.n_corners
        tr = lens.project(det.object_points / 1000.0 @ T[:3, :3].T + T[:3, 3])
        errs.append(np.linalg.norm(det.corners - tr, axis=1)[det.model_ok])
        err_cv.append(np.linalg.norm(det.opencv_corners - tr, axis=1))
        assert det.fraction_model > 0.9
        cs.append(det.corners)
        objs.append(det.object_points)
    assert partial >= 3                       # boards overhanging the image still give their corners
    e, ecv = np.concatenate(errs), np.concatenate(err_cv)
    rms = float(np.sqrt(np.mean(e ** 2)))
    assert rms < 0.04 and e.max() < 0.2, (rms, e.max())
    assert rms < 0.5 * float(np.sqrt(np.mean(ecv ** 2)))
    res = calibrate_intrinsics(cs, None, BOARD.inner, BOARD.square_mm, (lens.width, lens.height),
                               leave_one_out=False, object_points=objs)
    re = ray_error_px(lens, res.intrinsics, step=4)
    assert re.rms_px < 3.0 * res.predicted_ray.rms_px and re.rms_px < 0.15, (re.rms_px, res.predicted_ray.rms_px)


def test_calibrate_intrinsics_charuco_command(views, tmp_path):
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.sensor import CameraIntrinsics

    out = tmp_path / "intr.json"
    r = CliRunner().invoke(app, ["calibrate", "intrinsics", str(views), "--board", "charuco", "--squares", "13x10",
                                 "--square-mm", "80", "--marker-mm", "56", "--dictionary", "DICT_4X4_100",
                                 "-o", str(out), "--no-loo"])
    assert r.exit_code == 0, r.output
    lens, _ = _truth(views)
    est = CameraIntrinsics.from_dict(json.loads(out.read_text()))
    assert ray_error_px(lens, est, step=4).rms_px < 0.15
    rep = json.loads((tmp_path / "intr_report" / "intrinsics_report.json").read_text())
    assert rep["charuco"]["squares_x"] == 13 and len(rep["detected"]) == 8
