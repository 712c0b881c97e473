"""OpenCV sample chessboard and the Azure Kinect recording (real data)."""

from __future__ import annotations

import cv2
import matplotlib
import numpy as np
import pytest

from tofmetry.calibrate import board as B

pytestmark = pytest.mark.realdata


def test_opencv_chessboard_calibrates(shared_data):
    files = sorted((shared_data / "opencv-chessboard").glob("left*.jpg"))
    corners = [B.detect_corners(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE), (9, 6)) for f in files]
    assert all(c is not None for c in corners) and len(corners) == 13
    fit = B.calibrate_intrinsics(corners, None, (9, 6), 1.0, (640, 480), leave_one_out=False)
    # measured: RMS 0.258 px, held-out 0.270 px, fx = fy = 532.2 px; margins 20 %
    assert fit.rms_px < 0.31 and not fit.rejected_views
    assert fit.intrinsics.fx == pytest.approx(532, abs=5) and fit.intrinsics.fy == pytest.approx(532, abs=5)
    cv = B.cross_validate_intrinsics(corners, (9, 6), 1.0, (640, 480), k=5)
    assert cv["rms_px"] < 0.33


@pytest.fixture(scope="module")
def azure_capture(shared_data, tmp_path_factory):
    pytest.importorskip("av")
    from tofmetry.io.azure_kinect import import_azure_kinect

    out = tmp_path_factory.mktemp("azure") / "cap"
    summary = import_azure_kinect(shared_data / "azure-kinect-recording" / "recording.mkv", out)
    return out, summary


def test_azure_frames_match_extracted_images(shared_data, azure_capture):
    from tofmetry.io import Capture

    out, summary = azure_capture
    root = shared_data / "azure-kinect-recording"
    cap = Capture(out)
    assert len(cap) == 1 and cap.sensor == "azure_kinect" and cap.shape == (576, 640)
    np.testing.assert_array_equal(cap.depth(0), cv2.imread(str(root / "depth_mm.png"), cv2.IMREAD_UNCHANGED))
    np.testing.assert_array_equal(cap.ir(0), cv2.imread(str(root / "ir.png"), cv2.IMREAD_UNCHANGED))
    ref = cv2.cvtColor(cv2.imread(str(root / "color.jpg")), cv2.COLOR_BGR2RGB)
    # colour goes MJPG -> RGB -> JPEG (q92) in the capture: a few grey levels of re-encoding
    assert np.abs(cap.color(0).astype(int) - ref).mean() < 4
    intr, src = cap.intrinsics()
    assert src == "capture.json" and intr.fx == pytest.approx(504.6, abs=0.1)
    # rational -> Brown refit: measured 0.28 px RMS over the image inside MetricRadius
    assert cap.meta.extra["azure"]["depth_brown_refit_rms_px"] < 0.4


def test_kinect_v2_calibration_refused_for_azure(azure_capture):
    from tofmetry.calibrate.board import constant_shift_calibration
    from tofmetry.errors import SensorMismatchError
    from tofmetry.io import Capture
    from tofmetry.io.calibration_file import load_calibration, save_calibration
    from tofmetry.sensor import KINECT_V2

    out, _ = azure_capture
    cap = Capture(out)
    f = out.parent / "k2.npz"
    save_calibration(f, constant_shift_calibration(10.0, KINECT_V2.depth, "kinect_v2"))
    with pytest.raises(SensorMismatchError):
        load_calibration(f, sensor=cap.sensor, shape=cap.shape)


def test_azure_colored_cloud_through_factory_extrinsics(azure_capture):
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tofmetry.io import Capture, read_ply, write_ply
    from tofmetry.io.azure_kinect import load_capture_calibration
    from tofmetry.pointcloud import depth_to_points, sample_colors

    out, _ = azure_capture
    cap = Capture(out)
    intr, _ = cap.intrinsics()
    cintr, ext = load_capture_calibration(out)
    pts = depth_to_points(cap.depth(0), intr, max_mm=2500)
    col, ok = sample_colors(pts, cap.color(0), cintr, ext)
    # measured: 90 % of the points within 2.5 m land in the colour image and pass the occlusion test
    assert ok.mean() > 0.8
    write_ply(out.parent / "azure_colored.ply", pts[ok], colors=col[ok])
    back = read_ply(out.parent / "azure_colored.ply")
    np.testing.assert_array_equal(back["colors"], col[ok])
    # the mug (nearest object, < 0.9 m) is mostly white/grey ceramic: bright, low saturation
    mug = ok & (pts[:, 2] < 0.9)
    c = col[mug].astype(float)
    assert mug.sum() > 5000 and np.median(c.mean(1)) > 120
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.set_facecolor("0.5")
    ax.scatter(pts[ok, 0] / pts[ok, 2], -pts[ok, 1] / pts[ok, 2], c=col[ok] / 255.0, s=0.3, marker="s", linewidths=0)
    ax.set_xlabel("x / z [-]")
    ax.set_ylabel("-y / z [-]")
    ax.set_title("Azure Kinect: depth points coloured via factory extrinsics")
    fig.savefig(out.parent / "azure_colored.png", dpi=80)
    plt.close(fig)
    assert (out.parent / "azure_colored.png").stat().st_size > 10000
