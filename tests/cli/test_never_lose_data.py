"""Never lose data: inputs stay byte-identical, nothing is replaced without --force, paths stay inside
their dataset, and an interrupted command leaves nothing that looks complete."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.errors import InputError

from .conftest import tree_hash

runner = CliRunner()


def _run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def board_images(tmp_path_factory):
    from tofmetry.simulate import datasets

    return datasets.checkerboard_images(tmp_path_factory.mktemp("nl") / "imgs", n_images=8, seed=4)


def test_inputs_stay_identical_and_nothing_is_replaced_without_force(tmp_path, small_wall, small_cal, one_capture,
                                                                    board_images):
    """Each command runs once (inputs hashed before and after), then again: refused, outputs untouched."""
    data = tmp_path / "in"
    wall = shutil.copytree(small_wall, data / "wall")
    cap = shutil.copytree(one_capture, data / "cap")
    cal = shutil.copy(small_cal, data / "cal.npz")
    imgs = shutil.copytree(board_images, data / "imgs")
    out = tmp_path / "out"
    out.mkdir()
    commands = [
        ("info", cap),
        ("info", cal),
        ("cloud", cap, "--calibration", cal, "-o", out / "c.ply"),
        ("correct", cap, "--calibration", cal, "-o", out / "corr"),
        ("filter", cap, "-o", out / "filt"),
        ("assess", "noise", cap, "-o", out / "noise"),
        ("calibrate", "intrinsics", imgs, "--board", "9x6", "--square-mm", "50", "-o", out / "intr.json", "--no-loo"),
        ("calibrate", "depth", wall, "-o", out / "cal2.npz", "--report", out / "rep"),
        ("calibrate", "validate", wall, "--calibration", cal, "-o", out / "val"),
        ("export", "iai-kinect2", cal, "-o", out / "iai"),
        ("export", "e57", out / "c.ply", "-o", out / "c.e57"),
        ("export", "ply", out / "c.e57", "-o", out / "c2.ply"),
        ("simulate", "wall", "-o", out / "sim", "--frames", "2"),
    ]
    before = tree_hash(data)
    for args in commands:
        r = _run(*args)
        assert r.exit_code == 0, (args, r.output, r.exception)
        assert tree_hash(data) == before, f"{args[:2]} modified its inputs"
    written = tree_hash(out)
    for args in commands:
        if args[0] == "info":
            continue
        r = _run(*args)
        assert isinstance(r.exception, InputError), (args, r.output)
        assert "--force" in str(r.exception), (args, str(r.exception))
        assert tree_hash(out) == written, f"{args[:2]} replaced an output without --force"
    assert tree_hash(data) == before
    # with --force, the same commands replace their outputs (and still leave the inputs alone)
    r = _run("cloud", cap, "--calibration", cal, "-o", out / "c.ply", "--force")
    assert r.exit_code == 0, r.output
    assert tree_hash(data) == before


# ------------------------------------------------------------------ paths inside data files
def test_station_paths_must_stay_inside_the_dataset(tmp_path, small_wall):
    from tofmetry.io import WallDataset, write_stations_csv

    ds = shutil.copytree(small_wall, tmp_path / "w")
    names = [s.name for s in WallDataset(ds).stations]
    for bad, msg in (("../w/" + names[1], "outside"), (str(ds / names[1]), "absolute"), ("/etc", "absolute"),
                     ("C:\\data\\x", "absolute"), (names[1] + "/../../w/" + names[1], "outside"), ("..", "outside")):
        write_stations_csv(ds / "stations.csv", [(names[0], 800.0), (bad, 1300.0)])
        with pytest.raises(InputError, match=msg):
            WallDataset(ds)


def test_tum_lists_must_stay_inside_the_folder(tmp_path, one_capture):
    from tofmetry.io.tum import import_tum

    root = tmp_path / "tum"
    (root / "depth").mkdir(parents=True)
    src = sorted((one_capture / "depth").glob("*.png"))[0]
    shutil.copy(src, root / "depth" / "1.0.png")
    shutil.copy(src, tmp_path / "secret.png")
    for entry, msg in ((f"1.0 ../secret.png", "outside"), (f"1.0 {tmp_path / 'secret.png'}", "absolute")):
        (root / "depth.txt").write_text(f"# timestamp filename\n{entry}\n")
        with pytest.raises(InputError, match=msg):
            import_tum(root, tmp_path / "out")
        assert not (tmp_path / "out").exists()


def test_no_pickle_and_safe_yaml_only():
    """Loaders never unpickle and never use an unsafe YAML loader (checked on the source)."""
    root = Path(__file__).resolve().parents[2] / "tofmetry"
    for f in root.rglob("*.py"):
        text = f.read_text()
        assert "allow_pickle=True" not in text, f
        assert "import pickle" not in text and "pickle.load" not in text, f
        assert "yaml.load(" not in text and "yaml.unsafe_load" not in text and "UnsafeLoader" not in text, f
        assert "yaml.FullLoader" not in text, f


def test_a_pickled_npz_is_never_loaded(tmp_path):
    """A calibration-like .npz whose arrays hold Python objects is refused without unpickling them."""
    import pickle

    from tofmetry.errors import FormatError
    from tofmetry.io.calibration_file import read_calibration_file

    class Boom:
        def __reduce__(self):
            return (os.system, ("touch " + str(tmp_path / "pwned"),))

    hdr = json.dumps({"format": "tofmetry-depth-calibration", "version": 2})
    np.savez(tmp_path / "evil.npz", header=np.array(hdr), range_knots=np.array([Boom()], dtype=object),
             range_coeffs=np.zeros(3), node_mm=np.zeros(1), surfaces=np.zeros((1, 2, 2)))
    assert pickle  # (the module is only used to build the test file)
    with pytest.raises(FormatError, match="never loads"):
        read_calibration_file(tmp_path / "evil.npz")
    assert not (tmp_path / "pwned").exists()


# ------------------------------------------------------------------ interrupted commands
CLI = [sys.executable, "-m", "tofmetry.cli"]


def _start(args, cwd):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([*CLI, *map(str, args)], cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def _complete(name: str, target: Path, long_capture: Path) -> bool:
    """Whether ``target`` is a finished output of command ``name``, read back in full (a
    half-written one raises or misses parts, and is not complete)."""
    from tofmetry.io import Capture
    from tofmetry.io.ply import read_ply
    from tofmetry.pipelines import load_calibration

    if not target.exists():
        return False
    try:
        if name == "correct":
            cap, src = Capture(target), Capture(long_capture)
            return len(cap) == len(src) and all(cap.depth(i).shape == src.depth(0).shape for i in range(len(cap)))
        if name == "calibrate depth":
            return load_calibration(target) is not None
        if name == "reconstruct":
            return json.loads((target / "poses.json").read_text()) is not None and len(
                read_ply(target / "mesh.ply")["points"]) > 0
        if name == "study":
            return (target / "report.html").is_file() and json.loads((target / "report.json").read_text()) is not None
    except Exception:  # noqa: BLE001 - anything unreadable is not complete
        return False
    return False


def _wait_for(cond, proc, timeout=120.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if cond():
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.05)
    return False


def _staging(parent: Path, name: str):
    return [p for p in parent.iterdir() if p.name.startswith(f".{name}.") and p.name.endswith(".tmp")]


@pytest.fixture(scope="module")
def long_capture(one_capture, tmp_path_factory):
    """A 300-frame capture (frames repeated): long enough to be interrupted while it streams."""
    cap = tmp_path_factory.mktemp("long") / "cap"
    (cap / "depth").mkdir(parents=True)
    src = sorted((one_capture / "depth").glob("*.png"))
    for i in range(300):
        os.link(src[i % len(src)], cap / "depth" / f"{i:06d}.png")
    meta = json.loads((one_capture / "capture.json").read_text())
    meta.pop("timestamps_s", None)
    (cap / "capture.json").write_text(json.dumps(meta))
    return cap


@pytest.fixture(scope="module")
def small_scan(tmp_path_factory):
    from tofmetry.simulate import datasets

    return datasets.scan(tmp_path_factory.mktemp("scan") / "scan", n_views=8, n_frames=2, seed=5)


@pytest.fixture(scope="module")
def study_data(tmp_path_factory, small_wall):
    from tofmetry.simulate import datasets

    d = tmp_path_factory.mktemp("study") / "data"
    shutil.copytree(small_wall, d / "wall")
    datasets.noise(d / "noise", n_frames=30, seed=2)
    datasets.checkerboard_images(d / "checkerboard", n_images=8, seed=3)
    return d


def _cases(long_capture, small_cal, small_wall, small_scan, study_data):
    """(name, args, output, started(tmp) -> bool) of each command interrupted."""
    return [
        ("correct", ["correct", long_capture, "--calibration", small_cal, "-o", "{tmp}/corr"], "corr",
         lambda t: bool(_staging(t, "corr"))),
        ("calibrate depth", ["calibrate", "depth", small_wall, "-o", "{tmp}/cal.npz", "--report", "{tmp}/rep"],
         "cal.npz", None),
        ("reconstruct", ["reconstruct", small_scan, "--no-calibration", "-o", "{tmp}/model", "--allow-unreliable"],
         "model", None),
        ("study", ["study", study_data, "-o", "{tmp}/st"], "st", lambda t: (t / "st" / "noise").is_dir()),
    ]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["SIGINT", "SIGKILL"])
def test_interrupted_commands_leave_nothing_that_looks_complete(sig, tmp_path, long_capture, small_cal, small_wall,
                                                                 small_scan, study_data):
    for name, args, out, started in _cases(long_capture, small_cal, small_wall, small_scan, study_data):
        t = tmp_path / name.replace(" ", "-")
        t.mkdir()
        argv = [str(a).replace("{tmp}", str(t)) for a in args]
        p = _start(argv, t)
        # mid-run: the command's own progress marker, else a few seconds after the imports
        ok = _wait_for(lambda: started(t), p) if started else (time.sleep(4.0) or p.poll() is None)
        assert ok and p.poll() is None, f"{name}: finished or failed before it could be interrupted: " + \
            (p.communicate()[1][-2000:] if p.poll() is not None else "")
        os.killpg(p.pid, sig) if sig == signal.SIGKILL else p.send_signal(sig)
        _, err = p.communicate(timeout=120)
        target = t / out
        if _complete(name, target, long_capture):
            # the output was finished (renamed into place) before the signal took effect: on a
            # loaded machine the signal can land after it, e.g. while the report is written. What
            # exists must then be whole (checked by reading it), and a rerun asks for --force.
            r = subprocess.run([*CLI, *argv], cwd=t, capture_output=True, text=True, timeout=600)
            assert r.returncode != 0 and "--force" in r.stderr + r.stdout, (name, r.returncode, r.stderr[-2000:])
            continue
        if sig == signal.SIGINT:
            assert p.returncode == 130, (name, p.returncode, err[-2000:])
            assert "interrupted" in err, (name, err[-2000:])
        if name == "study":
            assert not (target / "report.html").exists() and not (target / "report.json").exists(), name
        else:
            assert not target.exists(), f"{name}: {target} exists after {sig.name}"
            assert not (t / "rep").exists() or not (t / "rep" / "fit.json").exists()
        if sig == signal.SIGINT:
            assert not _staging(t, out), f"{name}: staging left after SIGINT"
        # a rerun without --force succeeds, or says exactly what to remove
        r = subprocess.run([*CLI, *argv], cwd=t, capture_output=True, text=True, timeout=600)
        if r.returncode != 0:
            assert name == "study" and r.returncode == 2, (name, r.returncode, r.stderr[-2000:])
            assert str(target.resolve()) in r.stderr and "remove" in r.stderr, r.stderr
            shutil.rmtree(target)
            r = subprocess.run([*CLI, *argv], cwd=t, capture_output=True, text=True, timeout=600)
            assert r.returncode in (0, 1), r.stderr[-2000:]
        else:
            assert target.exists(), name
