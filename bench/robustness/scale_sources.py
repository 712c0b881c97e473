"""Where a model's scale error comes from: the same views judged at each stage of the chain.

``PYTHONPATH=$PWD .venv/bin/python -m bench.robustness.scale_sources --seeds S1,S2 [--mat] [--planned T] [--errors TERMS]
[--set STAGE.FIELD=JSON ...] [-o DIR]``

A family draw (:mod:`bench.robustness.family`: object, path, sensor, calibrated by tofmetry's own chain; with
``--mat`` standing on its dot mat) is scanned, and the scale of what each stage makes of its views is fitted
against the reference mesh by :func:`tofmetry.evaluate.scale_from_reference` (the family's own measure: a
rigid motion, a scale about the centroid and an offset along the normals):

* ``points_true``: the views' prepared object points placed by the **true** poses (the depth chain alone:
  calibration, amplitude correction with the coefficient the boards measure, noise; no registration, no
  fusion), those more than half the segmentation's minimum height above the ground;
* ``fused_true``: those views fused at the true poses, cropped to the object as the pipeline crops and judged
  as the family judges a model (the depth chain and the fusion);
* ``model``: the reconstruction as ``tofmetry reconstruct`` makes it (registration, joint fit, fusion),
  aligned to the reference as the family aligns it.

So a scale error present in ``points_true`` is the sensor's (what the calibration leaves, or the measure's own
response to noise on this shape), one that appears in ``fused_true`` the fusion's, and the rest the poses'.
``--errors`` keeps only some error terms of the sensor (:func:`bench.robustness.drift.keep_errors`); without the
amplitude bias the amplitude correction is switched off as well.

Measured (2026-12-06, session 54; rows ``bench/results/scale_sources_dev105_106_igea_terms_rows.jsonl``): the two
igeas whose points read -0.44 and -0.60 % at the true poses, with one error term of the sensor at a time beside the
noise (``--errors noise,TERM``), points / fused / model. 1262340483: noise alone -0.08 / - / +0.01 %, with the
amplitude bias -0.24 / -0.36 / -0.21 % (its coefficient measured within 0.05 mm per ln unit of the truth: what is
left is the bias's form on a head seen at every incidence, not its size), the per-pixel deformation -0.16 / -0.30 / -,
the range curve (wiggling) -0.11 / -0.25 / -, flying pixels -0.05 / - / -; no one term makes it, and the fusion adds
-0.12 to -0.14 % on this small head (0.16 m) whatever the term. 1430467187 (0.30 m, predicted scale sigma 0.62 %: its
calibration's predicted central error is 4.2 mm): noise alone -0.04 / -0.03 / +0.01 %, the range curve -0.39 +-
0.18 / - / -0.09 % (the flat support's curve, :mod:`tofmetry.reconstruct._support_curve`, takes most of it out of
the model), every other term within 0.05 % of the noise's. So the misses of these heads are the sum of several
terms' few tenths of a millimetre over the object, read as a scale where scale and offset barely differ, not one
error a single correction would remove.

Measured (2026-12-06, session 53; ``--plan-distance`` for draws 106-107's seeds; rows
``bench/results/scale_sources_dev105_107_igea_fandisk_rows.jsonl``): the eight held-out runs of draws 105-107 whose
scale lay beyond 0.2 % but two. Six igeas (scale/offset correlation -0.978 to -0.980, on the family's 0.98 line:
``fused_true`` falls on its far side on four of them and reads "not separable"), points / fused / model:
777095218 -0.12 / - / -0.59 %, 1262340483 -0.44 / - / -0.43 %, 1402597130 +0.07 / +0.06 / -0.65 %,
1430467187 -0.60 / - / -0.45 %, 1409541855 -0.12 / - / -0.24 %, 1647792163 -0.11 / -0.06 / +0.22 %; two fandisks
(correlation -0.87) -0.11 / -0.12 / -0.26 % and -0.05 / -0.09 / -0.22 %. So on two igeas the depth chain alone,
at the true poses, reads -0.44 and -0.60 %: their points' signed distance runs with height (the upper tenth
-0.19 mm against the lowest +0.02 mm; +0.22 against -0.12 mm), a few tenths of a millimetre that a head of
0.16-0.30 m, where scale and offset barely differ, reads as half a per cent. Fitted with an offset per region
instead (16 k-means regions) the same points read -0.24 and -0.49 %. The four others' errors are their poses'.

Measured (2026-12-05, session 45): draw 92's dome 1716637505 +0.76 / +0.21 / +0.59 % (offsets -0.69 / -0.27 /
-0.60 mm) and the development vase 1220163138 +1.52 / +1.50 / -0.52 % (offsets -0.44 / -0.48 / +0.76 mm): near a
surface of revolution the fitted scale trades against the offset (correlation 0.97-0.98), and a few tenths of a
millimetre of surface error that varies over the object swing the scale by a per cent either way.

Measured (2026-12-04, session 44, after the amplitude correction's reference was fixed): draw 90's plaques 229085989
-0.12 / -0.02 / +0.26 % (its poses') and 755125470 +0.07 / +0.20 / +0.26 % (offset -0.33 mm through the chain), its igea
887220926 +0.87 / +0.29 / +0.27 % (its own points').

Measured (2026-12-04, session 43): draw 88's plaques 745329806 -0.03 / +0.21 / +0.29 % and 974295433 +0.06 / +0.22 /
+0.36 %: on thin objects the fusion adds +0.16-0.24 % (the truncation band fattens the rim; ``FusionConfig``), and
1811854792 +0.23 / +0.25 / +0.77 % (its poses).

Measured (2026-12-02, session 32, with the stages above): the plaque 1118179638 (draw 72, 6 views at 0.80 m,
its drawn path) +0.01 % at the true poses, +0.07 % fused there, +0.59 % through the chain: its scale error is the
poses'. The plaque 1558612541 +0.29 / +0.19 / +0.71 %, the igea 412929893 +0.52 / +0.42 / +0.33 %. Before
session 32 the first two stages ran without the boards' coefficient (the default one), and ``fused_true`` took
the fused vertices within 0.75 object sizes of the centre, the ground ring with them: the plaque 1118179638 read
+0.015 % (offset -0.26 mm) and +0.32 %.

Earlier (2026-12-02, session 30, 5066a02: every stage on smoothed depth; the first two stages as they were
before session 32; docs/history/object-models.md), two development draws of draw 68 on the mat: a plaque (1558612541, 0.22 m, 11 hand-held views at 0.68 m) +0.28 % at the true poses
(points), +0.35 % fused there, +0.71 % through the chain (the poses put its faces 0.5 mm closer); an igea
(412929893, 0.19 m, 14 views at 0.76 m) +0.46 / +0.40 / +0.53 %: its scale error is the depth chain's. Before
the smoothing the plaque's points at the true poses read +1.14 % (the measure's response to 2-3 mm of noise per
view's mean on a slab) and its model +1.06 %. Without the sensor's noise the igea's points read +0.29 %, 0.12 % of
it what the amplitude correction leaves (``--errors`` without ``amplitude_bias``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from bench.robustness.drift import keep_errors
from bench.robustness.family import (board_captures, calibrate_sensor, config_with, draw_case, draw_mat, judging_config,
                                     plan_min_distance_m)


def _scale(points: np.ndarray, ref) -> dict:
    from tofmetry.evaluate import scale_from_reference

    try:
        sc = scale_from_reference(points, ref)
    except Exception as exc:  # noqa: BLE001 - a stage with too few points is a result
        return {"error": f"{type(exc).__name__}: {exc}"[:200]}
    return {"scale_pct": round(100 * sc["scale_error"], 4), "offset_mm": round(sc["offset_mm"], 3),
            "sigma_pct": round(100 * sc["sigma"], 4), "correlation": round(sc["correlation"], 4)}


def sources_case(seed: int, work: Path, mat: bool = False, errors: str = "all", config=None, n_frames: int = 5,
                 planned: float | None = None, plan_distance: bool = False) -> dict:
    """One draw's scale at each stage (module docstring); returns one JSON-able row. ``plan_distance``:
    with ``planned``, the views stand no nearer than the plan with the calibration places them, as
    ``family --plan-distance`` draws them (:func:`bench.robustness.family.run_case`)."""
    from tofmetry.evaluate import evaluate_model
    from tofmetry.io import ScanDataset, read_json
    from tofmetry.io.mesh import Geometry
    from tofmetry.pipelines.amplitude_slope import amplitude_slope_from_boards
    from tofmetry.pipelines.reconstruct import reconstruct_scan, with_measured_amplitude_slope
    from tofmetry.reconstruct import ReconstructionConfig, ReconstructionPipeline, poses_document
    from tofmetry.reconstruct._model_build import crop_model, fuse_views
    from tofmetry.reconstruct._pipeline import _no_progress
    from tofmetry.simulate import datasets

    d = keep_errors(draw_case(seed, planned=planned), errors)
    cal, white, _ = calibrate_sensor(d.sensor, seed, tilt_work=work)
    near = plan_min_distance_m(d, cal) if plan_distance and planned is not None else None
    if near is not None:
        d = keep_errors(draw_case(seed, planned=planned, min_distance_m=near), errors)
    if errors != "all" and "amplitude_bias" not in d.sensor.errors.enabled:
        white = None
    boards = board_captures(d.sensor, seed, work) if white is not None else None
    dm = draw_mat(seed) if mat else None
    scan_dir = work / f"scan-{seed}"
    datasets.scan(scan_dir, n_frames=n_frames, mesh=d.mesh, poses=d.path.poses, sensor=d.sensor, seed=seed,
                  force=True, info=d.describe(), mat=dm)
    cfg = config or ReconstructionConfig()
    if dm is not None:
        cfg.registration.mat = dm.to_dict()
    ref = Geometry(d.object.vertices, d.object.triangles, source="reference")
    ds = ScanDataset(scan_dir)
    # the views' depth as reconstruct_scan prepares it: with the amplitude coefficient the boards measure
    # (before 2026-12-02 these two stages ran with the default coefficient, and read the bias it leaves)
    cfg_views = cfg if boards is None else with_measured_amplitude_slope(
        cfg, amplitude_slope_from_boards(boards, cal))
    views, segs, _, intr = ReconstructionPipeline(ds, cal, cfg_views, white_map=white).load_views()
    by = {v["name"]: np.asarray(v["camera_to_world"]) for v in read_json(scan_dir / "truth.json")["views"]}
    W = np.array([by[n] for n in ds.names])
    pts = np.concatenate([v.points[s.object_mask] @ T[:3, :3].T + T[:3, 3] for v, s, T in zip(views, segs, W)])
    above = pts[:, 2] > float(d.object.vertices[:, 2].min()) + 0.5 * cfg.segment.min_height_mm * 1e-3
    row = {"seed": int(seed), "object": d.object.name, "size_m": round(float(d.object.size_m), 4),
           "path": d.path.kind, "distance_m": round(float(d.path.distance_m), 4), "n_views": int(d.path.n_views),
           "mat": mat, "errors": errors,
           "points_true": _scale(pts[above], ref)}
    # fused at the true poses, cropped to the object as the pipeline crops (the true ground is z = 0) and
    # judged as the family judges a model (aligned, the reference's underside left out)
    V, F, N, P, PN, info = fuse_views(views, segs, W, intr, cfg_views, _no_progress)
    V, F = crop_model(V, F, N, P, PN, pts, np.array([0.0, 0.0, 1.0, 0.0]), cfg_views, info["crop_margin_mm"])[:2]
    ev_true = evaluate_model(Geometry(V, F, source="fused at the true poses"), ref, judging_config())
    row["fused_true"] = _scale(ev_true.points, ref) | {"mean_signed_mm": round(ev_true.stats_trimmed.mean_signed_mm, 3)}
    res = reconstruct_scan(scan_dir, cal, None, config=cfg_views, white_map=white)  # the boards' coefficient, fitted once
    model = Geometry(res.mesh_vertices, res.mesh_triangles, source="model")
    ev = evaluate_model(model, ref, judging_config(), poses=poses_document(res))  # as the family aligns it
    row["model"] = _scale(ev.points, ref) | {"mean_signed_mm": round(ev.stats_trimmed.mean_signed_mm, 3)}
    row["reliable"] = bool(res.diagnostics.get("reliable"))
    shutil.rmtree(scan_dir, ignore_errors=True)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True, help="comma-separated family seeds")
    ap.add_argument("--mat", action="store_true", help="each object stands on its dot mat (family --mat)")
    ap.add_argument("--planned", type=float, default=None, metavar="TARGET",
                    help="the views the plan proposes for this completeness (family --planned)")
    ap.add_argument("--plan-distance", action="store_true",
                    help="with --planned, the views no nearer than the plan with the calibration places them (family --plan-distance)")
    ap.add_argument("--errors", default="all", help="error terms of the sensor kept (drift.keep_errors)")
    ap.add_argument("--set", action="append", default=[], metavar="STAGE.FIELD=JSON",
                    help="override one field of the reconstruction config (repeatable)")
    ap.add_argument("-o", "--output", type=Path, default=None, help="folder for scale_sources_rows.jsonl")
    a = ap.parse_args(argv)
    cfg = config_with(a.set)
    work = Path(tempfile.mkdtemp(prefix="tof-scale-"))
    rows = []
    try:
        for s in [int(x) for x in a.seeds.split(",") if x.strip()]:
            r = sources_case(s, work, a.mat, a.errors, cfg.model_copy(deep=True), planned=a.planned,
                             plan_distance=a.plan_distance)
            rows.append(r)
            print(json.dumps(r), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if a.output is not None:
        a.output.mkdir(parents=True, exist_ok=True)
        (a.output / "scale_sources_rows.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
