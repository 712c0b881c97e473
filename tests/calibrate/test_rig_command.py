"""``tofmetry calibrate rig`` on rendered IR images of 3 virtual sensors seeing common board poses:
every sensor's extrinsics within 1 mm / 0.1 deg of the truth, uncertainties reported, rig.json
round-trips, clear errors for a bad folder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.calibrate.test_rig import _rig
from tests.calibrate.test_stereo import rotation_error_deg
from tofmetry.calibrate import board_object_points
from tofmetry.errors import InputError
from tofmetry.simulate.scenes import rotation_xyz

BOARD, SQ = (9, 6), 50.0


@pytest.fixture(scope="module")
def rig_dir(tmp_path_factory):
    return make_rig_dir(tmp_path_factory.mktemp("rig") / "rig")


def make_rig_dir(root):
    """3 sensors (random lenses near the Kinect v2's, 0.4 m apart), 12 board poses 1.1-1.5 m away."""
    from tofmetry.io import write_intrinsics
    from tofmetry.io.images import write_png16
    from tofmetry.simulate import VirtualKinect, scenes

    intr, exts = _rig(3)
    cams = [VirtualKinect(seed=s, intrinsics=k, supersample=3) for s, k in enumerate(intr)]
    names = ["a_ref", "b_left", "c_right"]
    for n, k in zip(names, intr):
        (root / n).mkdir(parents=True)
        write_intrinsics(root / n / "intrinsics.json", k)
    obj = board_object_points(BOARD, SQ) / 1000.0
    rng = np.random.default_rng(8)
    v = 0
    while v < 12:
        R = rotation_xyz(*rng.uniform(-25, 25, 2), rng.uniform(-15, 15))
        t = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), rng.uniform(1.1, 1.5)])
        T0 = np.eye(4)
        T0[:3, :3], T0[:3, 3] = R, t - R @ obj.mean(axis=0)
        Ts = [e.matrix @ T0 for e in exts]
        uvs = [k.project(obj @ T[:3, :3].T + T[:3, 3]) for k, T in zip(intr, Ts)]
        if not all(((uv > 25) & (uv < [k.width - 25, k.height - 25])).all() for uv, k in zip(uvs, intr)):
            continue
        for n, cam, T in zip(names, cams, Ts):
            fr = next(cam.iter_frames(scenes.checkerboard(*BOARD, SQ / 1000.0, T), 1))
            write_png16(root / n / f"{v:04d}.png", fr.ir)
        v += 1
    return root, exts


def test_rig_command_within_1mm_0_1deg_and_round_trip(rig_dir, tmp_path):
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.io.rig_json import read_rig, write_rig

    root, truth = rig_dir
    out = tmp_path / "rig.json"
    r = CliRunner().invoke(app, ["calibrate", "rig", str(root), "--board", "9x6", "--square-mm", "50", "-o", str(out)])
    assert r.exit_code == 0, r.output
    sensors = read_rig(out)
    assert [s.name for s in sensors] == ["a_ref", "b_left", "c_right"]
    d = json.loads(out.read_text())
    for i in (1, 2):
        e = sensors[i].rig_to_sensor
        dt_mm = np.linalg.norm(e.translation - truth[i].translation) * 1e3
        dr = rotation_error_deg(e.rotation, truth[i].rotation)
        assert dt_mm < 1.0 and dr < 0.1, (i, dt_mm, dr)
        assert 0 < max(sensors[i].translation_std_mm) < 1.0 and 0 < max(sensors[i].rotation_std_deg) < 0.1
        assert d["sensors"][i]["heldout_rms_px"] < 0.5 and d["sensors"][i]["n_heldout"] >= 2
    # round trip
    again = tmp_path / "again.json"
    write_rig(again, sensors)
    back = read_rig(again)
    for a, b in zip(sensors, back):
        assert a.name == b.name and a.intrinsics == b.intrinsics
        np.testing.assert_array_equal(a.rig_to_sensor.matrix, b.rig_to_sensor.matrix)
        assert a.translation_std_mm == b.translation_std_mm and a.rotation_std_deg == b.rotation_std_deg


def test_rig_folder_errors(tmp_path):
    from tofmetry.io import write_intrinsics
    from tofmetry.io.rig_json import read_rig
    from tofmetry.pipelines.rig import rig_from_folders
    from tofmetry.sensor import KINECT_V2

    (tmp_path / "only").mkdir()
    write_intrinsics(tmp_path / "only" / "intrinsics.json", KINECT_V2.depth)
    with pytest.raises(InputError, match="one sub-folder per sensor"):
        rig_from_folders(tmp_path, BOARD, SQ)
    (tmp_path / "bad.json").write_text('{"format": "other"}')
    with pytest.raises(InputError, match="tofmetry-rig"):
        read_rig(tmp_path / "bad.json")
