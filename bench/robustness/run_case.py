"""Run reconstruct + evaluate on matrix cases; append one JSON line per case to $RB_ROOT/results_<tag>.jsonl.

Usage (see README.md here): RB_ROOT=/tmp/rb TOFMETRY=.venv/bin/tofmetry python bench/robustness/run_case.py TAG CASE...
"""
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from tofmetry.io import read_json
from tofmetry.reconstruct import relative_pose_errors

TAG = sys.argv[1]
EXE = os.environ.get("TOFMETRY", "tofmetry")
RB = os.environ.get("RB_ROOT", "/tmp/rb")


for name in sys.argv[2:]:
    scan = Path(RB + "/scans") / name
    rec = Path(f"{RB}/out/{TAG}/{name}/rec"); ev = rec.parent / "ev"
    shutil.rmtree(rec.parent, ignore_errors=True)
    t0 = time.time()
    r = subprocess.run([EXE, "reconstruct", str(scan), "--calibration", RB + "/cal.npz", "--amplitude-reference",
                        RB + "/wall", "-o", str(rec), "--allow-unreliable"], capture_output=True, text=True, check=False)
    dt = time.time() - t0
    row = {"case": name, "exit": r.returncode, "wall_s": round(dt, 1)}
    if r.returncode != 0:
        row["error"] = (r.stderr + r.stdout)[-600:]
    else:
        pj = read_json(rec / "poses.json")
        poses = np.array([v["camera_to_world"] for v in pj["views"]])
        err = relative_pose_errors(poses, [v["camera_to_world"] for v in read_json(scan / "truth.json")["views"]])
        row.update(max_rot_deg=round(float(err[:, 0].max()), 3), max_cam_mm=round(float(err[:, 1].max()), 2),
                   reliable=pj.get("reliable"), reasons=pj.get("consistency", {}).get("reasons"))
        for k in ("ambiguity", "refused"):
            if k in pj:
                row[k] = pj[k]
        r2 = subprocess.run([EXE, "evaluate", str(rec / "mesh.ply"), "--reference", str(scan / "reference.ply"), "--poses",
                             str(rec / "poses.json"), "--align", "--exclude-normal", "0,0,-1", "-o", str(ev)],
                            capture_output=True, text=True, check=False)
        if r2.returncode == 0:
            m = read_json(ev / "metrics.json"); st = m["stats_trimmed"]
            row.update(mean=round(st["mean_abs_mm"], 2), std=round(st["std_signed_mm"], 2),
                       p95=round(st["percentiles_abs_mm"]["p95"], 2), max=round(st["max_abs_mm"], 2),
                       compl5=round(m["completeness"]["5"]["completeness"], 3),
                       compl5_obs=round((m.get("completeness_observed") or {}).get("5", {}).get("completeness", float("nan")), 3))
        else:
            row["eval_error"] = (r2.stderr + r2.stdout)[-400:]
    print(json.dumps(row), flush=True)
    with open(f"{RB}/results_{TAG}.jsonl", "a") as fh:
        fh.write(json.dumps(row) + "\n")
