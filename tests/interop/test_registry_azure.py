"""Format registry, CLI import/export, and Azure Kinect parsing on synthetic inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.errors import FormatError, InputError
from tofmetry.io import registry


def test_unknown_format_lists_known():
    with pytest.raises(InputError, match=r"unknown import format 'nope'; known: .*azure-kinect.*iai-kinect2"):
        registry.get_importer("nope")
    with pytest.raises(InputError, match=r"unknown export format"):
        registry.get_exporter("nope")


def test_missing_optional_dependency_is_named():
    fmt = registry.Format("x", "tofmetry.io.e57:export_e57_cli", "test", ("tofmetry_no_such_pkg",))
    with pytest.raises(InputError, match=r"needs the optional package 'tofmetry_no_such_pkg'.*pip install"):
        fmt.load()


def test_every_registered_format_loads():
    for table in (registry.IMPORTERS, registry.EXPORTERS):
        for f in table.values():
            assert callable(f.load())


def test_cli_import_export_iai_round_trip(tmp_path):
    from tofmetry.io import iai_kinect2 as ik
    from tofmetry.sensor import KINECT_V2, Extrinsics

    src = tmp_path / "dev"
    ik.write_iai_calibration(src, ik.IaiCalibration(KINECT_V2.depth, KINECT_V2.color,
                                                    Extrinsics(np.eye(3), np.array([-0.05, 0, 0])), -20.0))
    r = CliRunner().invoke(app, ["import", "iai-kinect2", str(src), "-o", str(tmp_path / "ds")])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "ds" / "depth_shift.json").read_text())["depth_shift_mm"] == -20.0
    r = CliRunner().invoke(app, ["export", "iai-kinect2", str(tmp_path / "ds"), "-o", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    for f in ik.CALIB_FILES:
        assert (tmp_path / "out" / f).read_bytes() == (src / f).read_bytes()
    # the shift is also a tofmetry calibration: exporting it gives the same depthShift
    r = CliRunner().invoke(app, ["export", "iai-kinect2", str(tmp_path / "ds" / "depth_shift.npz"), "-o", str(tmp_path / "o2")])
    assert r.exit_code == 0, r.output
    assert ik.read_calib_depth(tmp_path / "o2" / "calib_depth.yaml") == -20.0


def test_cli_iai_poses_need_board(tmp_path):
    import cv2

    src = tmp_path / "rec"
    src.mkdir()
    cv2.imwrite(str(src / "0000_depth.png"), np.full((424, 512), 1000, np.uint16))
    cv2.imwrite(str(src / "0000_ir.png"), np.full((424, 512), 1000, np.uint16))
    r = CliRunner().invoke(app, ["import", "iai-kinect2", str(src), "-o", str(tmp_path / "ds")])
    assert r.exit_code != 0 and "--board" in str(r.exception)
    r = CliRunner().invoke(app, ["import", "iai-kinect2", str(src), "-o", str(tmp_path / "ds"), "--board", "5x7",
                                 "--square-mm", "30"])
    assert r.exit_code == 0, r.output
    from tofmetry.io.board_dataset import BoardDataset

    ds = BoardDataset(tmp_path / "ds")
    assert len(ds) == 1 and ds.board.size == (5, 7) and ds.corners(0) is None


def test_corners_json_mismatch_names_file(tmp_path):
    from tofmetry.io.board_dataset import BoardSpec, read_corners

    (tmp_path / "corners.json").write_text(json.dumps({"corners_px": [[1, 2]] * 34}))
    with pytest.raises(FormatError, match=r"corners.json: 34 corners do not match the board 5x7"):
        read_corners(tmp_path / "corners.json", BoardSpec(5, 7, 30.0))
    with pytest.raises(InputError, match="COLSxROWS"):
        BoardSpec.parse("5by7", 30)


# ----------------------------------------------------------------------------- Azure Kinect
def _azure_json():
    depth = {"Purpose": "CALIBRATION_CameraPurposeDepth", "MetricRadius": 1.74, "SensorWidth": 1024, "SensorHeight": 1024,
             "Rt": {"Rotation": [1, 0, 0, 0, 1, 0, 0, 0, 1], "Translation": [0, 0, 0]},
             "Intrinsics": {"ModelParameters": [0.5, 0.5, 0.49, 0.49, 0.3, -0.1, 0.01, 0.0, 0.0, 0.0, 0, 0, 1e-4, -2e-4]}}
    color = {"Purpose": "CALIBRATION_CameraPurposePhotoVideo", "SensorWidth": 4096, "SensorHeight": 3072,
             "Rt": {"Rotation": [1, 0, 0, 0, 1, 0, 0, 0, 1], "Translation": [-0.032, 0.0, 0.004]},
             "Intrinsics": {"ModelParameters": [0.5, 0.5, 0.48, 0.64, 0.05, -0.02, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0]}}
    return {"CalibrationInformation": {"Cameras": [depth, color]}}


def test_azure_calibration_mapping_follows_the_sdk():
    from tofmetry.io.azure_kinect import parse_calibration

    cams = parse_calibration(_azure_json(), "NFOV_UNBINNED", 720)
    d = cams["depth"].intrinsics
    # SDK: cx = 0.5 * 1024 - 192 (crop) - 0.5 (pixel-centre origin); fx = 0.49 * 1024
    assert (d.width, d.height) == (640, 576)
    assert d.cx == pytest.approx(319.5) and d.cy == pytest.approx(512 - 180 - 0.5) and d.fx == pytest.approx(0.49 * 1024)
    # the native rational model is kept (p1 = params[13], p2 = params[12]); k4..k6 = 0 here, so a
    # Brown refit is the same model
    assert d.model == "rational"
    np.testing.assert_allclose(d.distortion, [0.3, -0.1, -2e-4, 1e-4, 0.01, 0, 0, 0], atol=1e-6)
    assert cams["depth"].refit_max_px < 1e-3
    c = cams["color"].intrinsics
    assert (c.width, c.height) == (1280, 720)
    assert c.cy == pytest.approx(0.5 * 960 - 120 - 0.5) and c.fy == pytest.approx(0.64 * 960)
    np.testing.assert_allclose(cams["color"].to_depth.translation, [-0.032, 0.0, 0.004])


def test_azure_rational_model_is_kept_and_refit_cost_reported():
    from tofmetry.io.azure_kinect import parse_calibration

    j = _azure_json()
    j["CalibrationInformation"]["Cameras"][0]["Intrinsics"]["ModelParameters"][7:10] = [0.2, 0.01, 0.0]
    cams = parse_calibration(j, "NFOV_UNBINNED", None)
    assert cams["color"] is None
    assert 0 < cams["depth"].refit_rms_px < 2.0
    assert cams["depth"].rational[5] == 0.2
    assert cams["depth"].intrinsics.distortion[5] == 0.2 and cams["depth"].intrinsics.model == "rational"


def test_azure_mkv_without_depth_track(tmp_path):
    av = pytest.importorskip("av")
    from tofmetry.io.azure_kinect import read_azure_mkv

    path = tmp_path / "nodepth.mkv"
    with av.open(str(path), "w", format="matroska") as c:
        s = c.add_stream("ffv1", rate=30)
        s.width, s.height, s.pix_fmt = 32, 16, "gray"
        s.metadata["title"] = "COLOR"
        fr = av.VideoFrame.from_ndarray(np.zeros((16, 32), np.uint8), format="gray")
        for p in s.encode(fr):
            c.mux(p)
        for p in s.encode():
            c.mux(p)
    with pytest.raises(FormatError, match=r"nodepth.mkv: no depth track"):
        read_azure_mkv(path)
    (tmp_path / "junk.mkv").write_bytes(b"not a matroska file")
    with pytest.raises(FormatError, match="junk.mkv"):
        read_azure_mkv(tmp_path / "junk.mkv")


def test_azure_stream_sync_on_synthetic_mkv(tmp_path):
    av = pytest.importorskip("av")
    from fractions import Fraction

    from tofmetry.io.azure_kinect import AzureInfo, iter_azure_frames

    path = tmp_path / "rec.mkv"
    rng = np.random.default_rng(0)
    depth = [rng.integers(0, 4000, (8, 16), dtype=np.uint16) for _ in range(3)]
    ir = [rng.integers(0, 60000, (8, 16), dtype=np.uint16) for _ in range(3)]
    with av.open(str(path), "w", format="matroska") as c:
        streams = []
        for title in ("DEPTH", "IR"):
            # FFmpeg's Matroska muxer cannot write k4arecorder's raw 'b16g' track; a lossless
            # 16-bit ffv1 track exercises the same synchronisation and uint16 path
            s = c.add_stream("ffv1", rate=30)
            s.width, s.height, s.pix_fmt = 16, 8, "gray16le"
            s.time_base = Fraction(1, 1000000)
            s.metadata["title"] = title
            streams.append(s)
        for i in range(3):
            for s, img in zip(streams, (depth[i], ir[i])):
                fr = av.VideoFrame.from_ndarray(img, format="gray16le")
                fr.pts = i * 33333
                fr.time_base = Fraction(1, 1000000)
                for p in s.encode(fr):
                    c.mux(p)
        for s in streams:
            for p in s.encode():
                c.mux(p)
    info = AzureInfo(path, {}, {}, "NFOV_UNBINNED", None, 0, 1, None)
    frames = list(iter_azure_frames(info))
    assert len(frames) == 3
    for i, (t, d, r, col) in enumerate(frames):
        assert t == pytest.approx(i * 0.033333, abs=1e-3) and col is None   # Matroska stores ms
        np.testing.assert_array_equal(d, depth[i])      # lossless 16-bit: exact
        np.testing.assert_array_equal(r, ir[i])
    assert len(list(iter_azure_frames(info, max_frames=2))) == 2
