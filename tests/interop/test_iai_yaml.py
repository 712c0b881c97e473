"""iai_kinect2 OpenCV-YAML files: round trip, OpenCV compatibility, and bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tofmetry.errors import FormatError, InputError
from tofmetry.io import iai_kinect2 as ik
from tofmetry.sensor import KINECT_V2, CameraIntrinsics, Extrinsics

INTR = CameraIntrinsics(512, 424, 365.123456789, 364.5, 255.75, 207.25, (0.09, -0.27, 0.001, -0.002, 0.09))


def test_calib_ir_round_trip_exact(tmp_path):
    ik.write_calib_ir(tmp_path / "calib_ir.yaml", INTR)
    back = ik.read_calib_ir(tmp_path / "calib_ir.yaml")
    assert back == INTR          # %.16e keeps every double bit
    text = (tmp_path / "calib_ir.yaml").read_text()
    assert text.startswith("%YAML:1.0\n---\ncameraMatrix: !!opencv-matrix\n   rows: 3\n")


def test_written_files_load_in_opencv_filestorage(tmp_path):
    ik.write_calib_ir(tmp_path / "calib_ir.yaml", INTR)
    ik.write_calib_depth(tmp_path / "calib_depth.yaml", -23.75)
    ext = Extrinsics(cv2.Rodrigues(np.array([0.01, -0.02, 0.03]))[0], np.array([-0.052, 0.001, -0.002]))
    ik.write_calib_pose(tmp_path / "calib_pose.yaml", ext, INTR, KINECT_V2.color)
    fs = cv2.FileStorage(str(tmp_path / "calib_ir.yaml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_array_equal(fs.getNode("cameraMatrix").mat(), INTR.K)
    np.testing.assert_array_equal(fs.getNode("projection").mat()[:3, :3], INTR.K)
    fs.release()
    fs = cv2.FileStorage(str(tmp_path / "calib_depth.yaml"), cv2.FILE_STORAGE_READ)
    assert fs.getNode("depthShift").real() == -23.75
    fs.release()
    back = ik.read_calib_pose(tmp_path / "calib_pose.yaml")
    np.testing.assert_array_equal(back.rotation, ext.rotation)
    np.testing.assert_array_equal(back.translation, ext.translation)
    d = ik.read_opencv_yaml(tmp_path / "calib_pose.yaml")
    # epipolar constraint: a colour-frame point and its IR-frame source satisfy x_c^T E x_ir = 0
    X = np.array([0.1, -0.2, 1.3])
    xc = ext.apply(X)[0]
    assert abs((xc / xc[2]) @ d["essential"] @ (X / X[2])) < 1e-12


def test_format_matches_opencv_layout_for_long_rows():
    txt = ik.format_opencv_yaml({"m": np.arange(16, dtype=float).reshape(4, 4) + 0.123456789})
    lines = txt.splitlines()
    assert all(len(line) <= 80 for line in lines)
    assert lines[6].startswith("   data: [") and lines[7].startswith("       2.1")  # continuation indented 7 like OpenCV


def test_not_opencv_yaml_names_file(tmp_path):
    f = tmp_path / "calib_ir.yaml"
    f.write_text("cameraMatrix: [1, 2, 3]\n")
    with pytest.raises(FormatError, match="calib_ir.yaml"):
        ik.read_calib_ir(f)


def test_entry_not_a_matrix_names_file_and_key(tmp_path):
    f = tmp_path / "calib_ir.yaml"
    f.write_text("%YAML:1.0\n---\ncameraMatrix: 3.5\ndistortionCoefficients: 1.0\n")
    with pytest.raises(FormatError, match=r"calib_ir.yaml.*cameraMatrix.*not an OpenCV matrix"):
        ik.read_calib_ir(f)


def test_wrong_matrix_shape(tmp_path):
    f = tmp_path / "calib_ir.yaml"
    ik.write_opencv_yaml(f, {"cameraMatrix": np.eye(4), "distortionCoefficients": np.zeros((1, 5))})
    with pytest.raises(FormatError, match=r"shape 4x4, expected 3x3"):
        ik.read_calib_ir(f)


def test_missing_file_and_missing_depth_shift(tmp_path):
    with pytest.raises(InputError, match="not found"):
        ik.read_calib_ir(tmp_path / "nope.yaml")
    ik.write_opencv_yaml(tmp_path / "calib_depth.yaml", {"other": 1.0})
    with pytest.raises(FormatError, match="depthShift"):
        ik.read_calib_depth(tmp_path / "calib_depth.yaml")


def test_ir_points_round_trip_and_board_mismatch(tmp_path):
    pts = np.random.default_rng(0).uniform(0, 400, (35, 2))
    ik.write_ir_points(tmp_path / "0000_ir_points.yaml", pts)
    back = ik.read_ir_points(tmp_path / "0000_ir_points.yaml", (5, 7))
    np.testing.assert_allclose(back, pts, rtol=1e-8)      # written with 9 significant digits like iai_kinect2
    with pytest.raises(FormatError, match=r"0000_ir_points.yaml: 35 corners do not match the board 6x7"):
        ik.read_ir_points(tmp_path / "0000_ir_points.yaml", (6, 7))


def test_folder_round_trip(tmp_path):
    ext = Extrinsics(np.eye(3), np.array([-0.05, 0.0, 0.0]))
    cal = ik.IaiCalibration(INTR, KINECT_V2.color, ext, 12.5)
    ik.write_iai_calibration(tmp_path / "dev", cal)
    back = ik.read_iai_calibration(tmp_path / "dev")
    assert back.ir == INTR and back.color == KINECT_V2.color and back.depth_shift_mm == 12.5
    np.testing.assert_array_equal(back.ir_to_color.translation, ext.translation)
