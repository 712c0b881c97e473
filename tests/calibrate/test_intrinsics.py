"""Checkerboard intrinsics: render a board with a known camera -> detect -> calibrate -> compare."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.calibrate._intrinsics import (
    PARAMS, board_object_points, calibrate_intrinsics, coverage_mask, detect_corners, normalize_ir, ray_difference_px,
)
from tofmetry.cli import app
from tofmetry.errors import EstimationError
from tofmetry.io import read_intrinsics
from tofmetry.io.images import write_png16
from tofmetry.sensor import CameraIntrinsics

TRUE = CameraIntrinsics(320, 256, 230.0, 231.0, 161.3, 126.4, (0.09, -0.25, 0.001, -0.0005, 0.08))
BOARD = (7, 5)
SQ = 30.0  # mm


def _rot(rx, ry, rz):
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


_RAYS = {}


def _sub_rays(intr, ss):
    """Undistorted rays of the ss x ss sub-pixel samples (computed once per camera)."""
    key = (intr, ss)
    if key not in _RAYS:
        h, w = intr.shape
        off = (np.arange(ss) + 0.5) / ss - 0.5
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        rays = []
        for dy in off:
            for dx in off:
                xy = intr.pixel_to_normalized(np.column_stack([(u + dx).ravel(), (v + dy).ravel()]))
                rays.append(np.column_stack([xy, np.ones(len(xy))]))
        _RAYS[key] = rays
    return _RAYS[key]


def render_board(intr, R, t, ss=3, amp=3000.0):
    """IR image (uint16, dark) of a checkerboard: board frame origin at the first inner corner [mm]."""
    h, w = intr.shape
    acc = np.zeros((h, w))
    n = R[:, 2]
    for d in _sub_rays(intr, ss):
        s = (n @ t) / (d @ n)  # ray-plane intersection
        p = (d * s[:, None] - t) @ R  # board coordinates [mm]
        i, j = np.floor(p[:, 0] / SQ), np.floor(p[:, 1] / SQ)
        inside = (i >= -1) & (i <= BOARD[0] - 1) & (j >= -1) & (j <= BOARD[1] - 1)
        margin = (i >= -2) & (i <= BOARD[0]) & (j >= -2) & (j <= BOARD[1])
        val = np.where(inside, np.where((i + j) % 2 == 0, 0.15, 0.85), np.where(margin, 0.85, 0.4))
        acc += np.where(s > 0, val, 0.4).reshape(h, w)
    return np.round(acc / ss ** 2 * amp).astype(np.uint16)


def _poses(n, seed):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        z = rng.uniform(450, 750)
        # aim the board centre at a 3x3 grid of image positions (covers the corners)
        gx, gy = (k % 3 - 1) * 0.42, ((k // 3) % 3 - 1) * 0.36
        R = _rot(np.deg2rad(rng.uniform(-30, 30)), np.deg2rad(rng.uniform(-30, 30)), np.deg2rad(rng.uniform(-15, 15)))
        centre = np.array([(BOARD[0] - 1) * SQ / 2, (BOARD[1] - 1) * SQ / 2, 0])
        t = np.array([gx * z, gy * z, z]) - R @ centre
        out.append((R, t))
    return out


@pytest.fixture(scope="module")
def board_images(tmp_path_factory):
    d = tmp_path_factory.mktemp("board")
    for k, (R, t) in enumerate(_poses(12, 0)):
        write_png16(d / f"ir_{k:03d}.png", render_board(TRUE, R, t))
    write_png16(d / "ir_blank.png", np.full(TRUE.shape[::-1][::-1], 900, np.uint16))
    return d


def test_detect_and_calibrate(board_images):
    from tofmetry.io.images import read_ir_image

    corners, names = [], []
    for f in sorted(board_images.glob("ir_0*.png")):
        c = detect_corners(normalize_ir(read_ir_image(f)), BOARD)
        assert c is not None, f
        corners.append(c)
        names.append(f.name)
    res = calibrate_intrinsics(corners, names, BOARD, SQ, (TRUE.width, TRUE.height))
    est = res.intrinsics
    truth = dict(zip(PARAMS, [TRUE.fx, TRUE.fy, TRUE.cx, TRUE.cy, *TRUE.distortion]))
    got = dict(zip(PARAMS, [est.fx, est.fy, est.cx, est.cy, *est.distortion]))
    for p in PARAMS:
        # each parameter within 4 of its own standard uncertainties (+ a tiny absolute floor
        # for the anti-aliasing bias of the renderer, 3x3 supersampling)
        assert abs(got[p] - truth[p]) < 4 * res.std[p] + 1e-4, (p, got[p], truth[p], res.std[p])
    assert res.rms_px < 0.2  # noise-free rendering: corner error is sub-pixel interpolation only
    assert set(res.per_image_rms_px) == set(names) and set(res.loo) == set(PARAMS)
    mask = coverage_mask(corners, TRUE.shape)
    diff = ray_difference_px(TRUE, est, mask)
    # Rays over the covered area: the estimate's own 1-sigma ray error there is about
    # sigma_c + |x| sigma_f ~ 0.8 + 0.7 x 1.9 ~ 2 px with 12 boards whose corners carry a
    # ~0.05 px per-image bias (anti-aliasing of the 3x3 supersampled render); require < 2 sigma
    # at the worst pixel and < 1 sigma in RMS.
    scale = max(res.std["cx"], res.std["cy"]) + 0.7 * max(res.std["fx"], res.std["fy"])
    assert np.nanmax(diff) < 2 * scale and np.sqrt(np.nanmean(diff ** 2)) < scale


def test_coverage_warning_and_too_few():
    rng = np.random.default_rng(1)
    obj = board_object_points(BOARD, SQ)
    corners = []
    for _k in range(5):  # boards only in the centre of the image, small
        R = _rot(*np.deg2rad(rng.uniform(-20, 20, 3)))
        t = np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), 900.0]) - R @ np.array([90.0, 60.0, 0])
        corners.append(TRUE.project(obj @ R.T + t).astype(np.float32))
    res = calibrate_intrinsics(corners, [f"i{k}" for k in range(5)], BOARD, SQ, (TRUE.width, TRUE.height), fix_k3=True)
    assert any("cover" in w for w in res.warnings)
    with pytest.raises(EstimationError, match="at least 3"):
        calibrate_intrinsics(corners[:2], ["a", "b"], BOARD, SQ, (TRUE.width, TRUE.height))


def test_cli_intrinsics(board_images, tmp_path):
    out = tmp_path / "intrinsics.json"
    r = CliRunner().invoke(app, ["calibrate", "intrinsics", str(board_images), "--board", "7x5", "--square-mm", "30",
                                 "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "ir_blank.png" in r.output  # rejected and reported
    intr = read_intrinsics(out)
    assert abs(intr.fx - TRUE.fx) < 3.0
    rep = json.loads((tmp_path / "intrinsics_report" / "intrinsics_report.json").read_text())
    assert rep["rejected"] == ["ir_blank.png"] and "leave_one_out_std" in rep
    assert (tmp_path / "intrinsics_report" / "coverage.png").stat().st_size > 5_000
    yml = (tmp_path / "calib_ir.yaml").read_text()
    assert "cameraMatrix" in yml and "opencv-matrix" in yml
