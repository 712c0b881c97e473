"""Jobs on long recordings: ``correct`` and ``assess`` warm-up / noise, split into chunks of frames.

:func:`run_chunked` is the job's task. It decides whether the job runs (skip, failed dependency),
then, from its worker, submits one task per chunk of frames and a combining task to the same
cluster (``distributed.worker_client``: the task leaves its worker's thread pool while it waits),
so a recording of any length spreads over every worker and each worker holds one chunk at a time.
Noise statistics are merged pairwise on the cluster (a tree), never all on one worker.
"""

from __future__ import annotations

import shutil
import time

from distributed import worker_client

from tofmetry.assess.noise import DEFAULT_BLOCKS, DEFAULT_SUBSETS
from tofmetry.batch import chunked as C
from tofmetry.batch.jobs import failed, ok_record, options, skip_or_start
from tofmetry.batch.outputs import fresh_staging, publish, staging_dir
from tofmetry.errors import TofmetryError
from tofmetry.io import Capture
from tofmetry.pipelines.assess import write_assessment
from tofmetry.pipelines.calibration_files import load_calibration


def is_chunked(spec: dict) -> bool:
    """Jobs that run in chunks of frames: ``correct``, and ``assess`` warm-up and noise."""
    if spec["kind"] == "correct":
        return True
    return spec["kind"] == "assess" and (spec.get("options") or {}).get("analysis") in ("warmup", "noise")


def _finish_correct(spec: dict, out: str, hashes: dict, t0: float, *parts: dict) -> dict:
    o = options(spec)
    inp = spec["inputs"]
    st = staging_dir(out, spec["name"])
    fig = C.correct_finish(inp["capture"], inp["calibration"], str(st), list(parts), accept_implausible=o.accept_implausible)
    rec = ok_record(spec, hashes, fig, "capture.json", time.time() - t0)
    publish(out, spec, rec)
    return rec


def _finish_noise(spec: dict, out: str, hashes: dict, t0: float, part) -> dict:
    o = options(spec)
    res = C.noise_result(part, row=o.row)
    st = staging_dir(out, spec["name"])
    write_assessment(res, st, "noise.json")
    fig = {"n_frames": res.n_frames, "sigma_single_mm": res.sigma_single_mm, "recommended_n": res.recommended_n}
    rec = ok_record(spec, hashes, fig, "noise.json", time.time() - t0)
    publish(out, spec, rec)
    return rec


def _finish_warmup(spec: dict, out: str, hashes: dict, t0: float, plan: dict, *series) -> dict:
    o = options(spec)
    res = C.warmup_result(spec["inputs"]["capture"], plan, list(series), tolerance_mm=o.tolerance_mm,
                          smooth_window_s=o.smooth_s, final_window_s=o.final_window_s)
    st = staging_dir(out, spec["name"])
    write_assessment(res, st, "warmup.json")
    fig = {"n_frames": int(len(res.time_s)), "total_drift_mm": res.total_drift_mm, "drift_range_mm": res.drift_range_mm,
           "stabilisation_time_s": res.stabilisation_time_s}
    rec = ok_record(spec, hashes, fig, "warmup.json", time.time() - t0)
    publish(out, spec, rec)
    return rec


def _tree(c, merge, parts: list, name: str):
    """Merge futures pairwise on the cluster, in frame order; returns one future."""
    level = 0
    while len(parts) > 1:
        nxt = [c.submit(merge, parts[i], parts[i + 1], key=f"{name}-merge-{level}-{i}")
               for i in range(0, len(parts) - 1, 2)]
        if len(parts) % 2:
            nxt.append(parts[-1])
        parts, level = nxt, level + 1
    return parts[0]


def run_chunked(spec: dict, out: str, token: str, *deps: dict) -> dict:
    """Run a chunked job (see :func:`is_chunked`); returns its record.

    ``token`` makes the keys of the chunk tasks unique to this batch run (and the same when Dask
    reruns this task after its worker died, so chunks already computed are reused).
    """
    t0 = time.time()
    try:
        rec, hashes = skip_or_start(spec, out, list(deps))
        if rec is not None:
            return rec
        o = options(spec)
        inp = spec["inputs"]
        cap = Capture(inp["capture"])
        if spec["kind"] == "correct":    # a bad calibration fails here, before any chunk runs
            load_calibration(inp["calibration"]).check_compatible(sensor=cap.sensor, shape=cap.shape)
        n, name = len(cap), f"{token}-{spec['name']}"
        st = str(fresh_staging(out, spec["name"]))
        r = spec.get("retries", 1)
        with worker_client() as c:
            if spec["kind"] == "correct":
                parts = [c.submit(C.correct_chunk, inp["capture"], inp["calibration"], st, a, b, o.float32,
                                  key=f"{name}-chunk-{a}", retries=r) for a, b in C.frame_ranges(n, spec["chunk_frames"])]
                fin = c.submit(_finish_correct, spec, out, hashes, t0, *parts, key=f"{name}-finish", retries=r)
            elif o.analysis == "noise":
                size = max(spec["chunk_frames"], max(DEFAULT_SUBSETS))
                parts = [c.submit(C.noise_chunk, inp["capture"], a, b, key=f"{name}-chunk-{a}", retries=r)
                         for a, b in C.frame_ranges(n, size, C.noise_multiple(DEFAULT_BLOCKS))]
                fin = c.submit(_finish_noise, spec, out, hashes, t0, _tree(c, C.merge_noise, parts, name),
                               key=f"{name}-finish", retries=r)
            else:
                plan = C.warmup_patch(inp["capture"], o.patch)
                parts = [c.submit(C.warmup_chunk, inp["capture"], a, b, plan["patch"], key=f"{name}-chunk-{a}", retries=r)
                         for a, b in C.frame_ranges(n, spec["chunk_frames"])]
                fin = c.submit(_finish_warmup, spec, out, hashes, t0, plan, *parts, key=f"{name}-finish", retries=r)
            rec = fin.result()
        rec["chunks"] = len(parts)
        return rec
    except TofmetryError as exc:
        shutil.rmtree(staging_dir(out, spec["name"]), ignore_errors=True)
        return failed(spec, exc, time.time() - t0)
