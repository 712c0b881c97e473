"""Benchmarks of ``tofmetry batch``: scaling with workers, memory on a long recording, cost per job kind.

1. **Throughput, 1 vs 2 workers** (same run, same jobs): ``--jobs`` depth calibrations of a small
   simulated wall dataset (CPU bound: the fit), run by :func:`tofmetry.batch.run_batch` on a
   LocalCluster of 1 worker, then of 2 workers (one thread each), each on a fresh output folder.
   Throughput = jobs / wall time of the batch (cluster start-up excluded). Target: ratio >= 1.7.
2. **Memory on a long recording**: ``tofmetry batch`` corrects a ``--frames``-frame recording
   (512x424 PNG; ``variants`` distinct frames hard-linked, so the input costs no disk) in chunks of
   ``--chunk`` frames on 2 workers; peak RSS of every worker process (``ru_maxrss``). Target: < 1 GiB.
3. **Cost per job kind**: the seconds of each job of run 1 and of the long correction, for the
   README's estimate.

``python -m bench.batch [--jobs 8] [--frames 50000] [--chunk 2000] [-o bench/results]``
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import cv2

from bench.frame_pipeline import test_frame
from tofmetry.batch import batch_client, run_batch
from tofmetry.io import atomic_write_json
from tofmetry.pipelines import save_calibration
from tofmetry.simulate import datasets

STATIONS = (800.0, 1200.0, 1600.0, 2000.0, 2500.0)


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def throughput(work: Path, n_jobs: int) -> dict:
    wall = datasets.wall_dataset(work / "wall", STATIONS, n_frames=3)
    m = work / "cal.toml"
    m.write_text("".join(f'[[job]]\nkind = "calibrate-depth"\nname = "cal-{k}"\ninputs = {{ dataset = "{wall}" }}\n\n'
                         for k in range(n_jobs)))
    res = {}
    for n in (1, 2):
        with batch_client(workers=n) as client:
            run_batch(m, work / f"warm-{n}", client=client)        # imports and first-call costs on every worker
            t0 = time.perf_counter()
            run = run_batch(m, work / f"out-{n}", client=client)
            dt = time.perf_counter() - t0
        assert run.counts["ok"] == n_jobs, run.records
        res[n] = {"seconds": dt, "jobs_per_min": 60 * n_jobs / dt,
                  "job_seconds": sorted(r["seconds"] for r in run.records)}
        print(f"{n} worker(s): {n_jobs} calibrations in {dt:.1f} s ({res[n]['jobs_per_min']:.1f} jobs/min)", flush=True)
    res["ratio"] = res[2]["jobs_per_min"] / res[1]["jobs_per_min"]
    print(f"throughput ratio 2 / 1 workers: {res['ratio']:.2f} (target >= 1.7)", flush=True)
    return res


def long_recording(work: Path, n_frames: int, chunk: int, variants: int = 16) -> dict:
    from bench.frame_pipeline import make_calibration

    cap = work / "long" / "capture"
    (cap / "depth").mkdir(parents=True)
    for s in range(variants):
        ok, buf = cv2.imencode(".png", test_frame(seed=s + 1), [cv2.IMWRITE_PNG_COMPRESSION, 1])
        (work / f"v{s}.png").write_bytes(buf.tobytes())
    for i in range(n_frames):
        os.link(work / f"v{i % variants}.png", cap / "depth" / f"{i:06d}.png")
    (cap / "capture.json").write_text(json.dumps({"sensor": "kinect_v2", "depth_unit_mm": 1.0}))
    save_calibration(work / "cal.npz", make_calibration())
    m = work / "long.toml"
    m.write_text(f'[defaults]\nchunk_frames = {chunk}\n[[job]]\nkind = "correct"\nname = "long"\n'
                 f'inputs = {{ capture = "{cap}", calibration = "{work / "cal.npz"}" }}\n')
    with batch_client(workers=2) as client:
        t0 = time.perf_counter()
        run = run_batch(m, work / "out-long", client=client)
        dt = time.perf_counter() - t0
        rss = client.run(_peak_rss_mib)
    rec = run.records[0]
    assert rec["status"] == "ok", rec
    n_out = len(os.listdir(work / "out-long" / "long" / "depth"))
    print(f"{n_frames} frames corrected in {dt:.0f} s ({n_frames / dt:.0f} frames/s) in {rec.get('chunks')} chunks; "
          f"peak RSS per worker {', '.join(f'{v:.0f}' for v in rss.values())} MiB (target < 1024)", flush=True)
    return {"frames": n_frames, "written": n_out, "chunk_frames": chunk, "chunks": rec.get("chunks"), "seconds": dt,
            "frames_per_s": n_frames / dt, "worker_peak_rss_mib": list(rss.values())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=8)
    ap.add_argument("--frames", type=int, default=50_000)
    ap.add_argument("--chunk", type=int, default=2000)
    ap.add_argument("--skip-throughput", action="store_true")
    ap.add_argument("--skip-long", action="store_true")
    ap.add_argument("-o", "--out", type=Path, default=Path("bench/results"))
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="tofmetry-bench-batch-"))
    res: dict = {"cpus": os.cpu_count()}
    try:
        if not a.skip_throughput:
            res["throughput"] = throughput(work / "t", a.jobs)
        if not a.skip_long:
            res["long_recording"] = long_recording(work / "l", a.frames, a.chunk)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    name = "batch.json" if not (a.skip_throughput or a.skip_long) else \
        ("batch_long.json" if a.skip_throughput else "batch_throughput.json")
    atomic_write_json(a.out / name, res)
    print(f"wrote {a.out / name}")


if __name__ == "__main__":
    main()
