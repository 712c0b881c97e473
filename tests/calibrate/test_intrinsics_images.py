"""Checkerboard images in every format OpenCV reads: 8-bit BMP (grey and grey-in-colour), PGM,
16-bit TIFF / PNG / PGM, JPEG, .npy; clear errors for unreadable files."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from tofmetry.calibrate import normalize_ir, ray_error_px
from tofmetry.errors import FormatError, InputError
from tofmetry.io.images import GRAY_IMAGE_SUFFIXES, read_gray_image, read_ir_image

BOARD, SQ = (9, 6), 50.0


@pytest.fixture(scope="module")
def png16(tmp_path_factory):
    """8 simulated 16-bit IR images of the default board."""
    from tofmetry.simulate import datasets

    return datasets.checkerboard_images(tmp_path_factory.mktemp("fmt") / "png16", n_images=8, seed=3)


def _write(path, img):
    ok = cv2.imwrite(str(path), img)
    assert ok, path
    return path


@pytest.mark.parametrize("suffix, kind", [
    (".bmp", "u8"), (".bmp", "u8x3"), (".pgm", "u8"), (".pgm", "u16"), (".tif", "u16"), (".tiff", "u8"),
    (".png", "u16"), (".png", "u8"), (".png", "u8x3"), (".npy", "u16"), (".npy", "f32"), (".jpg", "u8x3"),
])
def test_read_gray_image_round_trip(tmp_path, suffix, kind):
    rng = np.random.default_rng(0)
    a16 = rng.integers(0, 65535, (42, 51), dtype=np.uint16)
    a8 = (a16 >> 8).astype(np.uint8)
    src = {"u8": a8, "u16": a16, "u8x3": np.dstack([a8] * 3), "f32": a16.astype(np.float32) / 7}[kind]
    f = tmp_path / f"img{suffix}"
    if suffix == ".npy":
        np.save(f, src)
    else:
        _write(f, src)
    got = read_gray_image(f)
    assert got.ndim == 2 and got.shape == (42, 51)
    expect = {"u8": a8, "u16": a16, "u8x3": a8, "f32": src}[kind]
    assert got.dtype == expect.dtype
    if suffix == ".jpg":            # lossy: grey in colour comes back close, as one channel
        assert np.abs(got.astype(int) - expect).mean() < 12
    else:
        np.testing.assert_array_equal(got, expect)
    # the IR reader keeps its contract: uint16 (8-bit promoted unscaled)
    assert read_ir_image(f).dtype == np.uint16


def test_unreadable_images_name_the_file(tmp_path):
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 20)
    with pytest.raises(FormatError, match="broken.png"):
        read_gray_image(bad)
    txt = tmp_path / "notes.bmp"
    txt.write_text("not an image")
    with pytest.raises(FormatError, match="notes.bmp"):
        read_gray_image(txt)
    with pytest.raises(FormatError, match="missing.tif"):
        read_gray_image(tmp_path / "missing.tif")
    np.save(tmp_path / "cube.npy", np.zeros((2, 3, 4, 5)))
    with pytest.raises(FormatError, match="cube.npy"):
        read_gray_image(tmp_path / "cube.npy")
    np.save(tmp_path / "neg.npy", np.full((4, 4), -3, np.int32))
    with pytest.raises(FormatError, match="neg.npy.*16 bit"):
        read_gray_image(tmp_path / "neg.npy")
    assert ".bmp" in GRAY_IMAGE_SUFFIXES and ".pgm" in GRAY_IMAGE_SUFFIXES


def test_pipeline_reads_8bit_bmp_and_other_formats(png16, tmp_path):
    """A real Kinect v2 exporter's 8-bit BMPs (and PGM, TIFF, JPEG) calibrate like the 16-bit PNGs."""
    from tofmetry.pipelines import intrinsics_from_images
    from tofmetry.sensor import CameraIntrinsics

    true = CameraIntrinsics.from_dict(json.loads((png16 / "truth.json").read_text())["true_intrinsics"])
    ref = intrinsics_from_images(png16, BOARD, SQ, leave_one_out=False)
    srcs = sorted(png16.glob("ir_*.png"))
    bmp = tmp_path / "bmp8"
    bmp.mkdir()
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for k, f in enumerate(srcs):
        img16 = read_gray_image(f)
        img8 = normalize_ir(img16)
        _write(bmp / f"ir_{k:03d}.bmp", img8)
        # mixed folder: grey-in-colour BMP, 8-bit PGM, 16-bit PGM, 16-bit TIFF, grey JPEG
        fmt = k % 5
        if fmt == 0:
            _write(mixed / f"ir_{k:03d}.bmp", np.dstack([img8] * 3))
        elif fmt == 1:
            _write(mixed / f"ir_{k:03d}.pgm", img8)
        elif fmt == 2:
            _write(mixed / f"ir_{k:03d}.pgm", img16)
        elif fmt == 3:
            _write(mixed / f"ir_{k:03d}.tif", img16)
        else:
            cv2.imwrite(str(mixed / f"ir_{k:03d}.jpg"), np.dstack([img8] * 3), [cv2.IMWRITE_JPEG_QUALITY, 95])
    (bmp / "notes.txt").write_text("ignored: not an image suffix")
    for folder in (bmp, mixed):
        run = intrinsics_from_images(folder, BOARD, SQ, leave_one_out=False)
        assert len(run.result.used) == len(srcs) and not run.rejected, folder
        # 8 bits lose a little: the ray error stays of the 16-bit run's size (measured: 16-bit
        # 0.07 px, 8-bit BMP 0.07 px, mixed 0.08 px RMS over the full grid)
        e, e_ref = ray_error_px(true, run.intrinsics).rms_px, ray_error_px(true, ref.intrinsics).rms_px
        assert e < max(2 * e_ref, 0.25), (folder.name, e, e_ref)
    assert {d["dtype"] for d in run.detections.values()} == {"uint8", "uint16"}
    # an unreadable file in the folder is named
    (mixed / "ir_999.png").write_bytes(b"\x89PNG\r\n\x1a\ntruncated")
    with pytest.raises(FormatError, match="ir_999.png"):
        intrinsics_from_images(mixed, BOARD, SQ, leave_one_out=False)
    with pytest.raises(InputError, match="no images"):
        intrinsics_from_images(_empty(tmp_path), BOARD, SQ)


def _empty(tmp_path):
    d = tmp_path / "empty"
    d.mkdir()
    (d / "readme.txt").write_text("x")
    return d
