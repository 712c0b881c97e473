"""Time an 8-view reconstruction end to end (target: <= 30 s on 2 cores).

``.venv/bin/python -m bench.robustness.timing [--rounds 3] [--frames 10] [--seed 0] [--mat] [--set STAGE.FIELD=JSON ...]``

The default scan of ``tofmetry simulate scan`` (the balustrade-like object, 8 views at 1 m, 10
frames per view) and a depth calibration fitted by tofmetry's chain on a 5-station wall dataset
are made once; then ``tofmetry.pipelines.reconstruct.reconstruct_scan`` (with the amplitude
reference, writing the model folder, as ``tofmetry reconstruct`` does) is timed ``--rounds``
times, each in a new process so that imports and Open3D's start are counted, pinned to the
machine's cores as given (``taskset``-free: the machine has the cores it has). Prints the median
wall time and the stage timings of the median run, and the machine's load average. ``--mat``: the object stands on a printed dot mat and every view is placed
on it (``tofmetry reconstruct --mat``) instead of registered in a chain.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
from tofmetry.pipelines.reconstruct import reconstruct_scan
cfg = None
if sys.argv[5:]:  # A/B runs only: the family bench's parser of STAGE.FIELD=JSON (imported only then)
    from tofmetry.reconstruct import ReconstructionConfig
    from bench.robustness.family import override
    cfg = ReconstructionConfig()
    for item in sys.argv[5:]:
        cfg = override(cfg, item)
res = reconstruct_scan(sys.argv[1], sys.argv[2], sys.argv[3], config=cfg, amplitude_wall=sys.argv[4], force=True)
print(json.dumps({"wall_s": time.perf_counter() - t0, "stages_s": res.diagnostics["timings_s"],
                  "reliable": res.diagnostics["reliable"], "views": len(res.names)}))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--mat", action="store_true", help="the object on a dot mat, the views placed on it (reconstruct --mat)")
    ap.add_argument("--set", action="append", default=[], metavar="STAGE.FIELD=JSON",
                    help="override one field of the reconstruction config (repeatable; for A/B runs)")
    a = ap.parse_args(argv)
    from tofmetry.simulate import datasets

    work = Path(tempfile.mkdtemp(prefix="tof-timing-"))
    mat = None
    if a.mat:
        from tofmetry._shared.dot_mat import DotMat

        mat = DotMat(seed=a.seed, yaw_deg=20.0)
        a.set.append("registration.mat=" + json.dumps(DotMat(seed=a.seed).to_dict()))
    scan = datasets.scan(work / "scan", n_views=8, n_frames=a.frames, seed=a.seed, mat=mat)
    wall = datasets.wall_dataset(work / "wall", distances_mm=(800, 1000, 1250, 1500, 2000), n_frames=10, seed=a.seed + 1)
    exe = Path(sys.executable).with_name("tofmetry")
    subprocess.run([str(exe), "calibrate", "depth", str(wall), "--reference-offset-mm", "20", "-o", str(work / "cal.npz")],
                   check=True, capture_output=True)
    env = dict(os.environ)
    if a.set:  # the child imports the family bench's STAGE.FIELD=JSON parser: the repository goes first on the path
        env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[2])]
                                            + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    runs = []
    for k in range(a.rounds):
        t = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", CHILD, str(scan), str(work / "cal.npz"), str(work / f"rec{k}"),
                              str(wall), *a.set], capture_output=True, text=True, check=True, env=env)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        r["process_s"] = time.perf_counter() - t
        runs.append(r)
        print(f"round {k + 1}: {r['process_s']:.1f} s in a new process ({r['wall_s']:.1f} s after start-up); stages "
              + ", ".join(f"{n} {v:.1f}" for n, v in r["stages_s"].items()), flush=True)
    runs.sort(key=lambda r: r["process_s"])
    med = runs[len(runs) // 2]
    print(f"8-view reconstruction, median of {a.rounds}: {med['process_s']:.1f} s (target <= 30 s); cores "
          f"{os.cpu_count()}, load average {os.getloadavg()[0]:.2f}; reliable {med['reliable']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
