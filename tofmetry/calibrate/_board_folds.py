"""Board calibration validation: blocked fold designs (:func:`blocked_folds`, :func:`region_folds`),
the candidate ladder (:func:`candidate_ladder`), the pooled samples and their held-out fits
(``_Pool`` and helpers) and the predicted error on new views (:func:`predict_error`). Part of
:mod:`tofmetry.calibrate.board`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofmetry.calibrate._board_model import RANGE_VARIABLES, BoardDepthModel, ModelSpec, fit_board_model
from tofmetry.calibrate._board_support import error_stats
from tofmetry.calibrate._lens_cv import _folds
from tofmetry.errors import EstimationError, InputError


# ----------------------------------------------------------------------------- validation designs
def blocked_folds(view_order: np.ndarray, view_z_mm: np.ndarray, design: str, k: int | None = None,
                  seed: int = 0) -> list[np.ndarray]:
    """Held-out view indices of each fold of a validation design.

    Parameters
    ----------
    view_order : (V,) recording order of the views (e.g. their index).
    view_z_mm : (V,) median measured Z of each view [mm].
    design : ``"time"`` (contiguous blocks in recording order, default 5), ``"range"`` (bins of
        range: contiguous groups of views sorted by Z, default 4) or ``"random"`` (random k-fold
        over views, default 5; reported beside the blocked designs, never used to select).
        Image regions are not view folds: see :func:`region_folds`.
    k : number of folds (clamped to [2, V]).

    Returns
    -------
    list of (n_f,) int arrays of view indices.
    """
    V = len(view_order)
    if V < 2:
        raise EstimationError(f"validation needs at least 2 views, found {V}")
    if design == "time":
        k = min(k or 5, V)
        return [np.sort(b) for b in np.array_split(np.argsort(view_order, kind="stable"), k)]
    if design == "range":
        k = min(k or 4, V)
        return [np.sort(b) for b in np.array_split(np.argsort(view_z_mm, kind="stable"), k)]
    if design == "random":
        return _folds(V, k or 5, seed)
    raise InputError(f"validation design must be 'time', 'range' or 'random', found {design!r}")


def region_folds(shape: tuple[int, int], grid: tuple[int, int] = (3, 2)) -> list[tuple[int, int, int, int]]:
    """Image regions ``(u0, u1, v0, v1)`` [px, half-open] of a ``(nu, nv)`` split of the image."""
    H, W = shape
    ue = np.linspace(0, W, grid[0] + 1).round().astype(int)
    ve = np.linspace(0, H, grid[1] + 1).round().astype(int)
    return [(ue[i], ue[i + 1], ve[j], ve[j + 1]) for j in range(grid[1]) for i in range(grid[0])]


def candidate_ladder(n_views: int, z_span_mm: float, knot_spacing_mm: float = 200.0,
                     range_variable: str | None = None) -> list[ModelSpec]:
    """Candidate models, simplest first (``complexity``), gated by the support.

    * always: no correction (the identity: every model must beat it) and a constant.
    * 2-5 views: constant; constant + gain in radial range and in Z (if the views span >= 100 mm).
    * >= 6 views: also range splines (knots every ``knot_spacing_mm``, if the span holds 2 of
      them), then range + per-pixel surface: a coarse grid (9x8 nodes) with membrane weights 3
      and 1, a fine grid (17x15) with weights 3 and 1, and the coarse surface plus a gain
      surface (a per-pixel term growing with range).

    ``range_variable`` restricts the surface candidates to one range variable (the selection
    first chooses it among the range-only candidates); None gives both.
    """
    c = [ModelSpec("no correction", "z", 0.0, complexity=-1, identity=True), ModelSpec("constant", "z", 0.0, complexity=0)]
    if n_views >= 2 and z_span_mm >= 100:
        c += [ModelSpec("gain (radial)", "radial", np.inf, complexity=1),
              ModelSpec("gain (Z)", "z", np.inf, complexity=1)]
    if n_views >= 6 and z_span_mm >= 2 * knot_spacing_mm:
        c += [ModelSpec("spline (radial)", "radial", knot_spacing_mm, complexity=2),
              ModelSpec("spline (Z)", "z", knot_spacing_mm, complexity=2)]
    if n_views >= 6:
        sp = knot_spacing_mm if z_span_mm >= 2 * knot_spacing_mm else (np.inf if z_span_mm >= 100 else 0.0)
        for rv in ((range_variable,) if range_variable else RANGE_VARIABLES):
            lab = "radial" if rv == "radial" else "Z"
            c += [ModelSpec(f"coarse surface, smooth 3 ({lab})", rv, sp, surface_smooth=3.0, grid=(9, 8), complexity=3),
                  ModelSpec(f"coarse surface, smooth 1 ({lab})", rv, sp, surface_smooth=1.0, grid=(9, 8), complexity=4),
                  ModelSpec(f"fine surface, smooth 3 ({lab})", rv, sp, surface_smooth=3.0, grid=(17, 15), complexity=5),
                  ModelSpec(f"fine surface, smooth 1 ({lab})", rv, sp, surface_smooth=1.0, grid=(17, 15), complexity=6),
                  ModelSpec(f"coarse surface + gain surface ({lab})", rv, sp, surface_smooth=3.0, gain_smooth=3.0,
                            grid=(9, 8), complexity=7)]
    return c


# ----------------------------------------------------------------------------- pooled samples
@dataclass
class _Pool:
    """All samples of the views used, concatenated (internal)."""

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray          # measured Z [mm] (dark-only views: minus the dark bias)
    zref: np.ndarray
    view: np.ndarray       # view index (0..V-1)
    judge: np.ndarray      # white-square sample (held-out errors are judged on these)
    dark_view: np.ndarray  # sample of a dark-only view

    def take(self, m: np.ndarray) -> "_Pool":
        return _Pool(*(getattr(self, f)[m] for f in ("u", "v", "z", "zref", "view", "judge", "dark_view")))


def _subsample(view: np.ndarray, max_per_view: int, seed: int) -> np.ndarray:
    """Indices keeping at most ``max_per_view`` samples per view (fixed seed)."""
    rng = np.random.default_rng(seed)
    keep = []
    for k in np.unique(view):
        idx = np.flatnonzero(view == k)
        keep.append(idx if len(idx) <= max_per_view else np.sort(rng.choice(idx, max_per_view, replace=False)))
    return np.concatenate(keep) if keep else np.zeros(0, int)


def _fit(pool: _Pool, spec: ModelSpec, shape, intr, use_dark: bool) -> BoardDepthModel:
    m = pool.judge | (pool.dark_view if use_dark else False)
    if spec.complexity <= 0:
        m = pool.judge if pool.judge.any() else m
    return fit_board_model(pool.u[m], pool.v[m], pool.z[m], pool.zref[m], shape, spec, intrinsics=intr)


def _held_out_errors(pool: _Pool, spec: ModelSpec, shape, intr, use_dark: bool, folds: list) -> list[tuple]:
    """Per fold (aligned with ``folds``): ``(label, view ids (n,), errors (n,))`` on the judged
    (white) samples of the fold, or None where the fold cannot be fitted or judged."""
    out = []
    for label, test in folds:
        tr = pool.take(~test)
        te = pool.take(test & pool.judge)
        if te.z.size == 0 or not tr.judge.any():
            out.append(None)
            continue
        try:
            model = _fit(tr, spec, shape, intr, use_dark)
        except EstimationError:
            out.append(None)
            continue
        e = te.z + model.correction(te.u, te.v, te.z) - te.zref
        out.append((label, te.view, e))
    return out


def _design_masks(pool: _Pool, folds_by_design: dict) -> dict:
    out = {}
    for d, folds in folds_by_design.items():
        masks = []
        for j, f in enumerate(folds):
            if d == "region":
                u0, u1, v0, v1 = f
                masks.append((f"region {j}", (pool.u >= u0) & (pool.u < u1) & (pool.v >= v0) & (pool.v < v1)))
            else:
                masks.append((f"{d} {j}", np.isin(pool.view, f)))
        out[d] = masks
    return out


def _fold_mse(results: list) -> np.ndarray:
    """(F,) held-out MSE per fold [mm^2] (NaN where the fold was not fitted)."""
    return np.array([float(np.mean(r[2] ** 2)) if r is not None else np.nan for r in results])


def _finite_mean(x) -> float:
    """Mean of the finite values (inf when there is none: a candidate no fold could judge)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.mean(x)) if x.size else float("inf")


def _done(results: list) -> list:
    return [r for r in results if r is not None]


def predict_error(view_ids: np.ndarray, errors: np.ndarray, n_new_views: int | None = None,
                  view_order: np.ndarray | None = None, block: int | None = None, n_boot: int = 1000,
                  level: float = 0.9, seed: int = 0, max_per_view: int = 100) -> dict:
    """Predicted error on a set of new views from held-out errors, with bootstrap intervals.

    Parameters
    ----------
    view_ids : (N,) view of each held-out error; errors : (N,) held-out errors [mm].
    n_new_views : size of the set of new views the prediction is for (default: as many as were
        held out). Each bootstrap draw assembles that many views and pools their pixels, so the
        interval covers the sampling of views (their pose errors) as well as of pixels.
    view_order : (V,) recording order of the distinct views (sorted ``unique(view_ids)``);
        given, views are drawn in **moving blocks** of ``block`` consecutive views (default
        ``round(sqrt(V))``), so that errors shared by views recorded together (a drift, a group
        of similar poses) widen the interval as they should; None: views drawn independently.
    level : central interval probability.

    Returns
    -------
    dict: ``rms_mm``, ``p95_abs_mm``, ``mean_mm`` (point estimates on all held-out errors), each
    with ``*_interval`` ``[lo, hi]``; ``n_views``, ``n_new_views``, ``block``, ``level``.
    """
    ids = np.asarray(view_ids)
    e = np.asarray(errors, float)
    views = np.unique(ids)
    V = len(views)
    nan2 = [float("nan"), float("nan")]
    if V == 0:
        return {"rms_mm": float("nan"), "p95_abs_mm": float("nan"), "mean_mm": float("nan"), "rms_mm_interval": nan2,
                "p95_abs_mm_interval": nan2, "mean_mm_interval": nan2, "n_views": 0, "n_new_views": 0, "block": 0,
                "level": level}
    rng = np.random.default_rng(seed)
    per = []
    for k in views:
        x = e[ids == k]
        per.append(x if len(x) <= max_per_view else rng.choice(x, max_per_view, replace=False))
    if view_order is not None:
        seq = np.argsort(np.asarray(view_order), kind="stable")
        L = int(block or max(1, round(np.sqrt(V))))
    else:
        seq = np.arange(V)
        L = 1
    L = min(L, V)
    m = int(n_new_views or V)
    stats = np.empty((n_boot, 3))
    for b in range(n_boot):
        pick = []
        while len(pick) < m:
            s0 = int(rng.integers(0, V - L + 1))
            pick.extend(seq[s0:s0 + L].tolist())
        x = np.concatenate([per[i] for i in pick[:m]])
        stats[b] = [np.sqrt(np.mean(x ** 2)), np.percentile(np.abs(x), 95), np.mean(x)]
    a = (1 - level) / 2
    lo, hi = np.quantile(stats, [a, 1 - a], axis=0)
    st = error_stats(e)
    return {"rms_mm": st["rms_mm"], "p95_abs_mm": st["p95_abs_mm"], "mean_mm": st["mean_mm"],
            "rms_mm_interval": [float(lo[0]), float(hi[0])], "p95_abs_mm_interval": [float(lo[1]), float(hi[1])],
            "mean_mm_interval": [float(lo[2]), float(hi[2])], "n_views": V, "n_new_views": m, "block": L,
            "level": level}
