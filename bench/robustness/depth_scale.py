"""Where a model's scale error comes from: the object's depth error alone, at the true poses, before and after the
support curve; and the calibration's residual on walls, by image region.

``OMP_NUM_THREADS=1 PYTHONPATH=$PWD .venv/bin/python -m bench.robustness.depth_scale --seeds S1,S2,... -o DIR``
``... -m bench.robustness.depth_scale --walls SEED --span Z0,Z1 -o DIR``

A diagnostic. Each seed runs through the family (:func:`bench.robustness.family.run_case` with ``--mat --planned 0.9
--plan-distance``); the object's points of every view are kept as the support curve finds them (the calibrated
depth, camera frame) and as it leaves them, and the truth is ray-cast along each point's own ray on the reference
mesh. Per run:

* ``depth_scale_{before,after,truth}_pct``: the model's scale (the surface offset fitted beside it, as
  :func:`tofmetry.evaluate.scale_from_reference`) of the object's points put at the **true** poses: what the depth
  alone does to the scale, the registration left out (``truth``: the ray-cast points, a check: 0);
* per view (``views.{before,after}.NAME``): the object's median depth error [mm], its slope against Z [%] (the
  depth-direction gain of that view), the slope with the image position ``x, y`` fitted beside it, and with
  ``ln(1 / cos(incidence))`` beside it (its coefficient [mm]), the median depth [mm];
* ``poses_scale_pct``: the true points of every view placed by the poses the run ended with (those the fusion got),
  carried onto the truth by those poses' best rigid fit (:func:`tofmetry.evaluate.pose_errors`): what the poses
  alone do to the scale; ``placed_scale_pct``: the measured points after the support curve placed so (the two
  together, before the fusion); ``poses_views.NAME``: how far the view's aligned pose error moves the object's
  centre [mm], along the line of sight (positive: away from the camera), sideways and up, and the camera's true
  elevation over the object's centre [deg] (not in the session 60 rows: there from the drawn path).

``--walls SEED --span Z0,Z1``: the sensor of ``SEED`` calibrated as the family does (walls alone, no tilt boards), then
fronto-parallel walls every 25 mm over the span rendered and corrected; per image region (the centre, where an object
stands; the rows where the support lies near the object's depths; the top) the median residual per wall and its
slope over the span.

Measured (2026-12-06, session 59) at eb77ec2 on twelve development runs (``bench/results/depth_scale_dev_rows.jsonl``):
six whose placements stood unrefined and whose scale missed 0.2 % (fandisks 1626370171 +0.61 % and 1105210102
+0.36 %, igea 1849884082 +0.39 %, baluster 1758384059 +0.23 %, rocker arm 1545538445 +0.26 %, box 1942005185
-0.41 %), three other unrefined, a held bunny 184071080 (-0.22 %), bar 1592026448 (-0.21 %) and rocker arm.

* On the fandisks, the igea and the baluster the depth alone, at the true poses, gives the run's scale within 0.18 %
  (+0.49, +0.38, +0.57, +0.25 %); so does the held bunny's (-0.15 %). The box's, the bar's and the rocker arm
  1545538445's come from the poses (the depth alone -0.03, +0.01, -0.11 %).
* The support curve takes most of the object's depth slope (mean over the views +3.81 -> +0.74 %, -1.29 -> +0.45 %,
  +1.08 -> +0.46 %, -6.30 -> -0.67 %) but leaves +0.2 to +0.9 % of it in the same sense in every view, and on the
  held bunny puts -0.46 % where there was +0.12 %. Neither the image position nor ``ln(1 / cos(incidence))`` fitted
  beside it explains that rest (the slope changes by 0.2 % at most). The scale follows it: about 0.6 times the
  views' mean slope.
* On walls (``--walls``, ``bench/results/depth_scale_dev_walls_rows.jsonl``) the calibration's residual between its
  stations is steeper at the image centre, where the object stands, than on the rows where the support lies near
  it: fandisk 1626370171 over 875-1025 mm +4.00 against +3.65 / +3.41 %, baluster 1758384059 over 1000-1325 mm +1.54
  against +1.22 / +1.01 %; fandisk 1105210102 over 625-775 mm -3.00 against -2.98 / -2.97 % (its levels 0.3-0.5 mm
  apart instead). The igea 1849884082's object slope (+1.27 %) is not on its walls over 600-700 mm (-0.50 % at the
  centre): something of the object itself.

With ``--set preprocess.support_curve_stations=true`` (the curve's ``1``, ``Z``, ``Z^2`` tied to the calibration's
stations; nine of the runs, ``bench/results/depth_scale_dev_stations_rows.jsonl``, rows of this tool's first
version: run and depth-alone scales only) the depth alone came closer on 7 of 9 (|.| mean 0.285 -> 0.247 %), the
runs' scale not (|.| mean 0.235 -> 0.221 % over 8 separable, 5 -> 5 beyond 0.2 %).

With the support read in the object's own image columns (``--set preprocess.support_curve_columns=0.05``, an option,
off; ``bench/results/depth_scale_dev_columns_rows.jsonl``): the depth alone leaves 0.23 -> 0.14 % of scale on
average over the twelve (better on 9: fandisk 1626370171 +0.49 -> +0.21 %, fandisk 1105210102 +0.38 -> +0.18 %,
baluster 1758384059 +0.25 -> +0.11 %, held bunny 184071080 -0.15 -> -0.04 %; worse on a bunny 982114271 +0.03 ->
+0.17 %); the runs' scale |.| mean 0.238 -> 0.215 % over 11 separable, 7 -> 6 beyond 0.2 % (the rest is the poses':
rocker arm 1212029075 +0.01 -> +0.23 %, its depth -0.50 -> -0.25 % no longer offset by them).

With the curve changing across the image (``--set 'preprocess.support_curve_lateral=["x2"]'``, an option, off:
``e(Z) + x^2 / 0.25 h(Z)`` from the whole support; session 60, ``bench/results/depth_scale_dev_lateral_x2_rows.jsonl``):
the depth alone leaves 0.231 -> 0.176 % of scale on average over the twelve (fandisk 1626370171 +0.49 -> +0.24 %,
baluster +0.25 -> +0.10 %, rocker arm 1212029075 -0.50 -> -0.20 %, held bunny 184071080 -0.15 -> -0.04 %; fandisk
1105210102 +0.38 -> +0.40 %, bunny 982114271 +0.03 -> +0.15 %); the runs' scale |.| mean 0.238 -> 0.248 % over 11.
With ``["x2", "y2"]`` (``depth_scale_dev_lateral_x2y2_partial_rows.jsonl``, stopped) the fandisk 1626370171's
object fell off its reference (45 points within 3 mm) and the bunny 454453909's depth went -0.09 -> +1.21 %: on a
support Z follows the image row, so ``y^2 h(Z)`` and ``e(Z)`` part only across views.

The depth's share and the poses' share (session 60, the default config, ``bench/results/depth_scale_dev_poses_rows
.jsonl``) add up: the depth alone plus the poses alone gives the placed points' scale within 0.025 % on eleven of
twelve (0.056 % on the rocker arm 1212029075), and those the run's within 0.1 % on ten (0.12 and 0.16 % on the
rocker arms: the fusion and the model's own alignment). Depth / poses / run [%]: fandisk
1626370171 +0.49 / +0.13 / +0.61, fandisk 1105210102 +0.38 / +0.00 / +0.36, igea 1849884082 +0.57 / -0.07 / +0.39,
baluster 1758384059 +0.25 / +0.03 / +0.23, rocker arm 1545538445 -0.11 / +0.25 / +0.26, rocker arm 1212029075 -0.50
/ +0.41 / +0.01, box 1942005185 -0.03 / -0.36 / -0.41, held bar 1592026448 +0.01 / -0.20 / -0.21, held bunny
184071080 -0.15 / -0.01 / -0.22. Of these nine (beyond 0.2 %, or offset), the depth's share leads on five, the
poses' on four. On the unrefined runs the poses bring the object's centre toward the cameras (``along_mm``, the
most per run 0.4-2.5 mm; the held runs 0.1-0.65 mm): nearly alike over a run's views, an offset more than a scale.
The box's -0.36 % comes with every view but one within 0.1 mm there: from the views' rotations, not their lift.
On the two rocker arms (two rings of views each) the lift follows the elevation: 1.05-2.54 mm on rocker arm
1212029075's ring at 15 deg, 0.03-0.95 mm on its ring at 55 deg (1545538445: 0.36-1.89 mm at 8-21 deg, -0.07 to
+0.14 mm at 55 deg), as a support plane's error at the object over ``sin(elevation)`` would (session 58). The low
ring sees the object's sides, the high ring its top; the sides standing out more than the top read as a larger
object: their +0.41 and +0.25 %.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path
from unittest import mock

import numpy as np

from bench.robustness import family
from bench.robustness.mat_lift import cast_from, scan_truth
from tofmetry.calibrate import wall_sample
from tofmetry.errors import InputError
from tofmetry.evaluate import pose_errors, scale_from_reference
from tofmetry.io.mesh import Geometry
from tofmetry.reconstruct import _pipeline
from tofmetry.simulate.family import random_sensor
from tofmetry.simulate.walls import wall_station_means

#: a point's depth error beyond this is a flying or mixed pixel, left out of the fits [mm]
MAX_DZ_MM = 20.0
#: image regions of ``--walls`` on normalised rays (x, y): the centre, the support's rows near the object, the top
REGIONS = {"centre": lambda x, y: (np.abs(x) < 0.1) & (np.abs(y) < 0.1),
           "support_near": lambda x, y: (y > 0.03) & (y < 0.16) & (np.abs(x) < 0.6),
           "support_far": lambda x, y: (y > 0.16) & (y < 0.4) & (np.abs(x) < 0.6),
           "top": lambda x, y: (y < -0.2) & (np.abs(x) < 0.6)}


def _captured_run(seed: int, work: Path, config=None) -> tuple[dict, dict]:
    """The family row of ``seed`` and each view's object points before and after the support curve."""
    cap: dict = {}
    correct = _pipeline.ReconstructionPipeline.correct_by_support

    def snapshot(views, segs):
        return [(v.name, v.points[s.object_mask].copy()) for v, s in zip(views, segs)]

    def correct_by_support(self, views, segs, intr, anchors=None, level=True):
        cap.setdefault("before", snapshot(views, segs))
        report = correct(self, views, segs, intr, anchors, level)
        cap["after"] = snapshot(views, segs)
        return report

    def fuse(self, views, segs, poses, intr):  # the final poses, camera-to-world in the fit's own frame
        cap["poses"] = {v.name: np.array(T) for v, T in zip(views, poses)}
        return fusion(self, views, segs, poses, intr)

    fusion = _pipeline.ReconstructionPipeline.fuse
    with mock.patch.object(_pipeline.ReconstructionPipeline, "correct_by_support", correct_by_support), \
            mock.patch.object(_pipeline.ReconstructionPipeline, "fuse", fuse):
        row = family.run_case(seed, work, mat=True, planned=0.9, plan_distance=True, keep=True, config=config)
    return row, cap


def _scale_pct(points: list[np.ndarray], ref) -> tuple[float | None, str | None]:
    """The scale error [%] of the points (world [m]) against the reference, the offset fitted beside it; None
    and why where it cannot be read."""
    try:
        s = scale_from_reference(np.concatenate(points), ref)
    except InputError as exc:  # the points no longer meet the reference (a curve that broke)
        return None, str(exc)
    return (round(100 * s["scale_error"], 4), None) if np.isfinite(s["scale_error"]) else (None, "not separable")


def poses_share(cap: dict, true: dict, true_cam: dict, vertices: np.ndarray, ref) -> dict:
    """The scale the final poses give: each view's true object points (camera frame, ``true_cam``) and its
    measured ones after the support curve, placed by the poses the run ended with and carried onto the truth by
    the best rigid fit of those poses (:func:`tofmetry.evaluate.pose_errors`)."""
    est = cap.get("poses") or {}
    names = [n for n, _ in cap["after"] if n in est and n in true_cam]
    if len(names) < 2:
        return {"poses_scale_why": "fewer than two views reached the fusion"}
    E = np.array([est[n] for n in names])
    G = pose_errors(E, np.array([true[n] for n in names]), vertices).alignment
    placed = {n: G @ E_j for n, E_j in zip(names, E)}  # camera -> true world, by the run's poses
    measured = dict(cap["after"])
    out = {"poses_views": {}}
    c = np.mean(vertices, axis=0)
    for n in names:  # the object's centre moved by the view's aligned pose error [mm]
        T = true[n]
        d = 1e3 * ((placed[n] @ np.linalg.inv(T))[:3] @ np.r_[c, 1.0] - c)
        sight = (c - T[:3, 3]) / np.linalg.norm(c - T[:3, 3])  # camera -> object
        side = np.cross([0.0, 0.0, 1.0], sight)
        side /= np.linalg.norm(side)
        out["poses_views"][n] = {"along_mm": round(float(d @ sight), 3), "side_mm": round(float(d @ side), 3),
                                 "up_mm": round(float(d[2]), 3),
                                 "elevation_deg": round(float(np.degrees(np.arcsin(-sight[2]))), 1)}
    for key, pts in (("poses", true_cam), ("placed", measured)):
        world = [pts[n] @ placed[n][:3, :3].T + placed[n][:3, 3] for n in names]
        out[f"{key}_scale_pct"], why = _scale_pct(world, ref)
        if why:
            out[f"{key}_scale_why"] = why
    return out


def view_depth_error(P: np.ndarray, T: np.ndarray, scene) -> tuple[np.ndarray, list | None]:
    """One view's object points ``P`` (N, 3) camera frame [m] at the true camera-to-world ``T``: the true points
    (M, 3) world [m] (those whose ray hits the reference) and the figures (module docstring), None when fewer than
    200 points hit within :data:`MAX_DZ_MM`."""
    R, t = T[:3, :3], T[:3, 3]
    xy = P[:, :2] / P[:, 2:3]
    d = np.c_[xy, np.ones(len(P))] @ R.T  # the ray's t along (x, y, 1) is Z
    th, nrm = cast_from(scene, t, d)
    ok = np.isfinite(th)
    true_w = (np.c_[xy, np.ones(len(P))] * th[:, None])[ok] @ R.T + t
    dz, z = 1e3 * (P[ok, 2] - th[ok]), 1e3 * P[ok, 2]
    k = np.abs(dz) < MAX_DZ_MM
    if k.sum() < 200:
        return true_w, None
    cos_i = np.abs(np.sum(nrm[ok] * d[ok] / np.linalg.norm(d[ok], axis=1)[:, None], 1))
    zc = z[k] - np.median(z[k])
    one = np.ones(k.sum())
    slope = np.linalg.lstsq(np.c_[one, zc], dz[k], rcond=None)[0]
    with_xy = np.linalg.lstsq(np.c_[one, zc, xy[ok][k]], dz[k], rcond=None)[0]
    with_inc = np.linalg.lstsq(np.c_[one, zc, np.log(1 / np.clip(cos_i[k], 0.05, 1))], dz[k], rcond=None)[0]
    return true_w, {"level_mm": round(float(np.median(dz[k])), 2), "slope_pct": round(100 * float(slope[1]), 3),
                    "slope_given_xy_pct": round(100 * float(with_xy[1]), 3),
                    "slope_given_incidence_pct": round(100 * float(with_inc[1]), 3),
                    "incidence_mm": round(float(with_inc[2]), 3), "z_mm": round(float(np.median(z[k])))}


def run_seed(seed: int, config=None) -> dict:
    """One seed's row (module docstring)."""
    work = Path(tempfile.mkdtemp(prefix="tof-depth-scale-"))
    try:
        row, cap = _captured_run(seed, work, config)
        true, mesh, scene = scan_truth(work / f"scan-{seed}")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    ref = Geometry(np.asarray(mesh.vertices), np.asarray(mesh.triangles), source="reference")
    sc = row.get("support_curve") or {}
    out = {"seed": seed, "object": row["object"]["name"], "unrefined": any("unrefined" in w for w in row["warnings"]),
           "scale_error_pct": row.get("scale_error_pct"),
           "predicted_scale_sigma_pct": (row.get("scale") or {}).get("predicted_scale_sigma_pct"),
           "support_curve": {k: sc.get(k) for k in ("applied", "levelled", "object_gain_pct", "object_level_mm", "max_abs_mm")},
           "views": {}}
    if "before" not in cap:
        return out | {"why": "the support curve did not run"}
    true_cam = {}
    for stage in ("before", "after"):
        world, true_world = [], []
        for name, P in cap[stage]:
            T = true[name]
            tw, fig = view_depth_error(P, T, scene)
            world.append(P @ T[:3, :3].T + T[:3, 3])
            true_world.append(tw)
            if stage == "before":  # the points move along their rays: the same true points after
                true_cam[name] = (tw - T[:3, 3]) @ T[:3, :3]
            if fig is not None:
                out["views"].setdefault(stage, {})[name] = fig
        for key, pts in ((stage, world),) + ((("truth", true_world),) if stage == "before" else ()):
            out[f"depth_scale_{key}_pct"], why = _scale_pct(pts, ref)
            if why:
                out[f"depth_scale_{key}_why"] = why
    return out | poses_share(cap, true, true_cam, np.asarray(mesh.vertices), ref)


def wall_slopes(seed: int, span_mm: tuple[float, float], step_mm: float = 25.0, n_frames: int = 5) -> dict:
    """``--walls`` (module docstring): per region of :data:`REGIONS`, the median residual [mm] per wall and its
    slope over the span [%]."""
    draw = random_sensor(seed)
    cal, _, _ = family.calibrate_sensor(draw, seed)
    intr = draw.intrinsics
    zs = np.arange(span_mm[0], span_mm[1] + 1e-6, step_mm)
    rays = np.asarray(intr.ray_table(True))
    masks = {k: f(rays[..., 0], rays[..., 1]) for k, f in REGIONS.items()}
    med = {k: [] for k in REGIONS}
    for st in wall_station_means(draw, list(zs), n_frames, seed=seed + 7):
        m = st.mean_mm
        corr, _ = cal.correction(np.nan_to_num(m))
        with np.errstate(invalid="ignore"):
            c = np.where(np.isfinite(m) & (m > 0), m - corr, np.nan)
        r = c - wall_sample(c, st.optical_centre_mm, intr, name=st.name)[0].reference_mm
        for k, msk in masks.items():
            med[k].append(float(np.nanmedian(r[msk])))
    return {"seed": seed, "walls_mm": [float(z) for z in zs],
            "regions": {k: {"residual_mm": [round(v, 3) for v in med[k]],
                            "slope_pct": round(100 * float(np.polyfit(zs, med[k], 1)[0]), 3)} for k in REGIONS}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", help="comma-separated seeds")
    ap.add_argument("--walls", type=int, help="a seed whose sensor's calibrated walls are compared by image region")
    ap.add_argument("--span", default="800,1000", help="--walls: the walls' span Z0,Z1 [mm]")
    ap.add_argument("-o", "--output", type=Path, default=Path("bench/results"))
    ap.add_argument("--set", action="append", default=[], metavar="STAGE.FIELD=JSON",
                    help="override one field of the reconstruction config (repeatable; bench.robustness.family's)")
    a = ap.parse_args(argv)
    if (a.seeds is None) == (a.walls is None):
        ap.error("give --seeds or --walls")
    a.output.mkdir(parents=True, exist_ok=True)
    if a.walls is not None:
        r = wall_slopes(a.walls, tuple(float(x) for x in a.span.split(",")))
        with open(a.output / "depth_scale_walls_rows.jsonl", "a") as fh:
            fh.write(json.dumps(r) + "\n")
        for k, v in r["regions"].items():
            print(f"{k:<13} slope {v['slope_pct']:+.2f} %: " + " ".join(f"{x:+.2f}" for x in v["residual_mm"]))
        return 0
    config = family.config_with(a.set) if a.set else None
    for s in (int(x) for x in a.seeds.split(",")):
        r = run_seed(s, None if config is None else config.model_copy(deep=True))
        r["set"] = a.set
        with open(a.output / "depth_scale_rows.jsonl", "a") as fh:
            fh.write(json.dumps(r) + "\n")
        print(f"{s:>10} {r['object']:<11} {'unrefined' if r['unrefined'] else 'held':<9} scale {r['scale_error_pct']} %; "
              f"the depth alone at the true poses {r.get('depth_scale_before_pct')} % before the support curve, "
              f"{r.get('depth_scale_after_pct')} % after (truth {r.get('depth_scale_truth_pct')}); the true depth at the "
              f"final poses {r.get('poses_scale_pct')} %, the measured {r.get('placed_scale_pct')} %", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
