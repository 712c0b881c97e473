"""The colour calibration of a capture: its own files (written and read back exactly), else the sensor
profile's typical values, else a clear error."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.io import Capture, CaptureMeta, write_capture
from tofmetry.io.colour_calibration import capture_colour_calibration, write_colour_calibration
from tofmetry.sensor import KINECT_V2, CameraIntrinsics, Extrinsics


def _capture(path, sensor):
    return Capture(write_capture(path, [np.full((424, 512), 1000, np.uint16)], CaptureMeta(sensor=sensor)))


def test_own_files_then_profile_then_error(tmp_path):
    cap = _capture(tmp_path / "k", "kinect_v2")
    intr, ext, src = capture_colour_calibration(cap)
    assert src.startswith("profile kinect_v2") and intr == KINECT_V2.color
    np.testing.assert_array_equal(ext.matrix, KINECT_V2.ir_to_color.matrix)

    own = CameraIntrinsics(960, 540, 530.0, 531.0, 479.5, 269.5, (0.1, -0.05, 1e-4, -1e-4, 0.0, 0.2, -0.04, 0.0),
                           "rational")
    e = Extrinsics(np.eye(3), np.array([0.05, 0.001, -0.002]), "ir", "color")
    write_colour_calibration(cap.path, own, e, source="test")
    intr, ext, src = capture_colour_calibration(Capture(cap.path))
    assert src == "capture" and intr == own
    np.testing.assert_array_equal(ext.matrix, e.matrix)

    with pytest.raises(InputError, match="unknown sensor"):
        capture_colour_calibration(_capture(tmp_path / "u", "no_such_sensor"))
