"""Wall stations: the analytic wall render, the in-memory family path against the writer, the CLI."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.io import Capture, WallDataset
from tofmetry.pointcloud import temporal_stats
from tofmetry.sensor import KINECT_V2
from tofmetry.simulate import ErrorModel, SensorDraw, datasets, random_sensor, scenes, wall_station_means
from tofmetry.simulate.poses import look_at
from tofmetry.simulate.render import is_bare_wall, render, render_wall


def _assert_same_rendering(a, b):
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        assert x.shape == y.shape and x.dtype == y.dtype, f.name
        np.testing.assert_array_equal(x, y, err_msg=f.name)


@pytest.mark.parametrize("intr", [KINECT_V2.depth, random_sensor(4).intrinsics], ids=["kinect_v2", "random4"])
def test_analytic_wall_render_equals_the_ray_cast(intr):
    em = random_sensor(4).errors
    cases = [(0.8, (0.0, 0.0), np.eye(4)), (2.7, (1.2, -0.8), np.eye(4)), (1.3, (25.0, 40.0), np.eye(4)),
             (2.0, (0.0, 0.0), look_at((0.2, -0.1, -0.4), (0.3, 0.1, 2.0))),
             (1.0, (0.0, 80.0), np.eye(4))]  # the last one is seen edge-on: only part of the view hits it
    for dist, tilt, pose in cases:
        sc = scenes.wall(dist, tilt)
        assert is_bare_wall(sc)
        ray = render(sc, intr, pose, em, analytic_wall=False)
        _assert_same_rendering(ray, render(sc, intr, pose, em))
    assert 0 < (ray.true_depth > 0).mean() < 1
    assert not is_bare_wall(scenes.grey_board(1.0))
    with pytest.raises(Exception, match="bare wall"):
        render_wall(scenes.grey_board(1.0), intr, np.eye(4), em)


def test_in_memory_path_equals_the_dataset_writer(tmp_path):
    draw = random_sensor(9)
    dists, n = [900, 2300], 3
    out = datasets.wall_dataset(tmp_path / "w", dists, n_frames=n, seed=5, sensor=draw, tilt_jitter_deg=1.5)
    mem = wall_station_means(draw, dists, n_frames=n, seed=5, tilt_jitter_deg=1.5)
    ds = WallDataset(out, min_stations=2)
    truth = json.loads((out / "truth.json").read_text())
    assert SensorDraw.from_dict(truth["sensor"]) == draw and truth["sensor"]["describe"]["seed"] == 9
    npz = np.load(out / "truth.npz")
    for st, t, m in zip(ds.stations, truth["stations"], mem):
        assert (st.distance_mm, t["capture"]) == (m.distance_mm, m.name)
        assert t["optical_centre_mm"] == pytest.approx(m.optical_centre_mm)
        assert m.distance_mm - m.optical_centre_mm == pytest.approx(draw.errors.mounting_offset_mm)
        assert list(m.tilt_deg) == t["tilt_deg"] and m.tilt_deg != (0.0, 0.0)
        np.testing.assert_allclose(m.plane_normal, t["plane_normal"])
        assert m.plane_d_m == pytest.approx(t["plane_d_m"])
        np.testing.assert_allclose(m.true_depth_mm, npz[f"true_depth_{m.name}"], rtol=1e-6)
        cap = Capture(st.path)
        assert json.loads((st.path / "capture.json").read_text())["sensor"] == "kinect_v2"
        ref = temporal_stats(cap.depth_stack())
        keep = 2 * ref.count >= n
        np.testing.assert_array_equal(m.mean_mm, np.where(keep, ref.mean, np.nan))
        np.testing.assert_array_equal(m.std_mm, np.where(keep, ref.std, np.nan))
        np.testing.assert_array_equal(m.count, ref.count)
        assert m.n_frames == n and m.mean_mm.dtype == np.float64


def test_in_memory_nan_rule_and_explicit_tilts():
    em = ErrorModel.only("noise", "invalid")  # a wall at the 4.5 m limit: each reading valid half of the time
    draw = SensorDraw(None, "kinect_v2", KINECT_V2.depth, em)
    (m,) = wall_station_means(draw, [4500.0], n_frames=4, tilts_deg=[[0.0, 0.0]], seed=1)
    assert m.tilt_deg == (0.0, 0.0) and m.optical_centre_mm == 4500.0
    nan = np.isnan(m.mean_mm)
    np.testing.assert_array_equal(nan, 2 * m.count < 4)  # invalid in more than half of the frames
    assert nan.mean() == pytest.approx(5 / 16, abs=0.03)  # P(Binomial(4, 1/2) < 2)
    assert np.all(np.isnan(m.std_mm[nan])) and np.isfinite(m.std_mm[m.count >= 2]).all()
    (t,) = wall_station_means(draw, [1000.0], n_frames=1, tilts_deg=[[0.5, -0.5]])
    assert t.tilt_deg == (0.5, -0.5)
    np.testing.assert_allclose(t.plane_normal, scenes.wall(1.0, (0.5, -0.5)).info["plane_normal"])
    with pytest.raises(Exception, match="tilts_deg"):
        wall_station_means(draw, [1000.0, 2000.0], n_frames=1, tilts_deg=[[0.0, 0.0]])


def _run(args):
    res = CliRunner().invoke(app, ["simulate", *args])
    assert res.exit_code == 0, (res.output, res.exception)
    return res


def test_cli_wall_dataset_random_sensor_round_trip(tmp_path):
    out = tmp_path / "wd"
    _run(["wall-dataset", "-o", str(out), "--sensor", "random", "--seed", "3", "--frames", "2",
          "--distance-mm", "1000", "--distance-mm", "2000", "--distance-mm", "3000"])
    truth = json.loads((out / "truth.json").read_text())
    draw = SensorDraw.from_dict(truth["sensor"])
    assert draw == random_sensor(3) and truth["sensor"]["kind"] == "random"
    assert truth["true_intrinsics"] == draw.intrinsics.to_dict() and truth["tilt_jitter_deg"] == 1.5
    tilts = np.array([s["tilt_deg"] for s in truth["stations"]])
    assert np.all(np.hypot(tilts[:, 0], tilts[:, 1]) <= 1.5) and np.all(tilts != 0)
    for s in truth["stations"]:
        assert s["distance_mm"] - s["optical_centre_mm"] == pytest.approx(draw.errors.mounting_offset_mm)
        assert json.loads((out / s["capture"] / "capture.json").read_text())["sensor"] == "kinect_v2"
    mem = wall_station_means(draw, [1000, 2000, 3000], n_frames=2, seed=3, tilt_jitter_deg=1.5)
    ref = temporal_stats(Capture(out / "d2000").depth_stack())
    np.testing.assert_array_equal(np.isnan(mem[1].mean_mm), 2 * ref.count < 2)
    np.testing.assert_array_equal(np.nan_to_num(mem[1].mean_mm), np.nan_to_num(np.where(2 * ref.count >= 2, ref.mean, 0)))
    # the default sensor keeps frontal walls and today's record
    _run(["wall-dataset", "-o", str(tmp_path / "k"), "--frames", "1", "--distance-mm", "1500"])
    t2 = json.loads((tmp_path / "k" / "truth.json").read_text())
    assert t2["sensor"]["kind"] == "kinect_v2" and t2["stations"][0]["tilt_deg"] == [0.0, 0.0]
    res = CliRunner().invoke(app, ["simulate", "wall", "-o", str(tmp_path / "x"), "--sensor", "kinect_v3"])
    assert res.exit_code != 0 and "kinect_v3" in str(res.exception)


@pytest.mark.parametrize("cmd,args", [
    ("wall", ["--frames", "1"]),
    ("checkerboard", ["--images", "1"]),
    ("scan", ["--views", "1", "--frames", "1"]),
    ("warmup", ["--duration-s", "15", "--interval-s", "15"]),
    ("noise", ["--frames", "2"]),
    ("materials", ["--frames", "1"]),
    ("outdoor", ["--frames", "1"]),
])
def test_every_command_takes_a_random_sensor(tmp_path, cmd, args):
    out = tmp_path / cmd
    _run([cmd, "-o", str(out), "--sensor", "random", "--seed", "12", *args])
    truth = json.loads((out / "truth.json").read_text())
    assert truth["sensor"]["kind"] == "random" and truth["sensor"]["seed"] == 12
    intr = random_sensor(12).intrinsics
    assert truth["true_intrinsics"] == intr.to_dict()
    if cmd == "checkerboard":
        return
    cap = out / ("views/00" if cmd == "scan" else "capture")
    assert json.loads((cap / "capture.json").read_text())["sensor"] == "kinect_v2"
    assert Capture(cap).depth(0).any()
