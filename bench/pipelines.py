"""Benchmarks 3-5: depth calibration fit, reconstruction by stage, TSDF integration."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def bench_depth_fit(n_stations: int = 15, n_frames: int = 50) -> dict:
    """Fit on a simulated wall dataset of ``n_stations`` x ``n_frames`` (frames streamed from disk)."""
    from tofmetry.simulate import datasets

    dists = ([800.0] + [1000.0 + 250.0 * i for i in range(15)])[:n_stations]
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        datasets.wall_dataset(Path(tmp) / "wall", distances_mm=dists, n_frames=n_frames, seed=1)
        t_sim = time.perf_counter() - t0
        # the fit runs in a child process so that its own peak memory is measured (not the simulator's)
        code = ("import json, sys, time; from tofmetry.pipelines import calibrate_depth_dataset; "
                "t = time.perf_counter(); r = calibrate_depth_dataset(sys.argv[1], reference_offset_mm=20.0); "
                "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1]; "
                "print(json.dumps({'seconds': time.perf_counter() - t, 'fit_only_seconds': r.seconds, "
                "'peak_rss_mb': int(hwm) / 1024}))")
        out = subprocess.run([sys.executable, "-c", code, str(Path(tmp) / "wall")], capture_output=True, text=True,
                             check=True)
        # VmHWM of the child itself (RUSAGE_CHILDREN would count the parent's pages at fork time)
        res = json.loads(out.stdout.strip().splitlines()[-1])
        child_rss = res["peak_rss_mb"]
    return {"stations": n_stations, "frames_per_station": n_frames, "seconds": res["seconds"],
            "fit_only_seconds": res["fit_only_seconds"], "simulate_seconds": t_sim, "peak_rss_mb": child_rss,
            "frames_in_memory_would_be_mb": n_stations * n_frames * 512 * 424 * 2 / 2**20}


def bench_reconstruction() -> tuple[dict, dict]:
    """End-to-end reconstruction of the simulated 8-view scan (10 frames per view), by stage; TSDF frames/s."""
    from tofmetry.pipelines import load_calibration, save_calibration
    from tofmetry.pipelines import calibrate_depth_dataset
    from tofmetry.io import ScanDataset
    from tofmetry.pipelines.reconstruct import white_map_from_wall
    from tofmetry.reconstruct import ReconstructionConfig, ReconstructionPipeline, TSDFFusion
    from tofmetry.simulate import datasets

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        datasets.scan(tmp / "scan", n_views=8, n_frames=10, seed=0)
        datasets.wall_dataset(tmp / "wall", n_frames=20, seed=1)
        cal = calibrate_depth_dataset(tmp / "wall", reference_offset_mm=20.0).calibration
        save_calibration(tmp / "cal.npz", cal)
        cal = load_calibration(tmp / "cal.npz")
        white = white_map_from_wall(tmp / "wall", calibration=cal, intrinsics=cal.intrinsics)
        t0 = time.perf_counter()
        res = ReconstructionPipeline(ScanDataset(tmp / "scan"), cal, ReconstructionConfig(), white_map=white).run()
        total = time.perf_counter() - t0
        tm = res.diagnostics.get("timings_s", {})
        fus = res.diagnostics.get("fusion", {})
        # TSDF alone: integrate the 8 calibrated views repeatedly at the pipeline's voxel size
        intr = cal.intrinsics
        depth = np.asarray(ScanDataset(tmp / "scan")[0].depth(0), dtype=np.float32)
        f = TSDFFusion(intr, fus.get("voxel_mm", 1.5), fus.get("trunc_mm", 5.0), 2500.0)
        for _ in range(3):
            f.integrate(depth, np.eye(4))
        n = 30
        t0 = time.perf_counter()
        for _ in range(n):
            f.integrate(depth, np.eye(4))
        t_tsdf = (time.perf_counter() - t0) / n
    stages = {k.replace("_s", ""): v for k, v in tm.items() if k != "total_s"}
    return ({"seconds": total, "stages_s": stages, "views": len(res.names)},
            {"voxel_mm": float(fus.get("voxel_mm", float("nan"))), "ms_per_frame": t_tsdf * 1e3, "fps": 1.0 / t_tsdf})
