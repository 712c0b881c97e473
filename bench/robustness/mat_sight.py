"""How far the dot mat's placements are off along each camera's line of sight, against what the dots' size reads.

``PYTHONPATH=$PWD .venv/bin/python -m bench.robustness.mat_sight ROWS.jsonl [ROWS.jsonl ...] [-o OUT.jsonl]``

A diagnostic on stored family rows (:mod:`bench.robustness.family` with ``--mat``; nothing is simulated or
reconstructed again): each row's object and path are drawn again from its seed (:func:`family.draw_case`, the
distance ``--plan-distance`` raised it to taken from the row), which gives the true camera poses, and each placement
the row stored (``mat_fixes[*].camera_to_mat``) is compared with them after the one rigid alignment
:func:`tofmetry.evaluate.pose_errors` finds on the object's points. Per run:

* ``true_mm``: the placements' common error along their lines of sight [mm] (positive: the cameras stand too far
  back). Only its horizontal, radial part can change the model's size (a common vertical part is a shift the
  alignment takes out), so it is that part divided by the views' mean radial share of their line of sight;
* ``reading_mm``: what the dots' size reads for it, :func:`tofmetry.reconstruct._mat_range.range_offset`'s
  ``delta`` recomputed from the stored per-view pattern scales (distance to the dots: the optical axis cut with the
  sheet), with its 1-sigma ``reading_sigma_mm``;
* ``scale_error_pct``: the model's scale error the row measured.

Measured (2026-12-06, session 54) on the 200 runs of held-out draws 100-109 (all have at least two views placed by
six dots or more; ``bench/results/mat_sight_fresh100_109_rows.jsonl``): the placements stand +0.31 mm too far back on
average (sd 0.35, p90 +0.67 mm); the dots read -0.14 mm (sd 0.64), reading minus truth -0.45 +- 0.54 mm, growing
with distance (about -0.46 mm per metre), 2.3 times the sigma they claim (median 0.23 mm); reading and truth
correlate at 0.52. And the model's scale error does not follow the placements' error along sight (correlation
-0.02 over the 156 runs whose scale is separable; with the reading -0.11): where the joint fit refines the
placements on the object's points, what is left of the model's scale is the object's own (its depth chain, its
shape). So ``registration.mat_range_from_dots`` stays off: the reading is biased and too noisy to take out, and
taking out even the true along-sight error would not move most models' scale. Only the upright plaques of draw 108
(901233449 +0.82 mm, scale -0.71 %; 1247722146 -0.87 mm, +0.49 %) show the expected sign; rocker arms with +1.25
and +1.06 mm came out +0.67 and +0.34 %.

In the mat's own frame, no alignment (``height_mm``, ``outward_mm``; session 57, the 120 runs of held-out draws
110-115, ``bench/results/mat_sight_fresh110_115_rows.jsonl``): the placed cameras stand +0.17 mm too high (sd 0.38)
and +0.28 mm too far out (sd 0.34; the two correlate at 0.72); the outward error runs with the amplitude
coefficient's error (the grey-level boards' k minus the sensor's, correlation -0.72; the height -0.44), but the
true k leaves it as it is (:mod:`bench.robustness.true_k`). Where the placements stood
unrefined (28 runs) the model's mean signed deviation follows the outward error (correlation +0.71; +0.14 mm on
average, against -0.04 mm over the 92 runs whose joint fit held, which takes it out: correlation -0.03). On these
runs the aligned measure above reads +0.31 mm (sd 0.37) and the dots' reading follows it at 0.70, 0.38 mm short.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bench.robustness.family import MESH_DIR, over_stored_rows, stored_placements
from tofmetry.reconstruct._mat_range import widened_fit

#: a view's dots count only where at least this many were matched (as ``registration.mat_min_dots``)
MIN_DOTS = 6


def world_to_mat(yaw_deg: float) -> np.ndarray:
    """(3, 3) rotation from the world to the family's mat frame: the sheet lies centred at the world's origin, its
    long side turned by ``yaw_deg`` about z (:class:`tofmetry._shared.dot_mat.DotMat`), z up in both."""
    a = np.radians(yaw_deg)
    return np.array([[np.cos(a), np.sin(a), 0.0], [-np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def run_sight(row: dict, mesh_dir: Path | None = MESH_DIR) -> dict | None:
    """One stored family row's placements against the truth (module docstring); None where the row has no
    placements (no mat, refused) or fewer than two views placed by ``MIN_DOTS`` dots."""
    got = stored_placements(row, mesh_dir)
    if got is None:
        return None
    d, names, on, placed, true, pm = got
    fixes, p = row["mat_fixes"], row["path"]
    centre = d.object.vertices.mean(0)
    rad_err, rad_share, ps, ps_sig, dist = [], [], [], [], []
    for i, k in enumerate(on):
        e = (pm.alignment @ placed[i])[:3, 3] - true[k][:3, 3]
        back = -true[k][:3, 2]  # from the scene toward the camera
        radial = true[k][:3, 3] - centre
        radial[2] = 0.0
        radial /= np.linalg.norm(radial)
        rad_err.append(float(e @ radial))
        rad_share.append(float(back @ radial))
        f = fixes[names[k]]
        c, z = placed[i][:3, 3], placed[i][:3, 2]
        if ("dots" in f["how"] and f["n_matched"] >= MIN_DOTS and f.get("pattern_scale_sigma_pct")
                and f.get("pattern_scale_pct") is not None and z[2] < -1e-6):
            ps.append(f["pattern_scale_pct"] / 100)
            ps_sig.append(f["pattern_scale_sigma_pct"] / 100)
            dist.append(float(-c[2] / z[2]))
    if len(ps) < 2:
        return None
    # the placements in the mat's own frame against the truth, no alignment: the sheet lies centred at the
    # world's origin, its long side turned by its yaw about z (tofmetry._shared.dot_mat); the mat frame's
    # z is up, so a camera placed too high or too far out shows as it is
    to_mat = world_to_mat(row["mat"]["yaw_deg"])
    up_err, out_err = [], []
    for i, k in enumerate(on):
        c_true = to_mat @ true[k][:3, 3]
        e = placed[i][:3, 3] - c_true
        out = np.r_[c_true[:2], 0.0] / np.linalg.norm(c_true[:2])
        up_err.append(float(e[2]))
        out_err.append(float(e @ out))
    k_err = None
    if (row.get("amplitude_slope") or {}).get("k_mm_per_ln") is not None and row.get("true_k_mm_per_ln") is not None:
        k_err = round(row["amplitude_slope"]["k_mm_per_ln"] - row["true_k_mm_per_ln"], 4)
    delta, sigma, _ = widened_fit(np.asarray(ps), np.asarray(ps_sig), 1.0 / np.asarray(dist))  # as range_offset
    return {"seed": row["seed"], "object": row["object"]["name"], "distance_m": p["distance_m"],
            "dots_distance_m": round(float(np.median(dist)), 3), "views": len(on), "views_with_dots": len(ps),
            "true_mm": round(1e3 * float(np.mean(rad_err)) / float(np.mean(rad_share)), 3),
            "reading_mm": round(1e3 * delta, 3), "reading_sigma_mm": round(1e3 * sigma, 3),
            "height_mm": round(1e3 * float(np.mean(up_err)), 3), "outward_mm": round(1e3 * float(np.mean(out_err)), 3),
            "elevation_deg": p["elevation_deg"], "k_error_mm_per_ln": k_err,
            "unrefined": row.get("adjustment") is None, "mean_signed_mm": row.get("mean_signed_mm"),
            "scale_error_pct": row.get("scale_error_pct")}


def summarize(runs: list[dict]) -> dict:
    """The along-sight figures of the module docstring over ``runs`` (:func:`run_sight`'s)."""
    tr = np.array([r["true_mm"] for r in runs])
    rd = np.array([r["reading_mm"] for r in runs])
    sd = np.array([r["reading_sigma_mm"] for r in runs])
    D = np.array([r["dots_distance_m"] for r in runs])
    sc = np.array([np.nan if r["scale_error_pct"] is None else r["scale_error_pct"] for r in runs], float)
    ok = np.isfinite(sc)
    slope, at0 = np.polyfit(D, rd - tr, 1)
    return {"runs": len(runs), "true_mean_mm": round(float(tr.mean()), 3), "true_sd_mm": round(float(tr.std()), 3),
            "true_p90_mm": round(float(np.percentile(tr, 90)), 3),
            "reading_mean_mm": round(float(rd.mean()), 3), "reading_sd_mm": round(float(rd.std()), 3),
            "reading_minus_true_mean_mm": round(float((rd - tr).mean()), 3),
            "reading_minus_true_sd_mm": round(float((rd - tr).std()), 3),
            "reading_minus_true_per_m": round(float(slope), 3), "reading_minus_true_at_0_mm": round(float(at0), 3),
            "reading_sigma_median_mm": round(float(np.median(sd)), 3),
            "corr_reading_true": round(float(np.corrcoef(rd, tr)[0, 1]), 3),
            "runs_with_scale": int(ok.sum()),
            "corr_scale_true": round(float(np.corrcoef(sc[ok], tr[ok])[0, 1]), 3),
            "corr_scale_reading": round(float(np.corrcoef(sc[ok], rd[ok])[0, 1]), 3)} | _in_mat_frame(runs)


def _in_mat_frame(runs: list[dict]) -> dict:
    """The placements' height and outward errors in the mat's frame (:func:`run_sight`'s ``height_mm``,
    ``outward_mm``; absent from rows made before session 57): their means, by how the poses stood, and how the
    outward error follows the amplitude coefficient's error and the model's mean signed deviation."""
    runs = [r for r in runs if "height_mm" in r]
    if len(runs) < 3:
        return {}
    h = np.array([r["height_mm"] for r in runs])
    o = np.array([r["outward_mm"] for r in runs])
    un = np.array([r["unrefined"] for r in runs])
    k = np.array([np.nan if r["k_error_mm_per_ln"] is None else r["k_error_mm_per_ln"] for r in runs], float)
    ms = np.array([np.nan if r["mean_signed_mm"] is None else r["mean_signed_mm"] for r in runs], float)
    out = {"height_mean_mm": round(float(h.mean()), 3), "height_sd_mm": round(float(h.std()), 3),
           "outward_mean_mm": round(float(o.mean()), 3), "outward_sd_mm": round(float(o.std()), 3),
           "corr_outward_height": round(float(np.corrcoef(o, h)[0, 1]), 3)}
    for name, m in (("held", ~un), ("unrefined", un)):
        if m.sum() >= 2:
            out[f"{name}_runs"] = int(m.sum())
            out[f"{name}_outward_mean_mm"] = round(float(o[m].mean()), 3)
            out[f"{name}_mean_signed_mm"] = round(float(np.nanmean(ms[m])), 3)
            ok = m & np.isfinite(ms)
            if ok.sum() >= 3:
                out[f"{name}_corr_mean_signed_outward"] = round(float(np.corrcoef(ms[ok], o[ok])[0, 1]), 3)
    ok = np.isfinite(k)
    if ok.sum() >= 3:
        out["corr_outward_k_error"] = round(float(np.corrcoef(o[ok], k[ok])[0, 1]), 3)
        out["corr_height_k_error"] = round(float(np.corrcoef(h[ok], k[ok])[0, 1]), 3)
    return out


def main(argv=None) -> int:
    runs = over_stored_rows(argv, "python -m bench.robustness.mat_sight", __doc__.splitlines()[0], run_sight,
                            lambda r: f"{r['seed']:>10} {r['object']:<11} true {r['true_mm']:+.2f} mm, dots read "
                                      f"{r['reading_mm']:+.2f} +/- {r['reading_sigma_mm']:.2f} mm, in the mat's frame "
                                      f"{r['height_mm']:+.2f} mm up, {r['outward_mm']:+.2f} mm out, scale {r['scale_error_pct']}")
    print(json.dumps(summarize(runs), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
