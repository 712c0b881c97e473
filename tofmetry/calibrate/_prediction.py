"""How well a depth calibration predicts data it never saw: per-sample metrics and the
calibration's own predicted error (with a 90 % interval) from blocked validation.

Metrics of one sample after correction (all [mm]; ``e = corrected - reference``; for a sample
whose tilt is free, a wall, the tilt is re-fitted on ``e`` first, anchored on the optical
axis, because a wall's orientation is not known and a tilt-like sensor deformation cannot be
told from it):

* ``central_mm``: mean of ``e`` over the 10 x 10 px patch at the principal point (study
  Fig. 9a's central deviation).
* ``rms_mm``: RMS of ``e`` over the central 90 % of the image (all valid reference pixels of a
  partial sample such as a board); ``noise_mm``: RMS of the standard error of the sample's
  temporal mean over the same pixels, which no calibration removes; ``rms_systematic_mm =
  sqrt(rms^2 - noise^2)``.
* ``p95_mm``: 95th percentile of ``|e|`` over 4 x 4 px means (noise cut by 4).
* ``*_before`` figures: the same for the uncorrected depth, ``rms_before_raw_mm`` with the
  offset in, ``rms_before_mm`` with the central deviation removed (the shape of the error).

The prediction of each metric is its quadratic mean over the interpolation folds (each interior
station predicted by a calibration fitted on all the others): the typical size of the error at
a new station, which weights the larger errors as a user meets them. The 5th-95th percentile
range of the folds is its 90 % interval, and the median is reported too. The extrapolation
folds (nearest, farthest station left out) are reported apart. :func:`check_prediction`
compares a prediction with errors measured on new data the same way (quadratic mean).
"""

from __future__ import annotations

import numpy as np

from tofmetry.calibrate._wall import central_patch


def sample_metrics(corrected: np.ndarray, reference: np.ndarray, rays: np.ndarray, cxy: tuple,
                   sem: np.ndarray | None = None, free_tilt: bool = True, fraction: float = 0.9) -> dict:
    """Error metrics of one corrected sample (see the module docstring).

    Parameters
    ----------
    corrected, reference : (H, W) float [mm], NaN / 0 where invalid or unknown
    rays : (H, W, 2) undistorted normalised rays
    cxy : principal point [px]
    sem : (H, W) standard error of the temporal mean [mm] or None
    free_tilt : re-fit the sample's tilt (walls) before measuring
    """
    c = np.asarray(corrected, np.float64)
    r = np.asarray(reference, np.float64)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(c) & (c > 0) & np.isfinite(r) & (r > 0)
    e = np.where(ok, c - r, np.nan)
    h, w = e.shape
    region = np.zeros((h, w), bool)
    dv, du = int(round(h * (1 - fraction) / 2)), int(round(w * (1 - fraction) / 2))
    region[dv:h - dv, du:w - du] = True
    mask = ok & region
    if mask.sum() < 0.2 * ok.sum():  # a partial sample (board) mostly outside the centre: use all of it
        mask = ok
    if free_tilt and mask.sum() > 10:
        T = np.stack([r * rays[..., 0], r * rays[..., 1]], -1)[mask]
        tau, *_ = np.linalg.lstsq(T, e[mask], rcond=None)
        e = e - np.where(ok, r * (rays[..., 0] * tau[0] + rays[..., 1] * tau[1]), np.nan)
    sl = central_patch((h, w), cxy[0], cxy[1])
    cen = e[sl]
    central = float(np.nanmean(cen)) if np.isfinite(cen).any() else float("nan")
    em = e[mask]
    rms = float(np.sqrt(np.mean(em ** 2))) if em.size else float("nan")
    noise = float(np.sqrt(np.nanmean(np.square(sem[mask])))) if sem is not None and em.size else 0.0
    return {"central_mm": central, "rms_mm": rms, "noise_mm": noise,
            "rms_systematic_mm": float(np.sqrt(max(rms ** 2 - noise ** 2, 0.0))) if np.isfinite(rms) else rms,
            "p95_mm": _p95_blocks(np.where(mask, e, np.nan)), "n_pixels": int(mask.sum()),
            "tilt_removed": bool(free_tilt)}


def _p95_blocks(e: np.ndarray, block: int = 4) -> float:
    h, w = e.shape
    hb, wb = h // block, w // block
    a = e[:hb * block, :wb * block].reshape(hb, block, wb, block)
    fin = np.isfinite(a)
    n = fin.sum(axis=(1, 3))
    s = np.where(fin, a, 0.0).sum(axis=(1, 3))
    m = s[n >= block * block // 2] / n[n >= block * block // 2]
    return float(np.percentile(np.abs(m), 95)) if m.size else float("nan")


def before_after(measured: np.ndarray, corrected: np.ndarray, reference: np.ndarray, rays: np.ndarray, cxy: tuple,
                 sem: np.ndarray | None, free_tilt: bool) -> dict:
    """Metrics after correction plus ``rms_before_raw_mm`` and ``rms_before_mm`` (offset removed)
    and ``central_before_mm`` of the uncorrected depth."""
    after = sample_metrics(corrected, reference, rays, cxy, sem, free_tilt)
    raw = sample_metrics(measured, reference, rays, cxy, sem, free_tilt)
    shifted = np.asarray(measured, np.float64) - (raw["central_mm"] if np.isfinite(raw["central_mm"]) else 0.0)
    off = sample_metrics(shifted, reference, rays, cxy, sem, free_tilt)
    return after | {"central_before_mm": raw["central_mm"], "rms_before_raw_mm": raw["rms_mm"],
                    "rms_before_mm": off["rms_mm"], "rms_before_systematic_mm": off["rms_systematic_mm"]}


METRICS = ("central_abs_mm", "rms_mm", "rms_systematic_mm", "p95_mm")


def summarize_folds(rows: list[dict]) -> dict:
    """Prediction (quadratic mean), median and 90 % interval (5th-95th percentile over the folds) of each metric."""
    out = {}
    for key in METRICS:
        src = "central_mm" if key == "central_abs_mm" else key
        v = np.array([abs(r[src]) if key == "central_abs_mm" else r[src] for r in rows], float)
        v = v[np.isfinite(v)]
        if v.size == 0:
            out[key] = {"predicted": float("nan"), "median": float("nan"), "p5": float("nan"), "p95": float("nan"),
                        "max": float("nan"), "n": 0}
            continue
        out[key] = {"predicted": _qmean(v), "median": float(np.median(v)), "p5": float(np.percentile(v, 5)),
                    "p95": float(np.percentile(v, 95)), "max": float(v.max()), "n": int(v.size)}
    return out


def _qmean(v) -> float:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")


#: a calibration whose predicted central deviation at new stations may exceed this (the upper end
#: of its 90 % interval) warns [mm]
WARN_CENTRAL_MM = 1.5


#: a gap in the samples' coverage of the range variable wider than this warns [mm]
WARN_GAP_MM = 100.0


def range_coverage(references: list[np.ndarray], rays: np.ndarray, variable: str) -> dict:
    """Which values of the range variable the samples see, and the widest gap between them.

    Parameters
    ----------
    references : list of (H, W) float [mm], the samples' reference depth Z (NaN / 0 unknown)
    rays : (H, W, 2) undistorted normalised rays (x, y), Z along the optical axis
    variable : "z" (the range error is a function of Z) or anything else (of the ray length
        ``rho = Z * sqrt(1 + x^2 + y^2)``)

    Returns
    -------
    dict: ``variable``, ``intervals`` [[lo, hi], ...] [mm] (1st-99th percentile of each sample,
    merged), ``gap_mm`` (widest uncovered stretch between them) and ``gap_at_mm`` ([lo, hi] of it).
    A range error is seen only where the samples cover its variable: a wiggle whose half-period
    fits in a gap is invisible there, whatever the fit.
    """
    scale = np.ones(rays.shape[:2]) if variable == "z" else np.sqrt(1.0 + rays[..., 0] ** 2 + rays[..., 1] ** 2)
    spans = []
    for r in references:
        r = np.asarray(r, float)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(r) & (r > 0)
        if ok.sum() < 10:
            continue
        q = r[ok] * scale[ok]
        spans.append([float(np.percentile(q, 1)), float(np.percentile(q, 99))])
    spans.sort()
    merged = []
    for lo, hi in spans:
        if merged and lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    gaps = [(merged[k + 1][0] - merged[k][1], [merged[k][1], merged[k + 1][0]]) for k in range(len(merged) - 1)]
    gap, at = max(gaps) if gaps else (0.0, [])
    return {"variable": "Z" if variable == "z" else "ray length", "intervals": merged, "gap_mm": float(gap),
            "gap_at_mm": at}


def prediction_record(interp_rows: list[dict], extrap_rows: list[dict], note: str,
                      warn_central_mm: float = WARN_CENTRAL_MM, coverage: dict | None = None,
                      warn_gap_mm: float = WARN_GAP_MM) -> dict:
    """The ``prediction`` stored in a calibration (JSON-able), with its ``warnings``.

    A predicted central deviation whose 90 % interval reaches above ``warn_central_mm`` means the
    stations do not sample the range error finely enough (e.g. a wiggle of Z shorter than twice
    the station spacing, which no station between two others can see): the record says so and
    what to do. ``coverage`` (:func:`range_coverage`) with a gap wider than ``warn_gap_mm`` warns
    too: leave-one-out cannot see a wiggle that every station samples at the same phase (an
    alias), so a range error of a variable the samples see only at isolated values is not vouched
    for between them.
    """
    interp = summarize_folds(interp_rows) if interp_rows else {}
    warnings = []
    if coverage and coverage.get("gap_mm", 0.0) > warn_gap_mm:
        lo, hi = coverage["gap_at_mm"]
        warnings.append(
            f"the range error was fitted as a function of {coverage['variable']}, and the samples leave "
            f"{coverage['gap_mm']:.0f} mm of it unseen ({lo:.0f}-{hi:.0f} mm): a wiggle shorter than "
            f"{2 * coverage['gap_mm']:.0f} mm would go unnoticed between the stations, so the predicted error is not "
            f"vouched for there; add stations in between or calibrate on a wall seen at an angle")
    c = interp.get("central_abs_mm", {})
    if c.get("n") and c["p95"] > warn_central_mm:
        centers = np.sort([r["center_mm"] for r in interp_rows])
        spacing = float(np.median(np.diff(centers))) if len(centers) > 1 else float("nan")
        warnings.append(
            f"the range error changes faster than the stations ({spacing:.0f} mm apart) sample it: a station left "
            f"out is predicted to {c['predicted']:.1f} mm on the axis (RMS; 90 %: {c['p5']:.1f}-{c['p95']:.1f} mm), "
            f"so expect up to that much between stations; add stations in between or calibrate on a wall seen at an "
            f"angle")
    return {
        "method": note,
        "interpolation": interp,
        "extrapolation": extrap_rows,
        "folds": interp_rows,
        "interval": "5th-95th percentile over the blocked folds (90 %)",
        "warnings": warnings,
        "coverage": coverage or {},
    }


def check_prediction(prediction: dict, rows: list[dict], tolerance: float = 1.5, fail: float = 2.0) -> dict:
    """Compare a calibration's predicted error with errors measured on new data.

    Parameters
    ----------
    prediction : a calibration's ``prediction`` (see :func:`prediction_record`)
    rows : metrics of held-out samples (:func:`before_after` / :func:`sample_metrics` dicts)
    tolerance, fail : ratios measured / predicted (quadratic mean over the rows against the
        prediction) within which the prediction *holds*, and above which it *fails* (too optimistic)

    Returns
    -------
    dict per metric: ``predicted``, ``interval`` [p5, p95], ``measured`` (quadratic mean of the rows),
    ``ratio``, ``in_interval`` (fraction of rows inside the predicted interval, or below its upper
    end when it is 0), ``verdict`` ("holds", "pessimistic", "optimistic", "fails"); and ``verdict``
    overall (the worst).
    """
    interp = (prediction or {}).get("interpolation") or {}
    out = {}
    order = ["holds", "pessimistic", "optimistic", "fails"]
    worst = "holds"
    for key in METRICS:
        p = interp.get(key)
        src = "central_mm" if key == "central_abs_mm" else key
        vals = np.array([abs(r[src]) if key == "central_abs_mm" else r[src] for r in rows if src in r], float)
        vals = vals[np.isfinite(vals)]
        if not p or not p.get("n") or vals.size == 0:
            continue
        pred, meas = p.get("predicted", p["median"]), _qmean(vals)
        # a prediction of 0 (a systematic RMS at the noise floor) is met only by a measurement of 0
        ratio = meas / pred if pred > 0 else (1.0 if meas <= 0 else float("inf"))
        inside = float(np.mean((vals >= p["p5"]) & (vals <= p["p95"]))) if p["p95"] > p["p5"] else float(np.mean(vals <= p["p95"]))
        if ratio > fail:
            verdict = "fails"
        elif ratio > tolerance:
            verdict = "optimistic"
        elif ratio < 1 / tolerance:
            verdict = "pessimistic"
        else:
            verdict = "holds"
        out[key] = {"predicted": pred, "interval": [p["p5"], p["p95"]], "measured": meas, "ratio": ratio,
                    "in_interval": inside, "n": int(vals.size), "verdict": verdict}
        if order.index(verdict) > order.index(worst):
            worst = verdict
    out["verdict"] = worst if len(out) else "no prediction"
    return out
