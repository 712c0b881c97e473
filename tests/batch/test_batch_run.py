"""``tofmetry batch`` on a LocalCluster: ~20 mixed jobs, a bad job failing alone, a rerun skipping
everything finished, a worker killed mid-job, and the README's manifest."""

from __future__ import annotations

import json
import os
import re
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tofmetry.batch import batch_client, run_batch
from tofmetry.io import Capture
from tofmetry.pipelines.correct import correct_capture
from tofmetry.simulate import datasets

REPO = Path(__file__).resolve().parents[2]
STATIONS = (800.0, 1200.0, 1600.0, 2000.0, 2500.0)


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("batch-data")
    for k, s in enumerate(("S01", "S02")):
        datasets.wall_dataset(d / "walls" / s, STATIONS, n_frames=3, seed=k)
        datasets.warmup(d / "warmups" / s, duration_s=1200.0, interval_s=40.0, seed=k)
    datasets.wall_dataset(d / "check-wall", (1000.0, 1800.0), n_frames=3, seed=7)
    for k in range(4):
        datasets.wall_capture(d / "recordings" / f"r{k}", 1000.0 + 300 * k, n_frames=6, seed=k)
    datasets.noise(d / "long", n_frames=40)
    datasets.outdoor(d / "outdoor", n_frames=2)
    return d


MANIFEST = """
[defaults]
chunk_frames = 15

[[job]]
kind = "calibrate-depth"
name = "cal-S01"
sensor = "S01"
inputs = { dataset = "walls/S01" }

[[job]]
kind = "calibrate-depth"
name = "cal-S02"
sensor = "S02"
inputs = { dataset = "walls/S02" }

[[job]]
kind = "validate"
name = "val-S01"
sensor = "S01"
inputs = { dataset = "check-wall", calibration = "@cal-S01/calibration.npz" }

[[job]]
kind = "validate"
name = "val-S02"
sensor = "S02"
inputs = { dataset = "check-wall", calibration = "@cal-S02/calibration.npz" }

[[job]]
kind = "assess"
name = "warmup-S01"
sensor = "S01"
inputs = { capture = "warmups/S01/capture" }
options = { analysis = "warmup", final_window_s = 300 }

[[job]]
kind = "assess"
name = "warmup-S02"
sensor = "S02"
inputs = { capture = "warmups/S02/capture" }
options = { analysis = "warmup", final_window_s = 300 }

[[job]]
kind = "correct"
name = "fix"
inputs = { capture = "recordings/*/capture", calibration = "@cal-S01/calibration.npz" }

[[job]]
kind = "assess"
name = "noise"
inputs = { capture = "recordings/*/capture" }
options = { analysis = "noise" }

[[job]]
kind = "correct"
name = "long-fix"
inputs = { capture = "long/capture", calibration = "@cal-S02/calibration.npz" }

[[job]]
kind = "assess"
name = "long-noise"
inputs = { capture = "long/capture" }
options = { analysis = "noise" }

[[job]]
kind = "assess"
name = "warm-noise"
inputs = { capture = "warmups/*/capture" }
options = { analysis = "noise" }

[[job]]
kind = "assess"
name = "outdoor"
inputs = { capture = "outdoor/capture" }
options = { analysis = "outdoor" }

[[job]]
kind = "correct"
name = "bad"
inputs = { capture = "long/capture", calibration = "walls/S01/stations.csv" }
"""


def _manifest(data: Path) -> Path:
    p = data / "manifest.toml"
    p.write_text(MANIFEST)
    return p


def test_mixed_jobs_fail_alone_and_rerun_skips(data, tmp_path):
    manifest = _manifest(data)
    out = tmp_path / "out"
    with batch_client(workers=2) as client:
        run = run_batch(manifest, out, client=client)
        recs = {r["name"]: r for r in run.records}
        assert len(recs) == 20, sorted(recs)
        bad = recs.pop("bad")
        assert bad["status"] == "failed" and bad["error_type"] == "FormatError"
        assert "stations.csv" in bad["error"], bad["error"]
        assert {r["status"] for r in recs.values()} == {"ok"}, {k: r.get("error") for k, r in recs.items()}
        assert not (out / "bad").exists()
        assert not [p for p in out.iterdir() if p.name.startswith(".")]     # no staging left behind
        doc = json.loads((out / "summary.json").read_text())
        assert doc["counts"] == {"ok": 19, "skipped": 0, "failed": 1}
        assert [j["name"] for j in doc["jobs"] if j["status"] == "failed"] == ["bad"]
        assert recs["long-fix"]["chunks"] == 3 and recs["long-noise"]["chunks"] == 1
        assert len(Capture(out / "long-fix")) == 40
        fleet = {f["sensor"]: f for f in doc["fleet"]}
        assert set(fleet) == {"S01", "S02"}
        for f in fleet.values():
            assert f["total_drift_mm"] is not None and f["predicted_rms_mm"] > 0 and f["max_abs_dev_after_mm"] >= 0
        html = (out / "summary.html").read_text()
        assert "Sensors side by side" in html and "FormatError" in html and 'href="cal-S01/report/fit.json"' in html

        again = run_batch(manifest, out, client=client)
        st = {r["name"]: r["status"] for r in again.records}
        assert st.pop("bad") == "failed"
        assert set(st.values()) == {"skipped"}

        # an input that changes reruns its job (and only it)
        (data / "recordings" / "r0" / "capture" / "capture.json").write_text(
            (data / "recordings" / "r0" / "capture" / "capture.json").read_text() + "\n")
        third = {r["name"]: r["status"] for r in run_batch(manifest, out, client=client).records}
        assert third["fix-r0_capture"] == "ok" and third["noise-r0_capture"] == "ok" and third["fix-r1_capture"] == "skipped"


def _killer(client, stop: threading.Event, killed: list) -> None:
    pids = client.run(os.getpid)
    while not stop.is_set() and not killed:
        for addr, keys in client.processing().items():
            if any("-chunk-" in k for k in keys):
                os.kill(pids[addr], signal.SIGKILL)
                killed.append(pids[addr])
                return
        time.sleep(0.05)


def test_worker_killed_mid_job_batch_completes(data, tmp_path):
    manifest = tmp_path / "kill.toml"
    manifest.write_text(f"""
[defaults]
chunk_frames = 4
retries = 2
[[job]]
kind = "calibrate-depth"
name = "cal"
inputs = {{ dataset = "{data}/walls/S01" }}
[[job]]
kind = "correct"
name = "long-fix"
inputs = {{ capture = "{data}/long/capture", calibration = "@cal/calibration.npz" }}
""")
    out = tmp_path / "out"
    killed: list = []
    stop = threading.Event()
    with batch_client(workers=2) as client:
        t = threading.Thread(target=_killer, args=(client, stop, killed), daemon=True)
        t.start()
        run = run_batch(manifest, out, client=client)
        stop.set()
        t.join()
        alive = set(client.run(os.getpid).values())
    assert killed and killed[0] not in alive            # a worker died mid-chunk and was replaced
    assert [r["status"] for r in run.records] == ["ok", "ok"], run.records
    ref = correct_capture(data / "long" / "capture", out / "cal" / "calibration.npz", tmp_path / "ref")
    got, exp = Capture(out / "long-fix"), Capture(ref.output)
    assert len(got) == len(exp) == 40
    for i in range(40):
        np.testing.assert_array_equal(got.depth(i), exp.depth(i))


def test_readme_manifest_runs(tmp_path):
    text = (REPO / "README.md").read_text()
    block = re.search(r"<!-- batch-example -->\s*```bash\n(.*?)```\s*```toml\n(.*?)```", text, re.S)
    assert block, "README: the batch example (bash + toml blocks after <!-- batch-example -->) is missing"
    setup, manifest = block.group(1), block.group(2)
    for line in setup.splitlines():
        m = re.match(r"tofmetry simulate (\S+) -o (\S+)(.*)", line.split("#")[0].strip())
        if m:
            kind, dest, rest = m.groups()
            frames = int(re.search(r"--frames (\d+)", rest).group(1)) if "--frames" in rest else None
            if kind == "wall-dataset":
                dists = [float(x) for x in re.findall(r"--distance-mm (\d+)", rest)]
                datasets.wall_dataset(tmp_path / dest, dists, n_frames=frames)
            elif kind == "wall":
                datasets.wall_capture(tmp_path / dest, float(re.search(r"--distance-mm (\d+)", rest).group(1)),
                                      n_frames=frames, seed=int(re.search(r"--seed (\d+)", rest).group(1)))
            elif kind == "noise":
                datasets.noise(tmp_path / dest, n_frames=frames)
    (tmp_path / "batch.toml").write_text(manifest)
    with batch_client(workers=2) as client:
        run = run_batch(tmp_path / "batch.toml", tmp_path / "batch-out", client=client)
    assert run.counts["failed"] == 0 and run.counts["ok"] == len(run.records) >= 4, run.records
