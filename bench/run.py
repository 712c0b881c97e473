"""Run the benchmark suite: ``.venv/bin/python -m bench.run [--quick] [-o bench/results]``.

Writes ``results.json`` and ``results.md`` (a table with the machine description and date) into
the output folder and prints the table. Each figure is the median of repeated runs after warm-up;
references (numpy, Open3D, memory bandwidth) are measured in the same run; the ratio to the memory
bound is measured in paired rounds (copy, then kernel; see ``bench.frame_pipeline._paired_rounds``).
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import sys
from pathlib import Path

from bench._util import peak_rss_mb
from tofmetry.io import atomic_write_bytes, atomic_write_json


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return f"{cpu}, {os.cpu_count()} cores, {mem:.0f} GiB, Python {platform.python_version()}"


def table(res: dict) -> str:
    f = res["frame_pipeline"]
    t = res["temporal"]
    rows = [
        ("1. per-frame path of the API, `tofmetry.to_points(depth, cal, out=buf)` (correct + undistort + back-project, "
         "512x424)", f"{f['ours_ms']:.3f} ms = {f['ours_fps']:.0f} frames/s",
         "≥ 2000 frames/s", f"new array per call {f['ours_allocating_ms']:.3f} ms; prepared kernel alone {f['kernel_ms']:.3f} ms; "
         f"raw depth (identity calibration) {f['raw_depth_ms']:.3f} ms; the commands' path before "
         f"(apply_depth_calibration + depth_to_points) {f['old_path_ms']:.2f} ms (×{f['speedup_vs_old_path']:.0f}); "
         f"numpy {f['numpy_ms']:.1f} ms (×{f['speedup_vs_numpy']:.0f}); Open3D legacy {f['open3d_legacy_ms']:.2f} ms "
         f"(×{f['speedup_vs_open3d_legacy']:.1f}, target ≥ 4); Open3D tensor {f['open3d_tensor_ms']:.2f} ms; "
         f"bandwidth bound {f['bandwidth_bound_ms']:.3f} ms at {f['copy_bandwidth_GBps']:.1f} GB/s: ×{f['ratio_to_bound']:.2f} "
         f"(target ≤ 3; 10-90 % of {f['rounds']} paired rounds ×{f['ratio_to_bound_p10']:.2f}–{f['ratio_to_bound_p90']:.2f}, "
         f"{f['rounds_within_3x']}/{f['rounds']} rounds ≤ 3; against a {f['numba_threads']}-thread copy at "
         f"{f['copy_bandwidth_all_threads_GBps']:.1f} GB/s ×{f['ratio_to_bound_all_threads_copy']:.2f})"),
        ("2. temporal stats, 10 frames", f"{t['n10']['ms']:.2f} ms = {t['n10']['stacks_per_s']:.0f} stacks/s", "–",
         f"numpy {t['n10']['numpy_ms']:.1f} ms"),
        ("2. temporal stats, 50 frames", f"{t['n50']['ms']:.2f} ms = {t['n50']['stacks_per_s']:.0f} stacks/s", "≥ 200 stacks/s",
         f"numpy {t['n50']['numpy_ms']:.1f} ms"),
    ]
    if "correct" in res:
        c = res["correct"]
        rows.append((f"6. `tofmetry correct`, {c['frames']} frames end to end (new process)", f"{c['correct_s']:.2f} s = "
                     f"{c['correct_ms_per_frame']:.2f} ms/frame", "≤ 1.5 × the PNG copy",
                     f"reading + writing the same PNGs ({c['copy_threads']} threads) {c['copy_s']:.2f} s: ×{c['ratio']:.2f} "
                     f"(median of {c['rounds']} alternating pairs, " + ", ".join(f"×{r:.2f}" for r in c["ratios"]) + ")"))
    if "correct_memory" in res:
        m = res["correct_memory"]
        a, b = m["1000"], m["10000"]
        rows.append(("7. peak RSS of `tofmetry correct`, 1,000 vs 10,000 frames", f"{a['peak_rss_mib']:.0f} vs "
                     f"{b['peak_rss_mib']:.0f} MiB ({100 * m['rss_change']:+.1f} %)", "< 10 % apart",
                     f"{a['seconds']:.1f} s and {b['seconds']:.1f} s"))
    if "depth_fit" in res:
        d = res["depth_fit"]
        rows.append(("3. depth calibration fit, 15 stations × 50 frames", f"{d['seconds']:.1f} s", "≤ 20 s",
                     f"peak RSS of the fitting process {d['peak_rss_mb']:.0f} MiB (frames streamed; all frames would be "
                     f"{d['frames_in_memory_would_be_mb']:.0f} MiB), simulate+write {d['simulate_seconds']:.0f} s (not counted)"))
    if "reconstruction" in res:
        r = res["reconstruction"]
        rows.append(("4. reconstruction, 8-view scan, end to end", f"{r['seconds']:.1f} s", "≤ 30 s",
                     ", ".join(f"{k} {v:.1f} s" for k, v in r["stages_s"].items())))
    if "tsdf" in res:
        s = res["tsdf"]
        rows.append(("5. TSDF integration", f"{s['fps']:.0f} frames/s at {s['voxel_mm']:.1f} mm voxels", "–",
                     f"{s['ms_per_frame']:.1f} ms/frame, VoxelBlockGrid (CPU)"))
    lines = [f"Machine: {res['machine']}  ", f"Date: {res['date']}  ", "",
             "| benchmark | tofmetry | target | references (same run) |", "|---|---|---|---|"]
    lines += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("-o", "--output", type=Path, default=Path("bench/results"))
    ap.add_argument("--quick", action="store_true", help="fewer repetitions; skip the slow benchmarks 3-7")
    args = ap.parse_args(argv)
    from bench.frame_pipeline import bench_frame_pipeline, bench_temporal

    res = {"machine": machine(), "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}
    print("1. per-frame pipeline …", file=sys.stderr)
    res["frame_pipeline"] = bench_frame_pipeline(repeat=20 if args.quick else 100, rounds=9 if args.quick else 25)
    print("2. temporal statistics …", file=sys.stderr)
    res["temporal"] = bench_temporal(repeat=10 if args.quick else 40)
    if not args.quick:
        from bench.pipelines import bench_depth_fit, bench_reconstruction

        print("3. depth calibration fit …", file=sys.stderr)
        res["depth_fit"] = bench_depth_fit()
        print("4-5. reconstruction and TSDF …", file=sys.stderr)
        rec, tsdf = bench_reconstruction()
        res["reconstruction"], res["tsdf"] = rec, tsdf
        from bench.correct_stream import bench_correct, bench_correct_memory

        print("6. tofmetry correct, 1000 frames, against the PNG copy …", file=sys.stderr)
        res["correct"] = bench_correct(1000, rounds=5)
        print("7. peak RSS of tofmetry correct, 1000 and 10000 frames …", file=sys.stderr)
        res["correct_memory"] = bench_correct_memory()
    res["peak_rss_mb"] = peak_rss_mb()
    args.output.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.output / "results.json", res)
    md = table(res)
    atomic_write_bytes(args.output / "results.md", (md + "\n").encode())
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
