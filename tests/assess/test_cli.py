"""CLI: each assessment writes JSON + PNG; filter writes a new capture; clean errors."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.errors import InputError
from tofmetry.io import Capture, CaptureMeta, write_capture

runner = CliRunner()


def _run(*args):
    res = runner.invoke(app, [str(a) for a in args])
    return res


def test_assess_noise_and_materials_cli(noise_small_ds, grey_ds, tmp_path):
    out = tmp_path / "noise"
    r = _run("assess", "noise", noise_small_ds / "capture", "-o", out, "--row", 100)
    assert r.exit_code == 0, r.output
    d = json.loads((out / "noise.json").read_text())
    assert d["row"] == 100 and d["subsets"] == [10]
    assert (out / "noise_std_maps.png").stat().st_size > 10_000 and (out / "noise_profile.png").is_file()
    out = tmp_path / "mat"
    r = _run("assess", "materials", grey_ds / "capture", "-o", out, "--regions", grey_ds / "regions.json")
    assert r.exit_code == 0, r.output
    assert json.loads((out / "materials.json").read_text())["fit"]["slope_mm_per_ln"] > 0
    assert (out / "materials_deviation.png").is_file() and (out / "materials_samples.png").is_file()


def test_assess_warmup_cli(warmup_ds, tmp_path):
    out = tmp_path / "warm"
    r = _run("assess", "warmup", warmup_ds / "capture", "-o", out, "--patch", 8, "--tolerance-mm", 1.5)
    assert r.exit_code == 0, r.output
    d = json.loads((out / "warmup.json").read_text())
    assert d["patch"]["size"] == 8 and d["stabilisation_time_s"] is not None
    assert (out / "warmup.png").is_file()


def _edge_capture(path, n=3, timestamps=True):
    h, w = 424, 512
    rng = np.random.default_rng(0)
    frames = []
    for _ in range(n):
        d = np.full((h, w), 2000, np.uint16)
        d[:, :255] = 1000
        d[:, 255] = rng.integers(1200, 1800, h)
        frames.append(d)
    meta = CaptureMeta(sensor="kinect_v2", timestamps_s=[float(i) for i in range(n)] if timestamps else None)
    return write_capture(path, frames, meta, ir_frames=[np.full((h, w), 5000, np.uint16)] * n)


def test_outdoor_and_filter_cli(tmp_path):
    from tofmetry.io import read_ply

    cap = _edge_capture(tmp_path / "cap")
    out = tmp_path / "outdoor"
    r = _run("assess", "outdoor", cap, "-o", out)
    assert r.exit_code == 0, r.output
    d = json.loads((out / "outdoor.json").read_text())
    assert d["n_max_points"] == 217_088 and d["valid_fraction"] == 1.0
    assert abs(d["flying_share_of_cloud"] - 424 / 217_088) < 1e-4
    ply = read_ply(out / "outdoor_cloud.ply")
    assert (out / "outdoor_profile.png").is_file() and ply is not None
    r = _run("filter", cap, "-o", tmp_path / "filtered")
    assert r.exit_code == 0, r.output
    f = Capture(tmp_path / "filtered")
    assert len(f) == 3 and f.has_ir and (f.depth(0)[:, 255] == 0).all() and (f.depth(0)[:, :255] == 1000).all()
    assert (Capture(cap).depth(0)[:, 255] > 0).all()  # input untouched
    assert f.meta.extra["filtered"]["flying_pixels"]["k_noise"] == 3.0


def test_bad_inputs_give_clear_errors(tmp_path, grey_ds):
    import pytest

    cap = _edge_capture(tmp_path / "cap_nots", n=3, timestamps=False)
    r = _run("assess", "warmup", cap, "-o", tmp_path / "w")
    assert isinstance(r.exception, InputError) and "timestamps" in str(r.exception)
    one = _edge_capture(tmp_path / "one", n=1)
    r = _run("assess", "noise", one, "-o", tmp_path / "n")
    assert isinstance(r.exception, InputError) and "at least 2 frames" in str(r.exception)
    bad = tmp_path / "regions.json"
    bad.write_text(json.dumps({"regions": [{"name": "w", "rect": [0, 0, 600, 10], "reference": True}]}))
    r = _run("assess", "materials", grey_ds / "capture", "-o", tmp_path / "m", "--regions", bad)
    assert isinstance(r.exception, InputError) and "outside" in str(r.exception)
    r = _run("filter", cap, "-o", cap)
    assert isinstance(r.exception, InputError)
    with pytest.raises(InputError):
        raise r.exception
