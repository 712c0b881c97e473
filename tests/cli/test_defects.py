"""The defects of issue 17 ("Losing data or trust"), each reproduced as a user meets it."""

from __future__ import annotations

import json
import shutil
import zipfile

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.errors import ImplausibleResultError, InputError, TofmetryError
from tofmetry.io import WallDataset, write_stations_csv

runner = CliRunner()


def _run(*args):
    return runner.invoke(app, [str(a) for a in args])


# ------------------------------------------------------------------ a file that is not a calibration
def _not_calibrations(tmp_path):
    """Files a user may pass by mistake as --calibration."""
    files = {}
    (tmp_path / "text.npz").write_text("hello, not a calibration\n")
    files["text"] = tmp_path / "text.npz"
    import cv2

    (tmp_path / "image.npz").write_bytes(cv2.imencode(".png", np.zeros((8, 8), np.uint16))[1].tobytes())
    files["png"] = tmp_path / "image.npz"
    np.save(tmp_path / "array.npy", np.zeros(3))
    files["npy"] = tmp_path / "array.npy"
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    files["other npz"] = tmp_path / "other.npz"
    np.savez(tmp_path / "objects.npz", header=np.array([{"format": "x"}], dtype=object))
    files["object header"] = tmp_path / "objects.npz"
    np.savez(tmp_path / "bare.npz", header=np.array(json.dumps({"format": "tofmetry-depth-calibration", "version": 2})),
             range_knots=np.zeros(3), range_coeffs=np.zeros(3), node_mm=np.zeros(1), surfaces=np.zeros((1, 2, 2)))
    files["header without fields"] = tmp_path / "bare.npz"
    with zipfile.ZipFile(tmp_path / "zip.npz", "w") as z:
        z.writestr("header.npy", b"garbage")
    files["broken zip member"] = tmp_path / "zip.npz"
    return files


def test_a_file_that_is_not_a_calibration_gets_tofmetrys_own_error(tmp_path, small_wall, one_capture):
    scan_dir = tmp_path / "scan" / "views" / "00"
    shutil.copytree(one_capture, scan_dir)
    for label, f in _not_calibrations(tmp_path).items():
        paths = {
            "cloud": ("cloud", one_capture, "--calibration", f, "-o", tmp_path / "c.ply"),
            "correct": ("correct", one_capture, "--calibration", f, "-o", tmp_path / "corr"),
            "info": ("info", f),
            "validate": ("calibrate", "validate", small_wall, "--calibration", f),
            "reconstruct": ("reconstruct", tmp_path / "scan", "--calibration", f, "-o", tmp_path / "model"),
            "export": ("export", "iai-kinect2", f, "-o", tmp_path / "iai"),
        }
        for cmd, args in paths.items():
            if cmd == "info" and f.suffix != ".npz":
                continue
            r = _run(*args)
            assert isinstance(r.exception, TofmetryError), (label, cmd, r.output, r.exception)
            msg = str(r.exception)
            assert f.name in msg, (label, cmd, msg)
            assert "pickle" not in msg.lower(), (label, cmd, msg)
            assert "not a tofmetry calibration" in msg or "calibration" in msg, (label, cmd, msg)
    assert not (tmp_path / "c.ply").exists() and not (tmp_path / "corr").exists()


# ------------------------------------------------------------------ info on a truncated frame
def test_info_does_not_call_a_capture_with_a_truncated_frame_valid(tmp_path, one_capture):
    cap = shutil.copytree(one_capture, tmp_path / "cap")
    src = sorted((cap / "depth").glob("*.png"))[0]
    for i in range(3, 40):                               # 40 frames: info used to sample every 2nd frame only
        shutil.copyfile(src, cap / "depth" / f"{i:06d}.png")
        shutil.copyfile(cap / "ir" / src.name, cap / "ir" / f"{i:06d}.png")
    meta = json.loads((cap / "capture.json").read_text())
    meta.pop("timestamps_s", None)
    (cap / "capture.json").write_text(json.dumps(meta))
    f = sorted((cap / "depth").glob("*.png"))[1]
    f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 2])
    r = _run("info", cap)
    assert r.exit_code != 0
    assert "valid capture" not in r.output
    assert isinstance(r.exception, TofmetryError) and f.name in str(r.exception), r.output


# ------------------------------------------------------------------ cloud: every pixel outside the support
def test_cloud_refuses_a_capture_entirely_outside_the_calibrations_support(tmp_path, small_cal):
    from tofmetry.simulate import datasets

    far = datasets.wall_capture(tmp_path / "far", distance_mm=4300, n_frames=2, seed=3) / "capture"
    for args in (("cloud", far, "--calibration", small_cal, "-o", tmp_path / "far.ply"),
                 ("cloud", far, "--calibration", small_cal, "-o", tmp_path / "far.ply", "--average"),
                 ("correct", far, "--calibration", small_cal, "-o", tmp_path / "farc")):
        r = _run(*args)
        assert isinstance(r.exception, ImplausibleResultError), (args, r.output)
        assert "outside" in str(r.exception) and "--accept-implausible" in str(r.exception)
    assert not (tmp_path / "far.ply").exists() and not (tmp_path / "farc").exists()
    r = _run("cloud", far, "--calibration", small_cal, "-o", tmp_path / "far.ply", "--accept-implausible")
    assert r.exit_code == 0, r.output
    assert "outside" in r.output and (tmp_path / "far.ply").is_file()
    assert b"accepted implausible" in (tmp_path / "far.ply").read_bytes()[:2000]


# ------------------------------------------------------------------ study: a failed stage is not exit 0
def test_study_exits_non_zero_when_a_stage_fails(tmp_path):
    from tofmetry.simulate import datasets

    data = tmp_path / "data"
    datasets.noise(data / "noise", n_frames=12, seed=2)
    (data / "warmup").mkdir()                          # present but empty: that stage fails
    r = _run("study", data, "-o", tmp_path / "out")
    assert r.exit_code == 1, r.output
    assert "warmup" in r.output and "failed" in r.output
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert rep["stages"]["warmup"]["status"] == "failed" and rep["stages"]["noise"]["status"] == "ok"
    assert (tmp_path / "out" / "report.html").is_file()   # the report is still written


# ------------------------------------------------------------------ writing into the input folder
def test_refusal_to_write_into_the_input_names_the_paths(tmp_path, one_capture, small_cal, monkeypatch):
    cap = shutil.copytree(one_capture, tmp_path / "cap")
    monkeypatch.chdir(cap)
    for args in (("correct", ".", "--calibration", small_cal, "-o", ".", "--force"),
                 ("correct", ".", "--calibration", small_cal, "-o", "corrected"),
                 ("filter", ".", "-o", "filtered"),
                 ("cloud", ".", "-o", "cloud.ply")):
        r = _run(*args)
        assert isinstance(r.exception, InputError), (args, r.output)
        msg = str(r.exception)
        assert str(cap.resolve()) in msg, (args, msg)            # the absolute path, not "."
    assert sorted(p.name for p in cap.iterdir()) == sorted(p.name for p in one_capture.iterdir())


# ------------------------------------------------------------------ stations.csv escaping its folder
def test_stations_csv_entry_outside_the_dataset_is_refused(tmp_path, small_wall):
    ds = shutil.copytree(small_wall, tmp_path / "ds" / "wall")
    st = WallDataset(ds).stations
    shutil.copytree(st[1].path, tmp_path / "ds" / "outside" / "capture")
    rows = [(s.name, s.distance_mm) for s in st[:3]] + [("../outside/capture", 3500.0)]
    write_stations_csv(ds / "stations.csv", rows)
    r = _run("calibrate", "depth", ds, "-o", tmp_path / "cal.npz")
    assert isinstance(r.exception, InputError), r.output
    assert "../outside/capture" in str(r.exception) and "outside" in str(r.exception)
    assert not (tmp_path / "cal.npz").exists()
    write_stations_csv(ds / "stations.csv", [(s.name, s.distance_mm) for s in st[:3]] + [(str(st[3].path), 3500.0)])
    r = _run("calibrate", "depth", ds, "-o", tmp_path / "cal.npz")
    assert isinstance(r.exception, InputError) and "absolute" in str(r.exception), r.output


def test_a_stated_distance_the_sensor_contradicts_is_not_fitted(tmp_path, small_wall):
    """A station stated at 2000 mm whose wall the sensor sees at about 985 mm (a typo, a wrong folder)."""
    from tofmetry.simulate import datasets

    ds = shutil.copytree(small_wall, tmp_path / "wall")
    datasets.wall_capture(tmp_path / "near", distance_mm=985, n_frames=3, seed=5)
    shutil.copytree(tmp_path / "near" / "capture", ds / "wrong")
    st = WallDataset(ds).stations
    rows = [(s.name, s.distance_mm) for s in st[:2]] + [("wrong", 2000.0)] + [(s.name, s.distance_mm) for s in st[3:]]
    write_stations_csv(ds / "stations.csv", rows)
    r = _run("calibrate", "depth", ds, "-o", tmp_path / "cal.npz")
    assert isinstance(r.exception, ImplausibleResultError), r.output
    msg = str(r.exception)
    assert "wrong" in msg and "2000" in msg and "--accept-implausible" in msg
    assert not (tmp_path / "cal.npz").exists()
    r = _run("calibrate", "depth", ds, "-o", tmp_path / "cal.npz", "--accept-implausible", "--report", tmp_path / "rep")
    assert r.exit_code == 0, r.output
    assert "implausible" in r.output
    fit = json.loads((tmp_path / "rep" / "fit.json").read_text())
    assert fit["plausibility"]["accepted"] is True and any("wrong" in f for f in fit["plausibility"]["findings"])
    from tofmetry.pipelines import load_calibration

    assert load_calibration(tmp_path / "cal.npz").provenance["plausibility"]["accepted"] is True


# ------------------------------------------------------------------ a wrong --board size
def test_a_wrong_board_size_fails_and_calib_ir_is_not_overwritten(tmp_path):
    from tofmetry.simulate import datasets

    imgs = datasets.checkerboard_images(tmp_path / "imgs", n_images=20, seed=0)
    r = _run("calibrate", "intrinsics", imgs, "--board", "9x6", "--square-mm", "50", "-o", tmp_path / "a" / "intr.json",
             "--no-loo")
    assert r.exit_code == 0, r.output
    yaml = tmp_path / "a" / "calib_ir.yaml"
    before = yaml.read_bytes()
    r = _run("calibrate", "intrinsics", imgs, "--board", "5x4", "--square-mm", "50", "-o", tmp_path / "b" / "other.json",
             "--no-loo")
    assert isinstance(r.exception, ImplausibleResultError), r.output
    assert "reprojection RMS" in str(r.exception) and "--accept-implausible" in str(r.exception)
    assert not (tmp_path / "b").exists() or not any((tmp_path / "b").iterdir())
    assert yaml.read_bytes() == before
    # a second correct run into the same folder must not replace calib_ir.yaml without --force
    r = _run("calibrate", "intrinsics", imgs, "--board", "9x6", "--square-mm", "50", "-o", tmp_path / "a" / "third.json",
             "--no-loo")
    assert isinstance(r.exception, InputError) and "calib_ir.yaml" in str(r.exception), r.output
    assert not (tmp_path / "a" / "third.json").exists() and yaml.read_bytes() == before
