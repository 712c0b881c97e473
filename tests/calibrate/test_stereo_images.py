"""``tofmetry calibrate stereo`` end to end on rendered board images of a random virtual sensor.

Geometry (board poses, true extrinsics) -> the IR amplitude image rendered by the virtual sensor
and the colour image ray cast from the colour camera's own pose -> corners detected in both ->
extrinsics -> ``calib_pose.yaml`` read back and compared with the truth. The colour camera is the
1920x1080 lens resampled to 960x540 to keep the test short (edge pixels integrate their area,
``render_colour``'s supersampling; detection errors ~0.1 px in either image).
"""

from __future__ import annotations

import json

import cv2
import numpy as np
from typer.testing import CliRunner

from tests.calibrate.test_stereo import BOARD, SQUARE_MM, random_colour_sensor, rotation_error_deg
from tofmetry.cli import app
from tofmetry.io import write_intrinsics
from tofmetry.io.iai_kinect2 import read_calib_pose
from tofmetry.simulate import ColourCamera, ErrorModel, render, render_colour, scenes
from tofmetry.simulate.scenes import rotation_xyz


def _grey(p, label, albedo):
    return np.repeat(albedo[:, None], 3, axis=1)


def test_calibrate_stereo_cli_on_rendered_pairs(tmp_path):
    ir, color, truth = random_colour_sensor(4)
    color = color.scaled(960, 540)
    cam = ColourCamera(color, truth, texture=_grey, noise_dn=1.0)
    em = ErrorModel().without(*ErrorModel().enabled)
    rng = np.random.default_rng(4)
    pairs = tmp_path / "pairs"
    pairs.mkdir()
    s = SQUARE_MM * 1e-3
    centre = np.array([(BOARD[0] - 1) * s / 2, (BOARD[1] - 1) * s / 2, 0.0])
    for k in range(12):
        T = np.eye(4)
        T[:3, :3] = rotation_xyz(*rng.uniform(-30, 30, 2), rng.uniform(-10, 10))
        z = rng.uniform(0.8, 1.3)
        T[:3, 3] = np.array([rng.uniform(-0.15, 0.15) * z, rng.uniform(-0.1, 0.1) * z, z]) - T[:3, :3] @ centre
        scene = scenes.checkerboard(BOARD[0], BOARD[1], s, T)
        amp = render(scene, ir, np.eye(4), em, supersample=4).amplitude
        cv2.imwrite(str(pairs / f"{k:04d}_ir.png"), np.clip(amp / amp.max() * 60000, 0, 65535).astype(np.uint16))
        img = render_colour(scene, cam, rng=rng).image
        cv2.imwrite(str(pairs / f"{k:04d}_color.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    write_intrinsics(tmp_path / "ir.json", ir)
    write_intrinsics(tmp_path / "color.json", color)
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["calibrate", "stereo", str(pairs), "--board", f"{BOARD[0]}x{BOARD[1]}",
                                   "--square-mm", str(SQUARE_MM), "-o", str(out), "--ir-intrinsics",
                                   str(tmp_path / "ir.json"), "--color-intrinsics", str(tmp_path / "color.json")])
    assert res.exit_code == 0, res.output
    assert "held-out" in res.output
    pose = read_calib_pose(out / "calib_pose.yaml")
    dt_mm = np.linalg.norm(pose.translation - truth.translation) * 1e3
    dr = rotation_error_deg(pose.rotation, truth.rotation)
    rep = json.loads((out / "stereo.json").read_text())
    print(f"stereo checkerboard: {dt_mm:.3f} mm, {dr:.4f} deg, held-out {rep['heldout_rms_px']:.3f} px RMS "
          f"(max {rep['heldout_max_px']:.3f})")
    assert dt_mm < 1.0 and dr < 0.1, (dt_mm, dr)
    assert rep["n_heldout"] == 3 and rep["heldout_rms_px"] < 0.5, rep["heldout_rms_px"]
    assert len(rep["translation_std_mm"]) == 3 and not rep["skipped"]
    # the outputs exist now: a second run refuses to overwrite them
    again = CliRunner().invoke(app, ["calibrate", "stereo", str(pairs), "--board", "9x6", "--square-mm", "50",
                                     "-o", str(out)])
    assert again.exit_code != 0 and "--force" in str(again.exception)
