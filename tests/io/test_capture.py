"""Capture folder contract: round trip, atomic writes, and every bad-input case."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from tofmetry.errors import FormatError, InputError
from tofmetry.io import Capture, CaptureMeta, CaptureWriter, EmptyFrameWarning, write_capture
from tofmetry.sensor import KINECT_V2

H, W = 424, 512


def _frames(n=3, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 4500, size=(H, W), dtype=np.uint16) for _ in range(n)]


def test_round_trip_depth_ir_color_and_meta(tmp_path):
    depth = _frames(3)
    ir = [f // 2 for f in _frames(3, 1)]
    color = [np.full((1080, 1920, 3), 100 + 10 * i, np.uint8) for i in range(3)]
    meta = CaptureMeta(sensor="kinect_v2", intrinsics=KINECT_V2.depth, timestamps_s=[0.0, 1.0, 2.0])
    write_capture(tmp_path / "cap", depth, meta, ir_frames=ir, color_frames=color)
    cap = Capture(tmp_path / "cap")
    assert len(cap) == 3 and cap.shape == (H, W) and cap.sensor == "kinect_v2"
    for i in range(3):
        assert np.array_equal(cap[i], depth[i])
        assert np.array_equal(cap.ir(i), ir[i])
    assert abs(int(cap.color(1)[0, 0, 0]) - 110) <= 2  # JPEG
    assert cap.meta.intrinsics == KINECT_V2.depth
    assert np.allclose(cap.timestamps_s, [0, 1, 2])
    assert np.array_equal(cap.depth_stack(), np.stack(depth))


def test_refuses_to_overwrite_without_force_and_is_atomic(tmp_path):
    write_capture(tmp_path / "cap", _frames(1))
    with pytest.raises(InputError, match="--force"):
        write_capture(tmp_path / "cap", _frames(2))
    assert len(Capture(tmp_path / "cap")) == 1
    # a failure mid-way leaves neither a partial capture nor temp folders
    with pytest.raises(FormatError):
        with CaptureWriter(tmp_path / "bad") as w:
            w.add(_frames(1)[0])
            w.add(np.zeros((10, 10), np.uint16))
    assert not (tmp_path / "bad").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["cap"]
    write_capture(tmp_path / "cap", _frames(2), force=True)
    assert len(Capture(tmp_path / "cap")) == 2


def test_tiff_and_npy_depth_are_read(tmp_path):
    d = _frames(1)[0]
    (tmp_path / "c" / "depth").mkdir(parents=True)
    cv2.imwrite(str(tmp_path / "c" / "depth" / "000000.tif"), d)
    np.save(tmp_path / "c" / "depth" / "000001.npy", d)
    (tmp_path / "c" / "capture.json").write_text(json.dumps({"sensor": "kinect_v2", "depth_unit_mm": 1.0}))
    cap = Capture(tmp_path / "c")
    assert np.array_equal(cap[0], d) and np.array_equal(cap[1], d)


def _raw_capture(tmp_path, imgs, meta=None):
    c = tmp_path / "raw"
    (c / "depth").mkdir(parents=True)
    for i, img in enumerate(imgs):
        cv2.imwrite(str(c / "depth" / f"{i:06d}.png"), img)
    (c / "capture.json").write_text(json.dumps(meta or {"sensor": "kinect_v2", "depth_unit_mm": 1.0}))
    return c


def test_wrong_bit_depth_names_file(tmp_path):
    c = _raw_capture(tmp_path, [np.zeros((H, W), np.uint8)])
    with pytest.raises(FormatError, match=r"000000\.png.*16-bit"):
        Capture(c)


def test_wrong_resolution_names_file(tmp_path):
    c = _raw_capture(tmp_path, [np.ones((480, 640), np.uint16)])
    with pytest.raises(FormatError, match=r"000000\.png.*640x480.*512x424"):
        Capture(c)


def test_mixed_sizes(tmp_path):
    c = _raw_capture(tmp_path, [np.ones((10, 10), np.uint16), np.ones((12, 10), np.uint16)], {"sensor": "other"})
    with pytest.raises(FormatError, match="mixed size"):
        Capture(c)


def test_no_frames(tmp_path):
    (tmp_path / "e" / "depth").mkdir(parents=True)
    with pytest.raises(FormatError, match="no depth frames"):
        Capture(tmp_path / "e")


def test_truncated_png(tmp_path):
    c = _raw_capture(tmp_path, [_frames(1)[0]])
    f = c / "depth" / "000000.png"
    f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 2])
    cap = Capture(c)  # header intact: detected when decoded
    with pytest.raises(FormatError, match=r"000000\.png.*(unreadable|truncated)"):
        cap[0]


def test_not_a_png(tmp_path):
    c = _raw_capture(tmp_path, [_frames(1)[0]])
    (c / "depth" / "000000.png").write_bytes(b"garbage")
    with pytest.raises(FormatError, match="not a PNG"):
        Capture(c)


def test_all_zero_frame_warns_not_crashes(tmp_path):
    write_capture(tmp_path / "z", [np.zeros((H, W), np.uint16)])
    cap = Capture(tmp_path / "z")
    with pytest.warns(EmptyFrameWarning, match="all-zero"):
        d = cap[0]
    assert not d.any()


def test_timestamps_count_mismatch(tmp_path):
    c = _raw_capture(tmp_path, [_frames(1)[0]], {"sensor": "kinect_v2", "timestamps_s": [0.0, 1.0]})
    with pytest.raises(FormatError, match="timestamps"):
        Capture(c)


def test_missing_folder(tmp_path):
    with pytest.raises(InputError, match="not found"):
        Capture(tmp_path / "nope")
