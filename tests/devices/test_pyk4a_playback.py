"""The Azure Kinect device through the real pyk4a: the shared MKV played back by the Azure Kinect SDK
gives bit for bit the frames of tofmetry's own importer (PyAV), and the same factory calibration.

pyk4a-bundle 1.5 is built against numpy 1.x and cannot be imported next to tofmetry's numpy 2, so the
test makes a separate environment (``numpy<2`` + ``pyk4a-bundle``, cached in ``.cache/pyk4a-env``,
git-ignored; about 16 s to build from PyPI on 2 cores, measured 2026-11) and plays the recording back
there through ``tofmetry.devices.azure`` itself (tofmetry's light modules import with numpy 1.26; the
device needs neither OpenCV nor numba). Skipped, with pip's reason, where pip cannot install them.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tofmetry.io.azure_kinect import parse_calibration, read_azure_mkv

pytestmark = pytest.mark.realdata

REPO = Path(__file__).resolve().parents[2]
ENV = Path(os.environ.get("TOFMETRY_PYK4A_ENV", REPO / ".cache" / "pyk4a-env"))
REQUIREMENTS = ["numpy<2", "pyk4a-bundle>=1.5,<2"]
SCRIPT = Path(__file__).with_name("_pyk4a_playback.py")


def _env_python() -> Path:
    """The cached environment's python, built on first use (skips when pip cannot install the packages)."""
    py = ENV / "bin" / "python"
    stamp = ENV / ".tofmetry-env.json"
    want = {"python": sys.version.split()[0], "requirements": REQUIREMENTS}
    if stamp.is_file() and py.is_file() and json.loads(stamp.read_text()) == want:
        return py
    shutil.rmtree(ENV, ignore_errors=True)
    ENV.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "venv", str(ENV)], check=True, capture_output=True, timeout=300)
    r = subprocess.run([str(py), "-m", "pip", "install", "-q", "--timeout", "30", "--retries", "1", *REQUIREMENTS],
                       capture_output=True, text=True, timeout=900)
    if r.returncode != 0:
        shutil.rmtree(ENV, ignore_errors=True)
        tail = " ".join((r.stderr or r.stdout).strip().splitlines()[-3:])
        pytest.skip(f"pip could not install {' '.join(REQUIREMENTS)} in a separate environment: {tail}")
    stamp.write_text(json.dumps(want))
    return py


@pytest.fixture(scope="module")
def playback(shared_data, tmp_path_factory):
    mkv = shared_data / "azure-kinect-recording" / "recording.mkv"
    out = tmp_path_factory.mktemp("pyk4a")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME", "VIRTUAL_ENV")}
    env["PYTHONPATH"] = str(REPO)
    r = subprocess.run([str(_env_python()), str(SCRIPT), str(mkv), str(out)], capture_output=True, text=True,
                       env=env, timeout=300, cwd=REPO)
    assert r.returncode == 0, r.stderr[-3000:]
    return mkv, out


def test_sdk_playback_equals_the_importer_bit_for_bit(playback):
    mkv, out = playback
    rec = read_azure_mkv(mkv)
    depth, ir = np.load(out / "depth.npy"), np.load(out / "ir.npy")
    assert depth.dtype == np.uint16 and ir.dtype == np.uint16
    assert depth.shape == rec.depth.shape == (1, 576, 640)
    assert np.array_equal(depth, rec.depth) and np.array_equal(ir, rec.ir)
    assert (depth > 0).mean() > 0.5
    info = json.loads((out / "info.json").read_text())
    assert info["versions"]["numpy"].startswith("1.")
    # the SDK's device clock = the importer's time in the file + the recording's start offset
    ts = np.load(out / "timestamps_s.npy")
    offset = int(rec.tags["K4A_START_OFFSET_NS"]) / 1e9
    assert ts == pytest.approx(rec.timestamps_s + offset, abs=1e-6)


def test_sdk_calibration_equals_the_importer(playback):
    mkv, out = playback
    info = json.loads((out / "info.json").read_text())
    rec = read_azure_mkv(mkv)
    cal = parse_calibration(rec.calibration, rec.depth_mode, rec.color_height)
    assert info["sensor"] == "azure_kinect" and info["fps"] == 5.0        # the recording's camera_fps
    # depth camera: identical numbers (the SDK's float32 values, rational lens model)
    assert info["depth_intrinsics"] == cal["depth"].intrinsics.to_dict()
    # colour camera: the SDK scales the raw-sensor parameters in float32 (< 1e-4 px apart)
    ci, ti = info["color_intrinsics"], cal["color"].intrinsics.to_dict()
    assert ci["model"] == ti["model"] == "rational" and (ci["width"], ci["height"]) == (1280, 720)
    for k in ("fx", "fy", "cx", "cy"):
        assert ci[k] == pytest.approx(ti[k], abs=1e-4)
    assert ci["distortion"] == pytest.approx(ti["distortion"], abs=1e-9)
    # depth -> colour: metres, as the importer (about 32 mm baseline)
    ext = cal["color"].to_depth
    assert np.allclose(info["depth_to_color"]["rotation"], ext.rotation, atol=1e-9)
    assert np.allclose(info["depth_to_color"]["translation_m"], ext.translation, atol=1e-8)
    assert 0.02 < np.linalg.norm(info["depth_to_color"]["translation_m"]) < 0.05
    assert info["temperatures"] == [{}]          # pyk4a gives a playback no temperature
