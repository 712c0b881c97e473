"""Dataset writers: contract folders readable by tofmetry.io, truth files at the root only."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.io import Capture, ScanDataset, WallDataset, read_ply
from tofmetry.simulate import ErrorModel, datasets

CAPTURE_FILES = {"capture.json", "depth", "ir"}


def _capture_clean(path):
    names = {p.name for p in path.iterdir()}
    assert names <= CAPTURE_FILES | {"color"}, names
    meta = json.loads((path / "capture.json").read_text())
    assert meta["sensor"] == "kinect_v2"
    assert "intrinsics" not in meta  # the true intrinsics go to truth.json only


def test_wall_dataset_roundtrip_and_mounting_offset(tmp_path):
    out = datasets.wall_dataset(tmp_path / "wall", [1000, 2500], n_frames=3, seed=4)
    ds = WallDataset(out, min_stations=2)
    assert ds.distances_mm == [1000.0, 2500.0]
    truth = json.loads((out / "truth.json").read_text())
    for st, t in zip(ds.stations, truth["stations"]):
        _capture_clean(st.path)
        cap = st.open()
        assert len(cap) == 3 and cap.shape == (424, 512) and cap.has_ir
        assert st.distance_mm - t["optical_centre_mm"] == pytest.approx(20.0)  # paper: ~2 cm offset
        assert cap.timestamps_s[0] >= 3600.0  # warm sensor
        # raw reading ~ csv distance - 20 mm + systematic errors (|wiggling + deformation| < 25 mm)
        c = cap.depth_stack()[:, 202:212, 251:261].astype(float).mean()
        assert abs(c - (st.distance_mm - 20.0)) < 25.0
    npz = np.load(out / "truth.npz")
    assert npz["true_depth_d1000"].shape == (424, 512)
    assert truth["true_intrinsics"]["fx"] == pytest.approx(365.0)
    with pytest.raises(InputError, match="refusing to overwrite"):
        datasets.wall_dataset(out, [1000], n_frames=1)
    with pytest.raises(InputError, match="strictly increasing"):
        datasets.wall_dataset(tmp_path / "bad", [2000, 1000], n_frames=1)


def test_wall_dataset_without_offset(tmp_path):
    out = datasets.wall_dataset(tmp_path / "w", [1200], n_frames=1, errors=ErrorModel().without("mounting_offset"))
    t = json.loads((out / "truth.json").read_text())
    assert t["stations"][0]["optical_centre_mm"] == pytest.approx(1200.0)
    with pytest.raises(InputError, match="quantis"):
        datasets.wall_dataset(tmp_path / "w2", [1200], n_frames=1, errors=ErrorModel.none(quantize=False))


def test_materials_regions(tmp_path):
    out = datasets.materials(tmp_path / "m", board="samples", n_frames=2)
    _capture_clean(out / "capture")
    reg = json.loads((out / "regions.json").read_text())["regions"]
    names = [r["name"] for r in reg]
    assert "cd" in names and "white_paper" in names
    assert [r["name"] for r in reg if r["reference"]] == ["white_paper"]
    labels = np.load(out / "truth.npz")["labels"]
    truth = json.loads((out / "truth.json").read_text())
    by_name = {s["name"]: s["label"] for s in truth["samples"]}
    for r in reg:
        u0, v0, u1, v1 = r["rect"]
        assert u1 - u0 > 10 and v1 - v0 > 10
        assert np.all(labels[v0:v1, u0:u1] == by_name[r["name"]])  # rect lies inside its sample
    out2 = datasets.materials(tmp_path / "g", board="grey", n_frames=1)
    reg2 = json.loads((out2 / "regions.json").read_text())["regions"]
    assert len(reg2) == 20 and sum(r["reference"] for r in reg2) >= 2
    with pytest.raises(InputError, match="board"):
        datasets.materials(tmp_path / "x", board="marble")


def test_warmup_noise_outdoor(tmp_path):
    w = datasets.warmup(tmp_path / "w", duration_s=300, interval_s=100)
    cap = Capture(w / "capture")
    np.testing.assert_array_equal(cap.timestamps_s, [0, 100, 200, 300])
    t = json.loads((w / "truth.json").read_text())
    assert t["true_drift_mm"][0] == pytest.approx(-5.0, abs=0.3)
    n = datasets.noise(tmp_path / "n", n_frames=2)
    assert len(Capture(n / "capture")) == 2
    assert np.load(n / "truth.npz")["noise_sigma_mm"].shape == (424, 512)
    o = datasets.outdoor(tmp_path / "o", n_frames=1)
    _capture_clean(o / "capture")
    d = Capture(o / "capture").depth(0)
    assert 0.15 < (d > 0).mean() < 0.25
    assert np.load(o / "truth.npz")["flying"].shape == (1, 424, 512)


def test_scan_dataset(tmp_path):
    out = datasets.scan(tmp_path / "s", n_views=2, n_frames=1, seed=1)
    ds = ScanDataset(out)
    assert ds.names == ["00", "01"]
    ref = read_ply(out / "reference.ply")
    assert len(ref["faces"]) > 1000
    ext = ref["points"].max(0) - ref["points"].min(0)
    assert ext == pytest.approx([0.40, 0.20, 0.20], abs=0.02)  # balustrade ~40 x 20 x 20 cm
    truth = json.loads((out / "truth.json").read_text())
    from tofmetry.sensor import KINECT_V2

    centre = ref["points"].mean(0)
    for k, v in enumerate(truth["views"]):
        _capture_clean(ds.view_paths[k])
        T = np.array(v["camera_to_world"])
        pc = (centre - T[:3, 3]) @ T[:3, :3]  # world -> camera
        uv = KINECT_V2.depth.project(pc[None])[0]
        assert abs(uv[0] - 256) < 30 and abs(uv[1] - 212) < 40  # object central in the image
        # the true pose explains the measured depth at the object centre to within ~2 cm
        d = ds[k].depth(0)
        dz = pc[2] * 1000 - float(d[int(round(uv[1])), int(round(uv[0]))])
        assert 0 < dz < 250  # the surface lies in front of the object centre, within its half-size
        assert np.linalg.norm(T[:3, 3] - np.array(truth["target_m"])) == pytest.approx(1.0)


def test_checkerboard_images_detectable(tmp_path):
    cv2 = pytest.importorskip("cv2")
    from tofmetry.io.images import read_ir_image
    from tofmetry.sensor import CameraIntrinsics

    out = datasets.checkerboard_images(tmp_path / "cb", n_images=4, seed=5)
    board = json.loads((out / "board.json").read_text())
    assert board == {"cols": 9, "rows": 6, "square_mm": 50.0}
    truth = json.loads((out / "truth.json").read_text())
    intr = CameraIntrinsics.from_dict(truth["true_intrinsics"])
    obj = np.array([[i * 0.05, j * 0.05, 0] for j in range(6) for i in range(9)])
    found = 0
    for im in truth["images"]:
        ir = read_ir_image(out / im["file"]).astype(float)
        lo, hi = np.percentile(ir, [1, 99])
        g = np.clip((ir - lo) / (hi - lo) * 255, 0, 255).astype(np.uint8)
        ok, c = cv2.findChessboardCornersSB(g, (9, 6), flags=cv2.CALIB_CB_ACCURACY)
        if not ok:  # steeply tilted boards (~40 deg, ~10 px squares) can defeat the detector
            continue
        found += 1
        T = np.array(im["board_to_camera"])
        uv = intr.project(obj @ T[:3, :3].T + T[:3, 3])
        c = c.reshape(-1, 2)
        err = min(np.abs(c - uv).mean(), np.abs(c[::-1] - uv).mean())
        # anti-aliased rendering: the detector lands within a fraction of a pixel of the truth
        assert err < 0.3
    assert found >= 3


def test_scan_with_colour_from_the_cli(tmp_path):
    """``simulate scan --color``: one colour frame per view, rendered from the colour camera's own
    viewpoint, with its calibration beside the frames and in the truth; without it, no colour."""
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.io.colour_calibration import capture_colour_calibration
    from tofmetry.simulate import ColourCamera

    r = CliRunner().invoke(app, ["simulate", "scan", "-o", str(tmp_path / "c"), "--views", "2", "--frames", "2",
                                 "--color", "--no-errors"])
    assert r.exit_code == 0, r.output
    ds = ScanDataset(tmp_path / "c")
    truth = json.loads((tmp_path / "c" / "truth.json").read_text())
    cam = ColourCamera.from_dict(truth["color_camera"])
    default = ColourCamera(noise_dn=2.0)
    assert cam.intrinsics == default.intrinsics and cam.noise_dn == 2.0 and cam.exposure == default.exposure
    np.testing.assert_allclose(cam.ir_to_color.matrix, default.ir_to_color.matrix)
    for k in range(2):
        cap = ds[k]
        assert cap.has_color and len(cap.color_files) == 1 and len(cap) == 2
        img = cap.color(1)  # every frame reads the view's colour frame
        assert img.shape == (1080, 1920, 3) and img[..., 0].mean() > img[..., 2].mean()  # a red object on grey ground
        intr, ext, src = capture_colour_calibration(cap)
        assert src == "capture" and intr == cam.intrinsics
        np.testing.assert_allclose(ext.matrix, cam.ir_to_color.matrix)
    with pytest.raises(InputError, match="ColourCamera"):
        datasets.scan(tmp_path / "bad", n_views=1, n_frames=1, color="yes")
    assert not Capture(datasets.scan(tmp_path / "plain", n_views=1, n_frames=1) / "views" / "00").has_color
