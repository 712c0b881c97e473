"""Turn stage outcomes into the report: sections, the side-by-side table, report.json."""

from __future__ import annotations

import datetime as _dt

import numpy as np

from tofmetry.report import ComparisonRow, Report, Section
from tofmetry.study.stage import StudyContext


def _get(ctx: StudyContext, key: str) -> dict | None:
    o = ctx.outcomes.get(key)
    return o.data if (o is not None and o.status == "ok") else None


def _lower_is_better(ours: float, study: float, tol: float = 0.15) -> str:
    if ours < study * (1 - tol):
        return "better"
    if ours > study * (1 + tol):
        return "worse"
    return "comparable"


def comparison_rows(ctx: StudyContext) -> list[ComparisonRow]:
    """The final table: each figure of the reference study next to this run's, with a verdict.

    For sensor characteristics (a property of the sensor, not of the method) the verdict says
    whether this sensor behaves like the study's ("consistent" / "differs"); for method results
    (calibration residuals, model accuracy) it says whether tofmetry does better.
    """
    rows: list[ComparisonRow] = []
    w = _get(ctx, "warmup")
    if w:
        st = w.get("stabilisation_time_min")
        rs = [None if x is None else x / 60.0 for x in w.get("stabilisation_range_s", [None, None])]
        sens = " – ".join("n/a" if x is None else f"{x:.0f}" for x in rs)
        rows.append(ComparisonRow("warm-up time to stability", "not reached" if st is None else f"{st:.0f} min",
                                  "≈ 30 min", "§3.2", "consistent" if st is not None and 15 <= st <= 45 else "differs",
                                  f"drift stays within the tolerance after this; {sens} min at ±10 % tolerance"))
        rows.append(ComparisonRow("warm-up drift / residual", f"{abs(w['total_drift_mm']):.1f} mm / {w['residual_drift_mm']:.1f} mm",
                                  "≈ 5 mm / ≈ 1 mm", "§3.2",
                                  "consistent" if 2.5 <= abs(w["total_drift_mm"]) <= 8 else "differs"))
    n = _get(ctx, "noise")
    if n:
        s = {x["n"]: x for x in n["summaries"]}
        if 10 in s and max(s) >= 50:
            hi = s[max(s)]
            rows.append(ComparisonRow(
                f"std map, 10 vs {hi['n']} frames (median / spread)",
                f"{s[10]['median_mm']:.2f} / {s[10]['spread_mm']:.2f} mm vs {hi['median_mm']:.2f} / {hi['spread_mm']:.2f} mm",
                "no gain in mean std, more uniform", "§3.2, Fig. 3",
                "consistent" if abs(hi["median_mm"] - s[10]["median_mm"]) < 0.25 * s[10]["median_mm"] and hi["spread_mm"] < s[10]["spread_mm"] else "differs",
                f"recommended n = {n['recommended_n']}"))
    m = _get(ctx, "materials")
    if m and "materials" in m:
        b6 = m["materials"]["fit"]["bias_at_amplitude_ratio_6_mm"]
        rows.append(ComparisonRow("dark vs white bias (amplitude 1/6)", f"{b6:+.1f} mm", "+12 mm (black vs white)",
                                  "§3.3.1, Fig. 4", "consistent" if 6 <= b6 <= 18 else "differs"))
    o = _get(ctx, "outdoor")
    if o:
        rows.append(ComparisonRow("valid pixels in strong light", f"{100 * o['valid_fraction']:.0f} %", "≈ 20 %", "§3.3.2",
                                  "consistent" if 10 <= 100 * o["valid_fraction"] <= 30 else "differs"))
        rows.append(ComparisonRow("flying pixels in strong light", f"{100 * o['flying_share_of_cloud']:.1f} %", "≈ 2 %",
                                  "§3.3.2", "consistent" if 1 <= 100 * o["flying_share_of_cloud"] <= 4 else "differs"))
    i = _get(ctx, "intrinsics")
    if i and i.get("loo_max_spread_px") is not None:
        rows.append(ComparisonRow("intrinsics stability (leave-one-out spread of fx, fy, cx, cy)",
                                  f"≤ {i['loo_max_spread_px']:.2f} px", "\"vary by a few pixels\"", "§4.1",
                                  "better" if i["loo_max_spread_px"] < 1.0 else "comparable",
                                  f"reprojection RMS {i['rms_px']:.3f} px over {i['n_images_used']} images"))
    d = _get(ctx, "depth")
    if d:
        if d.get("central_dev_before_mm"):
            lo, hi = d["central_dev_before_mm"]
            rows.append(ComparisonRow("range error, central patch, 0.8–4.5 m (before)", f"{lo:+.1f} to {hi:+.1f} mm",
                                      "−15 to +7 mm", "§4.2.2, Fig. 7a", "consistent" if hi - lo < 40 else "differs",
                                      "offset between reference point and optical centre removed"))
        if d.get("heldout_central_after_max_mm") is not None:
            rows.append(ComparisonRow("central deviation after correction", f"|dev| ≤ {d['heldout_central_after_max_mm']:.1f} mm on held-out stations",
                                      "≈ 0 on the training stations only", "§4.3, Fig. 9a", "better",
                                      "validated on stations never used for fitting"))
        chk = d.get("prediction_check") or {}
        if chk.get("central_abs_mm") and chk.get("rms_mm"):
            c, r = chk["central_abs_mm"], chk["rms_mm"]
            rows.append(ComparisonRow("the calibration's own predicted error (held-out stations)",
                                      f"central {c['predicted']:.2f} mm predicted, {c['measured']:.2f} measured; "
                                      f"per-pixel RMS {r['predicted']:.2f} predicted, {r['measured']:.2f} measured",
                                      "not reported", "§4.3", "better" if chk.get("verdict") in ("holds", "pessimistic")
                                      else "differs", f"verdict: {chk.get('verdict')} (RMS over stations, tilt removed)"))
        h = d.get("heldout") or {}
        if isinstance(h.get("min_rms_reduction"), (int, float)) and np.isfinite(h["min_rms_reduction"]):
            rows.append(ComparisonRow("per-pixel RMS error reduction (central 90 %)",
                                      f"≥ {h['min_rms_reduction']:.1f}× (offset removed before), "
                                      f"≥ {h.get('min_rms_reduction_raw', float('nan')):.1f}× (raw), "
                                      f"≥ {h.get('min_rms_reduction_systematic', float('nan')):.1f}× (systematic part) "
                                      "on held-out stations",
                                      "not reported", "§4.3, Fig. 9b", "better",
                                      "against the true wall; stations never used for fitting"))
        if d.get("plane_std_before_mm") and d.get("plane_std_after_mm"):
            b, a = d["plane_std_before_mm"], d["plane_std_after_mm"]
            rows.append(ComparisonRow("plane-fit residual std before → after", f"{b[0]:.1f}–{b[1]:.1f} → {a[0]:.1f}–{a[1]:.1f} mm",
                                      "2–5 → 1–3 mm", "§4.3", _lower_is_better(a[1], 3.0)))
    md = _get(ctx, "model")
    if md and md.get("calibrated") and "mean_abs_mm" in md["calibrated"]:  # no reference: no accuracy rows
        c = md["calibrated"]
        rows.append(ComparisonRow("registration", md.get("registration_summary", "automatic"),
                                  "hand-picked points, 2–4 mm pairwise (2 cm with targets)", "§5.2.1", "better",
                                  "no manual input"))
        rows.append(ComparisonRow("model vs reference: mean deviation", f"{c['mean_abs_mm']:.2f} mm", "≈ 2 mm", "§5.3",
                                  _lower_is_better(c["mean_abs_mm"], 2.0), "mean |d|; Kinect Fusion 1.1 mm (§5.4)"))
        rows.append(ComparisonRow("model vs reference: std", f"{c['std_mm']:.2f} mm", "≈ 2.5 mm", "§5.3",
                                  _lower_is_better(c["std_mm"], 2.5), "Kinect Fusion 1.4 mm (§5.4)"))
        rows.append(ComparisonRow("model vs reference: max", f"{c['max_mm']:.1f} mm", "≈ 15 mm", "§5.3",
                                  _lower_is_better(c["max_mm"], 15.0), "after the documented edge trimming"))
        u = md.get("uncalibrated") or {}
        if "mean_abs_mm" in u:
            flag = "" if u.get("reliable", True) else "; registration flagged unreliable"
            rows.append(ComparisonRow("same model without depth calibration (mean |d| / std / max)",
                                      f"{u['mean_abs_mm']:.2f} / {u['std_mm']:.2f} / {u['max_mm']:.1f} mm",
                                      "(the study modelled calibrated data only)", "§4.3, §5", "n/a",
                                      "what the calibration buys" + flag))
        rows.append(ComparisonRow("share of deviations < 5 mm", f"{100 * c['share_within_5mm']:.1f} %", "90 %", "§5.3",
                                  "better" if c["share_within_5mm"] > 0.92 else ("comparable" if c["share_within_5mm"] > 0.88 else "worse")))
    return rows


def build_report(ctx: StudyContext) -> Report:
    sections = [Section(o.key, o.title, o.status, o.paragraphs, o.tables, o.figures, o.note) for o in ctx.outcomes.values()]
    md = ctx.outcomes.get("model")
    pts = vals = None
    rng = 5.0
    if md is not None and md.status == "ok" and "viewer" in md.data:
        v = md.data.pop("viewer")
        pts, vals, rng = v["points"], v["values"], v.get("range_mm", 5.0)
    meta = {
        "date (UTC)": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M"),
        "data": "virtual Kinect v2 (simulated)" if ctx.simulated else str(ctx.data_dir),
        "machine": getattr(ctx, "machine", ""),
        "total time": f"{getattr(ctx, 'total_seconds', float('nan')):.0f} s",
        "stages": ", ".join(f"{o.key}: {o.status}" for o in ctx.outcomes.values()),
    }
    accepted = implausible_accepted(ctx)
    if ctx.accept_implausible:
        meta["--accept-implausible"] = (f"given; {len(accepted)} implausible finding(s) accepted" if accepted
                                        else "given; every result passed the plausibility gates")
    return Report(
        title="tofmetry study: assessment and calibration of a ToF RGB-D camera",
        subtitle=("Protocol of Lachat et al. 2015 (Kinect v2), automated: assessment → calibration → validation → "
                  "object model → accuracy."),
        sections=sections, comparison=comparison_rows(ctx), viewer_points=pts, viewer_values=vals,
        viewer_range_mm=rng, meta=meta,
    )


def implausible_accepted(ctx: StudyContext) -> list[str]:
    """The implausible findings ``--accept-implausible`` let through, as ``"stage: finding"``."""
    out = []
    for o in ctx.outcomes.values():
        rec = o.data.get("plausibility") if isinstance(o.data, dict) else None
        if rec and rec.get("accepted"):
            out += [f"{o.key}: {f}" for f in rec.get("findings", [])]
    return out


def report_json(ctx: StudyContext, report: Report) -> dict:
    return {
        "meta": report.meta,
        "accept_implausible": {"given": ctx.accept_implausible, "accepted_findings": implausible_accepted(ctx)},
        "total_seconds": getattr(ctx, "total_seconds", None),
        "simulation_seconds": getattr(ctx, "simulation_seconds", None),
        "stages": {k: o.to_dict() for k, o in ctx.outcomes.items()},
        "comparison": [r.__dict__ for r in report.comparison],
    }


def _np_safe(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    return x
