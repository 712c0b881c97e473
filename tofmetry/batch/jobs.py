"""Job runners: one job of a manifest, run on a worker through the same pipeline functions as the CLI.

Every runner writes into the job's staging folder (:mod:`.outputs`) and returns its key figures
and the path of its report inside the output. :func:`run_whole` wraps a runner: skip when complete,
record a :class:`~tofmetry.errors.TofmetryError` as the job's failure (bad input is not retried),
publish the output with its marker. Any other exception propagates, so that Dask retries the task.
Long recordings go through :mod:`.chunked` instead (see :mod:`.run`).
"""

from __future__ import annotations

import os
import shutil
import socket
import time
from pathlib import Path
from typing import Any, Callable

from pydantic import BaseModel, ConfigDict, ValidationError

from tofmetry.assess import assess_materials, assess_outdoor, regions_from_dict
from tofmetry.errors import InputError, TofmetryError
from tofmetry.evaluate import EvaluationConfig
from tofmetry.io import Capture, atomic_write_bytes, atomic_write_json, read_intrinsics, read_json
from tofmetry.pipelines import (calibrate_depth_dataset, load_calibration, save_calibration, validate_depth,
                                write_depth_report, write_validation_report)
from tofmetry.pipelines.assess import write_assessment
from tofmetry.pipelines.evaluate import evaluate_files
from tofmetry.pipelines.reconstruct import reconstruct_scan
from tofmetry.reconstruct import ReconstructionConfig
from tofmetry.report import render_html
from tofmetry.study import load_config
from tofmetry.study.pipeline import StudyPipeline
from tofmetry.study.summary import build_report, report_json

from tofmetry.batch.outputs import completed, fresh_staging, input_hashes, publish, settings_hash, staging_dir


class _Opts(BaseModel):
    model_config = ConfigDict(extra="forbid")


class CalibrateOpts(_Opts):
    reference_offset_mm: float = 0.0
    tilted: bool = True
    squares: str = "auto"
    folds: int = 5
    accept_implausible: bool = False


class ValidateOpts(_Opts):
    reference_offset_mm: float = 0.0
    tilted: bool = False
    cv: bool = False


class CorrectOpts(_Opts):
    float32: bool = False
    accept_implausible: bool = False


class ReconstructOpts(_Opts):
    keep_all: bool = False
    poisson: bool = False
    voxel_mm: float | None = None
    max_mm: float = 2500.0
    global_adjust: bool = True
    amplitude_max_mm: float = 2500.0


class AssessOpts(_Opts):
    analysis: str
    patch: int = 10
    tolerance_mm: float = 1.0
    smooth_s: float | None = None
    final_window_s: float = 600.0
    row: int | None = None
    auto_grey_board: bool = False
    frame: int = 0


class StudyOpts(_Opts):
    accept_implausible: bool = False


OPTIONS: dict[str, type[_Opts] | None] = {
    "calibrate-depth": CalibrateOpts, "validate": ValidateOpts, "correct": CorrectOpts, "reconstruct": ReconstructOpts,
    "evaluate": None, "assess": AssessOpts, "study": StudyOpts,
}
ANALYSES = ("warmup", "noise", "materials", "outdoor")


def options(spec: dict) -> Any:
    """The job's options validated for its kind (evaluate: an :class:`~tofmetry.evaluate.EvaluationConfig`).

    Raises
    ------
    InputError
        Naming the job, its manifest line and the option.
    """
    model = OPTIONS[spec["kind"]] or EvaluationConfig
    try:
        opts = model.model_validate(spec.get("options") or {})
    except ValidationError as exc:
        what = "; ".join(f"options.{'.'.join(str(x) for x in e['loc'])}: {e['msg']}" for e in exc.errors())
        raise InputError(f"job {spec['name']!r} (manifest line {spec.get('line')}, kind {spec['kind']}): {what}") from None
    if spec["kind"] == "assess" and opts.analysis not in ANALYSES:
        raise InputError(f"job {spec['name']!r} (manifest line {spec.get('line')}): options.analysis must be one of "
                         f"{list(ANALYSES)}, found {opts.analysis!r}")
    return opts


def where() -> str:
    """``host:pid`` of the process running a task."""
    return f"{socket.gethostname()}:{os.getpid()}"


def failed(spec: dict, exc: BaseException, seconds: float = 0.0) -> dict:
    """The record of a job that failed with ``exc``."""
    return {"name": spec["name"], "kind": spec["kind"], "sensor": spec.get("sensor"), "status": "failed",
            "error_type": type(exc).__name__, "error": str(exc), "seconds": seconds, "worker": where()}


def dependency_failure(spec: dict, deps: list[dict]) -> dict | None:
    """A failed record when a job this one needs did not finish."""
    bad = [d["name"] for d in deps if d.get("status") not in ("ok", "skipped")]
    if not bad:
        return None
    return failed(spec, InputError(f"job(s) {', '.join(bad)} that {spec['name']!r} reads did not finish"))


# -------------------------------------------------------------------------------------- runners
def _intrinsics(spec: dict):
    p = spec["inputs"].get("intrinsics")
    return None if p is None else read_intrinsics(p)


def _calibrate(spec: dict, st: Path, o: CalibrateOpts) -> tuple[dict, str]:
    run = calibrate_depth_dataset(Path(spec["inputs"]["dataset"]), intrinsics=_intrinsics(spec),
                                  tilted=o.tilted, reference_offset_mm=o.reference_offset_mm, squares=o.squares,
                                  k_folds=o.folds, provenance={"batch_job": spec["name"]},
                                  accept_implausible=o.accept_implausible)
    save_calibration(st / "calibration.npz", run.calibration)
    write_depth_report(run, st / "report")
    cal = run.calibration
    interp = ((cal.prediction or {}).get("interpolation") or {})
    fig = {"kind": run.kind, "offset_mm": getattr(cal, "offset_mm", None), "fit_seconds": run.seconds}
    for key in ("rms_mm", "central_abs_mm", "p95_mm"):
        v = interp.get(key) or {}
        fig[f"predicted_{key}"] = v.get("predicted", v.get("median"))
    return fig, "report/fit.json"


def _validate(spec: dict, st: Path, o: ValidateOpts) -> tuple[dict, str]:
    ds = Path(spec["inputs"]["dataset"])
    if (ds / "board.json").is_file():
        raise InputError(f"{ds}: batch validation runs on wall datasets (stations.csv); use 'tofmetry calibrate "
                         "validate' for a board dataset")
    run = validate_depth(ds, load_calibration(spec["inputs"]["calibration"]), intrinsics=_intrinsics(spec),
                         tilted=o.tilted, reference_offset_mm=o.reference_offset_mm, cross_validate=o.cv)
    write_validation_report(run, st)
    s, chk = run.summary, run.prediction_check or {}
    fig = {k: s.get(k) for k in ("n_stations", "max_abs_dev_before_mm", "max_abs_dev_after_mm",
                                 "mean_plane_std_after_mm", "median_rms_reduction")}
    fig["measured_rms_mm"] = (chk.get("rms_mm") or {}).get("measured")
    fig["predicted_rms_mm"] = (chk.get("rms_mm") or {}).get("predicted")
    fig["prediction_verdict"] = chk.get("verdict")
    return fig, "validation.json"


def _reconstruct(spec: dict, st: Path, o: ReconstructOpts) -> tuple[dict, str]:
    cfg = ReconstructionConfig()
    cfg.segment.keep_all = o.keep_all
    cfg.fusion.poisson = o.poisson
    cfg.fusion.voxel_mm = o.voxel_mm
    cfg.preprocess.max_mm = o.max_mm
    cfg.registration.global_adjust = o.global_adjust
    inp = spec["inputs"]
    res = reconstruct_scan(inp["scan"], inp.get("calibration"), st, config=cfg,
                           amplitude_wall=inp.get("amplitude_reference"), amplitude_max_mm=o.amplitude_max_mm, force=True)
    d = res.diagnostics
    return {"views": len(res.names), "reliable": bool(d.get("reliable", True)), "mesh_vertices": len(res.mesh_vertices),
            "points": len(res.points), "pipeline_seconds": (d.get("timings_s") or {}).get("total_s")}, "poses.json"


def _evaluate(spec: dict, st: Path, cfg: EvaluationConfig) -> tuple[dict, str]:
    inp = spec["inputs"]
    run = evaluate_files(inp["model"], inp["reference"], st, config=cfg, poses=inp.get("poses"), force=True)
    stats = run.result.to_dict().get("stats_trimmed") or {}
    return {k: v for k, v in stats.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}, "metrics.json"


def _assess_whole(spec: dict, st: Path, o: AssessOpts) -> tuple[dict, str]:
    cap = Capture(spec["inputs"]["capture"])
    intr, _ = cap.intrinsics(_intrinsics(spec))
    kw = {}
    if o.analysis == "materials":
        regs = None
        if "regions" in spec["inputs"]:
            regs = regions_from_dict(read_json(spec["inputs"]["regions"], "regions"), cap.shape, spec["inputs"]["regions"])
        elif not o.auto_grey_board:
            raise InputError(f"job {spec['name']!r}: materials needs inputs.regions or options.auto_grey_board = true")
        res = assess_materials(cap, regs, intr=intr, auto_grey_board=o.auto_grey_board)
        fig = {"slope_mm_per_ln": res.slope_mm_per_ln, "regions": len(res.regions)}
    elif o.analysis == "outdoor":
        res = assess_outdoor(cap, intr=intr, frame=o.frame)
        fig = {"valid_fraction": res.valid_fraction, "flying_share": res.flying_share}
        kw = {"intrinsics": intr, "cloud_ply": "outdoor_cloud.ply"}
    else:
        raise InputError(f"job {spec['name']!r}: analysis {o.analysis!r} runs in chunks, not whole")
    write_assessment(res, st, f"{o.analysis}.json", **kw)
    return fig, f"{o.analysis}.json"


def _study(spec: dict, st: Path, o: StudyOpts) -> tuple[dict, str]:
    data = spec["inputs"].get("data")
    cfg = load_config(spec["inputs"].get("config"))
    ctx = StudyPipeline(None if data is None else Path(data), st, cfg, accept_implausible=o.accept_implausible).run()
    report = build_report(ctx)
    atomic_write_bytes(st / "report.html", render_html(report).encode())
    atomic_write_json(st / "report.json", report_json(ctx, report))
    bad = [k for k, v in ctx.outcomes.items() if v.status == "failed"]
    if bad:
        raise TofmetryStageError(f"study stage(s) failed: {', '.join(bad)} (see {st.name}/report.html)")
    return {"stages": len(ctx.outcomes), "seconds_total": ctx.total_seconds}, "report.html"


class TofmetryStageError(TofmetryError):
    """A stage of a study job failed (the study's report names it)."""


RUNNERS: dict[str, Callable[[dict, Path, Any], tuple[dict, str]]] = {
    "calibrate-depth": _calibrate, "validate": _validate, "reconstruct": _reconstruct, "evaluate": _evaluate,
    "assess": _assess_whole, "study": _study,
}


def ok_record(spec: dict, hashes: dict, figures: dict, report: str, seconds: float) -> dict:
    return {"name": spec["name"], "kind": spec["kind"], "sensor": spec.get("sensor"), "status": "ok",
            "seconds": seconds, "figures": figures, "report": f"{spec['name']}/{report}", "input_hashes": hashes,
            "settings": settings_hash(spec), "worker": where(), "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ",
                                                                                               time.gmtime())}


def skip_or_start(spec: dict, out: str, deps: list[dict]) -> tuple[dict | None, dict]:
    """``(record, hashes)``: a skipped / failed record when the job need not or cannot run, else None."""
    bad = dependency_failure(spec, deps)
    if bad is not None:
        return bad, {}
    hashes = input_hashes(spec["inputs"])
    done = completed(out, spec, hashes)
    if done is not None:
        return {**done, "status": "skipped", "skipped_seconds": done.get("seconds"), "seconds": 0.0}, hashes
    return None, hashes


def run_whole(spec: dict, out: str, *deps: dict) -> dict:
    """Run one job in one task (every kind but the chunked ones); returns its record."""
    t0 = time.perf_counter()
    try:
        rec, hashes = skip_or_start(spec, out, list(deps))
        if rec is not None:
            return rec
        opts = options(spec)
        st = fresh_staging(out, spec["name"])
        figures, report = RUNNERS[spec["kind"]](spec, st, opts)
        rec = ok_record(spec, hashes, figures, report, time.perf_counter() - t0)
        publish(out, spec, rec)
        return rec
    except TofmetryError as exc:
        shutil.rmtree(staging_dir(out, spec["name"]), ignore_errors=True)
        return failed(spec, exc, time.perf_counter() - t0)
