"""Models fused in the rig frame: 3 virtual sensors (random lenses near the Kinect v2's, 0.4 m apart)
calibrated by ``tofmetry calibrate rig`` on rendered board images, then one capture each (with a
colour frame) of an object 1.4 m away -> ``tofmetry reconstruct --rig`` -> the model, in the rig
frame and never aligned to the truth, lies on the true surface; a sensor knocked after the
calibration is caught by the overlap check.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.calibrate.test_rig import _rig
from tests.calibrate.test_rig_command import make_rig_dir
from tofmetry.errors import InputError
from tofmetry.io import read_ply
from tofmetry.io.rig_json import RigSensor, read_rig, write_rig
from tofmetry.sensor import Extrinsics
from tofmetry.simulate.scenes import rotation_xyz

NAMES = ["a_ref", "b_left", "c_right"]
FRAMES = 5


@pytest.fixture(scope="module")
def rig_scan(tmp_path_factory):
    """rig.json from ``calibrate rig``; scan/views/<sensor>/ one capture per sensor; the truth."""
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.io import CaptureMeta
    from tofmetry.simulate import ColourCamera, ErrorModel, VirtualKinect, datasets, render_colour
    from tofmetry.simulate.objects import textured_scene
    from tofmetry.simulate.poses import orbit_poses

    root = tmp_path_factory.mktemp("rigmodel")
    make_rig_dir(root / "boards")
    r = CliRunner().invoke(app, ["calibrate", "rig", str(root / "boards"), "--board", "9x6", "--square-mm", "50",
                                 "-o", str(root / "rig.json")])
    assert r.exit_code == 0, r.output
    intr, exts = _rig(3)  # the sensors make_rig_dir rendered
    v, f = datasets._load_mesh(None)
    scene = textured_scene(v, f, None)
    vw = scene.info["mesh_vertices_world"]
    T0 = orbit_poses(1, 1.5, 30.0, np.array([0.0, 0.0, vw[:, 2].max() / 2]))[0]  # sensor 0 -> world
    cam = ColourCamera(noise_dn=2.0)
    for k, (name, K, e) in enumerate(zip(NAMES, intr, exts)):
        T = T0 @ e.inverse().matrix  # sensor k -> rig -> world
        vk = VirtualKinect(ErrorModel.none().with_terms("noise"), seed=k, intrinsics=K)
        ts = 3600.0 + np.arange(float(FRAMES))
        datasets.write_frames(root / "scan" / "views" / name, vk.iter_frames(scene, FRAMES, T, timestamps_s=ts),
                              CaptureMeta(sensor="kinect_v2", timestamps_s=ts.tolist()),
                              colour=(render_colour(scene, cam, T, rng=np.random.default_rng(k)).image, cam))
    return {"root": root, "scan": root / "scan", "rig": root / "rig.json", "T0": T0, "intr": intr, "exts": exts,
            "mesh": (vw, scene.info["mesh_triangles"])}


def _surface_distance_mm(points_rig, rs):
    from tofmetry.evaluate import distances_to_mesh

    T0 = rs["T0"]
    return distances_to_mesh(points_rig @ T0[:3, :3].T + T0[:3, 3], *rs["mesh"]).distance * 1e3


def test_rig_model_lies_on_the_true_surface_in_the_rig_frame(rig_scan, tmp_path):
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.evaluate import distances_to_mesh
    from tofmetry.pipelines.reconstruct import reconstruct_rig

    out = tmp_path / "model"
    r = CliRunner().invoke(app, ["reconstruct", str(rig_scan["scan"]), "--rig", str(rig_scan["rig"]), "--no-calibration",
                                 "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "rig frame" in r.output and "consistent" in r.output and "coloured" in r.output
    d = json.loads((out / "poses.json").read_text())
    assert d["reliable"] and "rig frame" in d["world"] and [v["name"] for v in d["views"]] == NAMES
    sensors = read_rig(rig_scan["rig"])
    for v, s in zip(d["views"], sensors):  # poses are the rig's: camera -> rig
        np.testing.assert_allclose(v["camera_to_world"], s.rig_to_sensor.inverse().matrix, atol=1e-12)
    vox = d["diagnostics"]["fusion"]["voxel_mm"]
    pred = max(s["predicted_displacement_mm"] for s in d["diagnostics"]["rig"]["sensors"])
    assert all(e["verdict"] == "consistent" for e in d["edges"]), d["edges"]

    # the model against the truth, carried into the rig frame only by the true pose of sensor 0 (no
    # alignment): a TSDF surface lies within about half a voxel of the fused depth, the 5-frame mean
    # at 1.4 m has sigma ~0.75 mm (median |d| 0.5 mm), and the rig adds its own predicted error
    p = read_ply(out / "points.ply")
    dist = _surface_distance_mm(p["points"].astype(np.float64), rig_scan)
    med, p95, mean = np.median(np.abs(dist)), np.percentile(np.abs(dist), 95), dist.mean()
    print(f"rig model vs truth: median |d| {med:.2f} mm, P95 {p95:.2f} mm, mean {mean:+.2f} mm; voxel {vox:.2f} mm; "
          f"rig predicted <= {pred:.2f} mm; {len(dist)} points")
    assert med < 0.5 * vox + 0.5 + pred and p95 < vox + 1.5 + 2 * pred and abs(mean) < 0.5, (med, p95, mean)

    # the same captures fused at the *true* extrinsics: the rig calibration's error is all that differs
    truth = [RigSensor(s.name, k, e, s.rotation_std_deg, s.translation_std_mm)
             for s, k, e in zip(sensors, rig_scan["intr"], rig_scan["exts"])]
    ref = reconstruct_rig(rig_scan["scan"], truth)
    dd = np.abs(distances_to_mesh(p["points"], ref.mesh_vertices, ref.mesh_triangles).distance) * 1e3
    print(f"rig model vs the model at the true extrinsics: median {np.median(dd):.3f} mm, P95 {np.percentile(dd, 95):.3f} mm")
    assert np.percentile(dd, 95) < 2 * pred, (np.percentile(dd, 95), pred)

    # colour: each sensor's colour frame, occlusion-aware, as for a scan
    col = d["color"]
    assert col["views_with_color"] == 3 and col["mesh"]["share_colored"] > 0.95
    assert (read_ply(out / "mesh.ply")["colored"] > 0.5).mean() == pytest.approx(col["mesh"]["share_colored"])


def test_a_knocked_sensor_is_flagged(rig_scan, tmp_path):
    from typer.testing import CliRunner

    from tofmetry.cli import app

    sensors = read_rig(rig_scan["rig"])
    e = sensors[2].rig_to_sensor
    knocked = Extrinsics(rotation_xyz(0.0, 1.0, 0.0) @ e.rotation, e.translation, e.source, e.target)  # 1 deg of yaw
    bad = sensors[:2] + [RigSensor(sensors[2].name, sensors[2].intrinsics, knocked, sensors[2].rotation_std_deg,
                                   sensors[2].translation_std_mm)]
    write_rig(tmp_path / "knocked.json", bad)
    r = CliRunner().invoke(app, ["reconstruct", str(rig_scan["scan"]), "--rig", str(tmp_path / "knocked.json"),
                                 "--no-calibration", "--no-color", "-o", str(tmp_path / "m")])
    assert r.exit_code == 3, r.output
    d = json.loads((tmp_path / "m" / "poses.json").read_text())
    assert not d["reliable"] and d["color"] is None
    assert d["reasons"] and all("c_right" in x for x in d["reasons"]), d["reasons"]
    assert "does not fit" in r.output


def test_rig_input_errors(rig_scan, tmp_path):
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.pipelines.reconstruct import reconstruct_rig

    sensors = read_rig(rig_scan["rig"])
    renamed = [RigSensor("other" if s.name == "b_left" else s.name, s.intrinsics, s.rig_to_sensor, s.rotation_std_deg,
                         s.translation_std_mm) for s in sensors]
    with pytest.raises(InputError, match="b_left.*not sensors of the rig"):
        reconstruct_rig(rig_scan["scan"], renamed)
    with pytest.raises(InputError, match="calibrations: nope"):
        reconstruct_rig(rig_scan["scan"], sensors, calibrations={"nope": _identity_calibration()})
    run = CliRunner().invoke
    base = ["reconstruct", str(rig_scan["scan"]), "-o", str(tmp_path / "o")]
    for extra, msg in ((["--rig", str(rig_scan["rig"]), "--calibration", "c.npz"], "per sensor"),
                       (["--rig", str(rig_scan["rig"])], "either --sensor-calibration"),
                       (["--no-calibration", "--sensor-calibration", "a_ref=c.npz"], "needs --rig"),
                       (["--rig", str(rig_scan["rig"]), "--sensor-calibration", "a_ref"], "NAME=FILE")):
        r = run(app, base + extra)
        assert isinstance(r.exception, InputError) and msg in str(r.exception), (extra, r.output, r.exception)


def _identity_calibration():
    from tofmetry.calibrate.board import constant_shift_calibration
    from tofmetry.sensor import KINECT_V2

    return constant_shift_calibration(0.0, KINECT_V2.depth, sensor="kinect_v2")
