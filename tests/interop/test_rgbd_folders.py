"""TUM and Open3D RGB-D folders -> capture (tiny synthetic folders), E57 round trip."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tofmetry.errors import FormatError, InputError
from tofmetry.io import Capture, read_ply, write_ply
from tofmetry.io.open3d_rgbd import import_open3d, read_open3d_intrinsics, write_open3d_intrinsics
from tofmetry.io.tum import associate, import_tum
from tofmetry.sensor import CameraIntrinsics

H, W = 48, 64


def _depth(seed, scale):
    """Raw depth values for 0.5-3 m in ``scale`` units per metre (uint16)."""
    z_m = np.random.default_rng(seed).uniform(0.5, 3.0, (H, W))
    raw = np.rint(z_m * scale).astype(np.uint16)
    raw[0, :5] = 0
    return raw


def make_tum(root, n=3):
    (root / "depth").mkdir(parents=True)
    (root / "rgb").mkdir()
    dl, cl, raws = ["# depth maps", "# timestamp filename"], ["# color images"], []
    for i in range(n):
        t = 1305031102.0 + 0.033 * i
        raw = _depth(i, 5000.0)
        raws.append(raw)
        cv2.imwrite(str(root / "depth" / f"{t:.6f}.png"), raw)
        cv2.imwrite(str(root / "rgb" / f"{t + 0.004:.6f}.png"), np.full((H, W, 3), 40 * i, np.uint8))
        dl.append(f"{t:.6f} depth/{t:.6f}.png")
        cl.append(f"{t + 0.004:.6f} rgb/{t + 0.004:.6f}.png")
    (root / "depth.txt").write_text("\n".join(dl) + "\n")
    (root / "rgb.txt").write_text("\n".join(cl) + "\n")
    return raws


def test_tum_import_is_lossless_in_mm(tmp_path):
    raws = make_tum(tmp_path / "tum")
    summary = import_tum(tmp_path / "tum", tmp_path / "cap")
    assert summary["frames"] == 3 and summary["color"]
    cap = Capture(tmp_path / "cap")
    assert cap.meta.depth_unit_mm == pytest.approx(0.2)
    for i, raw in enumerate(raws):
        # Capture returns integer mm: raw/5 rounded -> at most 0.5 mm from raw * 0.2
        np.testing.assert_allclose(cap.depth(i), raw * 0.2, atol=0.5)
        assert (cap.depth(i)[raw == 0] == 0).all()
    assert cap.has_color and len(cap.timestamps_s) == 3
    # the raw values are kept bit-exact on disk
    np.testing.assert_array_equal(cv2.imread(str(cap.depth_files[1]), cv2.IMREAD_UNCHANGED), raws[1])


def test_tum_errors(tmp_path):
    with pytest.raises(InputError, match="depth.txt"):
        import_tum(tmp_path, tmp_path / "cap")
    (tmp_path / "t").mkdir()
    (tmp_path / "t" / "depth.txt").write_text("abc depth/x.png\n")
    with pytest.raises(FormatError, match=r"depth.txt:1: timestamp 'abc'"):
        import_tum(tmp_path / "t", tmp_path / "cap")


def test_associate_nearest_within_tolerance():
    idx = associate(np.array([0.0, 1.0, 2.0]), np.array([1.01, 0.005, 5.0]), 0.02)
    np.testing.assert_array_equal(idx, [1, 0, -1])


def test_open3d_import_with_intrinsics(tmp_path):
    root = tmp_path / "o3d"
    (root / "depth").mkdir(parents=True)
    (root / "color").mkdir()
    raws = []
    for i in range(2):
        raw = _depth(10 + i, 1000.0)
        raws.append(raw)
        cv2.imwrite(str(root / "depth" / f"{i:06d}.png"), raw)
        cv2.imwrite(str(root / "color" / f"{i:06d}.jpg"), np.full((H, W, 3), 100, np.uint8))
    intr = CameraIntrinsics(W, H, 50.0, 51.0, 31.5, 23.5)
    write_open3d_intrinsics(root / "camera_intrinsic.json", intr)
    assert read_open3d_intrinsics(root / "camera_intrinsic.json") == intr
    import_open3d(root, tmp_path / "cap")
    cap = Capture(tmp_path / "cap")
    assert cap.intrinsics()[0] == intr and cap.meta.depth_unit_mm == 1.0
    np.testing.assert_array_equal(cap.depth(1), raws[1])     # 1000 per m = mm: exact


def test_open3d_mismatched_colour_count(tmp_path):
    root = tmp_path / "o3d"
    (root / "depth").mkdir(parents=True)
    (root / "color").mkdir()
    cv2.imwrite(str(root / "depth" / "0.png"), _depth(0, 1000.0))
    cv2.imwrite(str(root / "color" / "0.jpg"), np.zeros((H, W, 3), np.uint8))
    cv2.imwrite(str(root / "color" / "1.jpg"), np.zeros((H, W, 3), np.uint8))
    with pytest.raises(FormatError, match="1 depth frames but 2 colour frames in color/"):
        import_open3d(root, tmp_path / "cap")


def test_e57_round_trip_from_ply(tmp_path):
    pytest.importorskip("pye57")
    from tofmetry.io.e57 import export_e57_cli, export_ply_cli, read_e57

    rng = np.random.default_rng(0)
    pts = rng.uniform(-2, 2, (500, 3))
    col = rng.integers(0, 256, (500, 3)).astype(np.uint8)
    write_ply(tmp_path / "c.ply", pts, colors=col)
    s = export_e57_cli(tmp_path / "c.ply", tmp_path / "c.e57")
    assert s["points"] == 500 and s["colors"]
    d = read_e57(tmp_path / "c.e57")
    # pye57 stores coordinates as single floats: 2 m * 2^-24 ~ 1.2e-7 m
    np.testing.assert_allclose(d["points"], pts, atol=3e-7)
    np.testing.assert_array_equal(d["colors"], col)
    export_ply_cli(tmp_path / "c.e57", tmp_path / "back.ply")
    np.testing.assert_allclose(read_ply(tmp_path / "back.ply")["points"], pts, atol=3e-7)
    with pytest.raises(InputError, match="already exists"):
        export_e57_cli(tmp_path / "c.ply", tmp_path / "c.e57")
