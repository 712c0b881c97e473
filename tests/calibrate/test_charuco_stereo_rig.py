"""``calibrate stereo`` and ``calibrate rig`` with ``--board charuco`` on rendered views, partial views included.

Stereo: a random virtual sensor's IR amplitude image and its colour image ray cast from the colour
camera's own pose (the 1920x1080 lens at 960x540; its edge pixels integrate their area, as
``render_colour`` does by default) of a 13x10 ChArUco board placed so that it often
overhangs one image or the other. Each pair contributes the corners both cameras identified. Rig:
3 virtual Kinect v2 sensors 0.4 m apart see common board poses.

Tolerances: the refined ChArUco corners are within ~0.03 px RMS of the truth in either image
(``test_charuco``), so ~100 corners x 7-8 pairs fix the extrinsics to a few hundredths of a mm;
the 1 mm / 0.1 deg and 0.5 px held-out bounds of the checkerboard tests hold with a wide margin.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from tests.calibrate.test_rig import _rig
from tests.calibrate.test_stereo import random_colour_sensor, rotation_error_deg
from tofmetry.calibrate import CharucoBoard, calibrate_rig, common_corners
from tofmetry.cli import app
from tofmetry.errors import InputError
from tofmetry.simulate.scenes import rotation_xyz

BOARD = CharucoBoard(13, 10, 80.0, 56.0, "DICT_4X4_100")
OPTS = ["--board", "charuco", "--squares", "13x10", "--square-mm", "80", "--marker-mm", "56",
        "--dictionary", "DICT_4X4_100"]
CENTRE = np.array([6.5 * 0.08, 5 * 0.08, 0.0])          # board centre in its own frame [m]


def _scene(T):
    from tofmetry.simulate import scenes

    return scenes.charuco(BOARD.squares_x, BOARD.squares_y, BOARD.square_mm / 1e3, BOARD.marker_mm / 1e3,
                          BOARD.dictionary, board_to_world=T)


def _grey(p, label, albedo):
    return np.repeat(albedo[:, None], 3, axis=1)


def test_common_corners():
    ids, pa, pb = common_corners([1, 4, 7, 9], np.arange(8.0).reshape(4, 2), [9, 2, 4], -np.arange(6.0).reshape(3, 2))
    assert ids.tolist() == [4, 9]
    np.testing.assert_array_equal(pa, [[2, 3], [6, 7]])
    np.testing.assert_array_equal(pb, [[-4, -5], [0, -1]])
    with pytest.raises(InputError, match="one id per corner"):
        common_corners([1, 2], np.zeros((3, 2)), [1], np.zeros((1, 2)))


def test_calibrate_stereo_charuco_on_rendered_pairs(tmp_path):
    from tofmetry.io import write_intrinsics
    from tofmetry.io.iai_kinect2 import read_calib_pose
    from tofmetry.simulate import ColourCamera, ErrorModel, render, render_colour

    ir, color, truth = random_colour_sensor(4)
    color = color.scaled(960, 540)
    cam = ColourCamera(color, truth, texture=_grey, noise_dn=1.0)
    em = ErrorModel().without(*ErrorModel().enabled)
    rng = np.random.default_rng(4)
    pairs = tmp_path / "pairs"
    pairs.mkdir()
    for k in range(10):
        T = np.eye(4)
        T[:3, :3] = rotation_xyz(*rng.uniform(-30, 30, 2), rng.uniform(-10, 10))
        z = rng.uniform(0.9, 1.3)
        T[:3, 3] = np.array([rng.uniform(-0.3, 0.3) * z, rng.uniform(-0.2, 0.2) * z, z]) - T[:3, :3] @ CENTRE
        amp = render(_scene(T), ir, np.eye(4), em, supersample=3).amplitude
        cv2.imwrite(str(pairs / f"{k:04d}_ir.png"), np.clip(amp / amp.max() * 60000, 0, 65535).astype(np.uint16))
        img = render_colour(_scene(T), cam, rng=rng).image
        cv2.imwrite(str(pairs / f"{k:04d}_color.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    write_intrinsics(tmp_path / "ir.json", ir)
    write_intrinsics(tmp_path / "color.json", color)
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["calibrate", "stereo", str(pairs), *OPTS, "-o", str(out), "--ir-intrinsics",
                                   str(tmp_path / "ir.json"), "--color-intrinsics", str(tmp_path / "color.json")])
    assert res.exit_code == 0, res.output
    pose = read_calib_pose(out / "calib_pose.yaml")
    dt_mm = np.linalg.norm(pose.translation - truth.translation) * 1e3
    dr = rotation_error_deg(pose.rotation, truth.rotation)
    rep = json.loads((out / "stereo.json").read_text())
    print(f"stereo charuco: {dt_mm:.3f} mm, {dr:.4f} deg, held-out {rep['heldout_rms_px']:.3f} px RMS "
          f"(max {rep['heldout_max_px']:.3f}), corners per pair {rep['sources']['corners_per_pair']}")
    assert dt_mm < 1.0 and dr < 0.1, (dt_mm, dr)
    assert rep["n_heldout"] == 2 and rep["heldout_rms_px"] < 0.5, rep["heldout_rms_px"]
    assert not rep["skipped"] and rep["sources"]["charuco"]["squares_x"] == 13
    # partial views: some pairs use only part of the board's 108 corners
    assert sum(n < BOARD.n_corners for n in rep["sources"]["corners_per_pair"]) >= 3


def make_charuco_rig_dir(root, n_views=9):
    """3 sensors (random lenses near the Kinect v2's, 0.4 m apart), ChArUco poses 0.9-1.3 m away."""
    from tofmetry.io import write_intrinsics
    from tofmetry.io.images import write_png16
    from tofmetry.simulate import VirtualKinect

    intr, exts = _rig(3)
    cams = [VirtualKinect(seed=s, intrinsics=k, supersample=3) for s, k in enumerate(intr)]
    names = ["a_ref", "b_left", "c_right"]
    for n, k in zip(names, intr):
        (root / n).mkdir(parents=True)
        write_intrinsics(root / n / "intrinsics.json", k)
    obj = BOARD.object_points() / 1000.0
    rng = np.random.default_rng(8)
    v, partial = 0, 0
    while v < n_views:
        R = rotation_xyz(*rng.uniform(-25, 25, 2), rng.uniform(-15, 15))
        t = np.array([rng.uniform(-0.35, 0.35), rng.uniform(-0.25, 0.25), rng.uniform(0.9, 1.3)])
        T0 = np.eye(4)
        T0[:3, :3], T0[:3, 3] = R, t - R @ CENTRE
        Ts = [e.matrix @ T0 for e in exts]
        uvs = [k.project(obj @ T[:3, :3].T + T[:3, 3]) for k, T in zip(intr, Ts)]
        inside = [((uv > 10) & (uv < [k.width - 10, k.height - 10])).all(axis=1) for uv, k in zip(uvs, intr)]
        if min(i.mean() for i in inside) < 0.5:           # every sensor sees at least half the board
            continue
        partial += any(not i.all() for i in inside)
        for n, cam, T in zip(names, cams, Ts):
            fr = next(cam.iter_frames(_scene(T), 1))
            write_png16(root / n / f"{v:04d}.png", fr.ir)
        v += 1
    return root, exts, partial


def test_calibrate_rig_charuco_within_1mm_0_1deg(tmp_path):
    from tofmetry.io.rig_json import read_rig

    root, truth, partial = make_charuco_rig_dir(tmp_path / "rig")
    assert partial >= 2                               # views where a sensor sees part of the board
    out = tmp_path / "rig.json"
    r = CliRunner().invoke(app, ["calibrate", "rig", str(root), *OPTS, "-o", str(out)])
    assert r.exit_code == 0, r.output
    sensors = read_rig(out)
    d = json.loads(out.read_text())
    for i in (1, 2):
        e = sensors[i].rig_to_sensor
        dt_mm = np.linalg.norm(e.translation - truth[i].translation) * 1e3
        dr = rotation_error_deg(e.rotation, truth[i].rotation)
        print(f"rig charuco sensor {i}: {dt_mm:.3f} mm, {dr:.4f} deg, held-out {d['sensors'][i]['heldout_rms_px']:.3f} px"
              f", {d['sensors'][i]['shared_views']} shared views")
        assert dt_mm < 1.0 and dr < 0.1, (i, dt_mm, dr)
        assert 0 < max(sensors[i].translation_std_mm) < 1.0 and 0 < max(sensors[i].rotation_std_deg) < 0.1
        assert d["sensors"][i]["heldout_rms_px"] < 0.5 and d["sensors"][i]["n_heldout"] >= 2


def test_calibrate_rig_ids_errors():
    from tofmetry.sensor import KINECT_V2

    k = KINECT_V2.depth
    obj = BOARD.object_points()
    c = [[np.zeros((6, 2))] * 3, [np.zeros((6, 2))] * 3]
    with pytest.raises(InputError, match="corner ids for 2 sensors x 3 views"):
        calibrate_rig([obj] * 3, c, [k, k], ids=[[np.arange(6)] * 3])
    # views with fewer than min_common corners in common do not count as shared
    ids = [[np.arange(6)] * 3, [np.arange(3, 9)] * 3]
    with pytest.raises(InputError, match="shares 0 board views"):
        calibrate_rig([obj] * 3, c, [k, k], ids=ids)


def test_stereo_charuco_pairs_without_board_are_named(tmp_path):
    from tofmetry.pipelines.stereo import stereo_from_images
    from tofmetry.sensor import KINECT_V2

    ir, color = KINECT_V2.depth, KINECT_V2.color.scaled(960, 540)
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"{k:04d}_ir.png"), np.full(ir.shape, 20000, np.uint16))
        cv2.imwrite(str(tmp_path / f"{k:04d}_color.png"), np.full((*color.shape, 3), 128, np.uint8))
    with pytest.raises(InputError, match=r"0 pair\(s\).*0000.*fewer than 6 ChArUco corners found in the IR image"):
        stereo_from_images(tmp_path, BOARD.inner, BOARD.square_mm, ir, color, charuco=BOARD)
