"""Benchmarks 6 and 7: ``tofmetry correct`` end to end, and its memory against the number of frames.

6. ``tofmetry correct`` on a 1,000-frame capture, run as a user runs it (a new process: start-up,
   imports, reading, correcting, writing), against a process that reads and writes the same depth
   PNGs and does nothing else (same PNG settings as the library's writer, one thread per core);
   both in the same run, alternating, median of ``rounds`` pairs. Target: ratio <= 1.5.
7. Peak RSS of ``tofmetry correct`` on 1,000 and on 10,000 frames (``os.wait4`` of the process).
   Target: they differ by less than 10 %.

The capture is synthetic (``bench.frame_pipeline.test_frame``: a slanted wall 0.8-3.5 m with noise
and 3 % dropouts, 16 different frames cycled), depth only, 512x424 uint16 PNG; the calibration is
``bench.frame_pipeline.make_calibration``. Run alone: ``python -m bench.correct_stream [--frames N]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2

from bench.frame_pipeline import make_calibration, test_frame

# the same encoder settings as tofmetry.io.images.encode_png16
PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1]

# A process that reads and writes the same PNGs and nothing else: the reference of benchmark 6.
COPY_SCRIPT = r"""
import os, sys
from concurrent.futures import ThreadPoolExecutor
import cv2
src, dst, threads = sys.argv[1], sys.argv[2], int(sys.argv[3])
names = sorted(n for n in os.listdir(os.path.join(src, "depth")) if n.endswith(".png"))
os.makedirs(os.path.join(dst, "depth"))
def one(name):
    img = cv2.imread(os.path.join(src, "depth", name), cv2.IMREAD_UNCHANGED)
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    with open(os.path.join(dst, "depth", name), "wb") as fh:
        fh.write(buf)
with ThreadPoolExecutor(threads) as ex:
    for _ in ex.map(one, names):
        pass
"""

CLI = "from tofmetry.cli import main; main()"


def make_capture(path: Path, n_frames: int, variants: int = 16) -> Path:
    """A depth-only capture of ``n_frames`` 512x424 uint16 PNG frames (``variants`` distinct ones)."""
    path = Path(path)
    (path / "depth").mkdir(parents=True)
    blobs = []
    for s in range(variants):
        ok, buf = cv2.imencode(".png", test_frame(seed=s + 1), PNG_PARAMS)
        blobs.append(buf.tobytes())

    def write(i: int) -> None:
        (path / "depth" / f"{i:06d}.png").write_bytes(blobs[i % variants])

    with ThreadPoolExecutor(4) as ex:
        list(ex.map(write, range(n_frames)))
    (path / "capture.json").write_text(json.dumps({"sensor": "kinect_v2", "depth_unit_mm": 1.0}))
    return path


def run_process(args: list[str], cwd: Path | None = None) -> tuple[float, float, float]:
    """Run ``args``; returns (wall time [s], CPU time [s], peak RSS [MiB]) of that process alone.

    The CPU time (user + system, all threads) is the figure to compare on a shared machine: other
    processes stretch the wall time of both sides, not their CPU time."""
    t0 = time.perf_counter()
    p = subprocess.Popen(args, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    dt = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    err = p.stderr.read().decode(errors="replace")
    p.stderr.close()
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, args))} failed ({p.returncode}):\n{err[-3000:]}")
    return dt, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0


def correct_cmd(cap: Path, cal: Path, out: Path) -> list[str]:
    return [sys.executable, "-c", CLI, "correct", str(cap), "--calibration", str(cal), "-o", str(out)]


def copy_cmd(cap: Path, out: Path, threads: int) -> list[str]:
    return [sys.executable, "-c", COPY_SCRIPT, str(cap), str(out), str(threads)]


def _fresh(path: Path) -> Path:
    shutil.rmtree(path, ignore_errors=True)
    return path


def bench_correct(n_frames: int = 1000, rounds: int = 3, workdir: Path | None = None) -> dict:
    """Benchmark 6: median wall time of ``tofmetry correct`` and of the plain PNG copy, alternating."""
    from tofmetry.pipelines import save_calibration

    threads = os.cpu_count() or 1
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        tmp = Path(tmp)
        cap = make_capture(tmp / "capture", n_frames)
        cal = tmp / "cal.npz"
        save_calibration(cal, make_calibration())
        run_process(correct_cmd(cap, cal, _fresh(tmp / "warm")))  # numba cache, page cache
        t_ours, t_copy, cpu_ours, cpu_copy, rss, load = [], [], [], [], [], []
        for _ in range(rounds):
            load.append(os.getloadavg()[0])
            dt, cpu, mb = run_process(correct_cmd(cap, cal, _fresh(tmp / "out")))
            t_ours.append(dt)
            cpu_ours.append(cpu)
            rss.append(mb)
            dt, cpu, _ = run_process(copy_cmd(cap, _fresh(tmp / "copy"), threads))
            t_copy.append(dt)
            cpu_copy.append(cpu)
        ratios = [a / b for a, b in zip(t_ours, t_copy)]
        size_mb = sum(f.stat().st_size for f in (cap / "depth").iterdir()) / 2**20
    return {"frames": n_frames, "rounds": rounds, "copy_threads": threads, "capture_mib": size_mb,
            "correct_s": statistics.median(t_ours), "copy_s": statistics.median(t_copy),
            "ratio": statistics.median(ratios), "ratios": ratios, "correct_runs_s": t_ours, "copy_runs_s": t_copy,
            "correct_ms_per_frame": 1e3 * statistics.median(t_ours) / n_frames,
            "copy_ms_per_frame": 1e3 * statistics.median(t_copy) / n_frames,
            "correct_peak_rss_mib": statistics.median(rss),
            "correct_cpu_s": statistics.median(cpu_ours), "copy_cpu_s": statistics.median(cpu_copy),
            "cpu_ratio": statistics.median(a / b for a, b in zip(cpu_ours, cpu_copy)),
            "load_average_1min": load}


def bench_correct_memory(small: int = 1000, large: int = 10000, workdir: Path | None = None) -> dict:
    """Benchmark 7: peak RSS of ``tofmetry correct`` on ``small`` and ``large`` frames."""
    from tofmetry.pipelines import save_calibration

    out = {}
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        tmp = Path(tmp)
        cal = tmp / "cal.npz"
        save_calibration(cal, make_calibration())
        for n in (small, large):
            cap = make_capture(tmp / f"capture{n}", n)
            dt, _, mb = run_process(correct_cmd(cap, cal, _fresh(tmp / "out")))
            out[str(n)] = {"seconds": dt, "peak_rss_mib": mb}
            shutil.rmtree(cap)
            shutil.rmtree(tmp / "out")
    a, b = out[str(small)]["peak_rss_mib"], out[str(large)]["peak_rss_mib"]
    out["rss_change"] = b / a - 1.0
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--memory", action="store_true", help="also benchmark 7 (writes 10,000 frames: about 2 GB)")
    args = ap.parse_args(argv)
    res = {"correct": bench_correct(args.frames, args.rounds)}
    if args.memory:
        res["memory"] = bench_correct_memory()
    print(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
