"""Fit, blocked cross-validation and model choice of the joint depth-error model (:mod:`._joint`).

* :func:`fit_joint` — one penalised weighted least-squares fit (with one robust reweighting).
* :func:`blocked_folds` — which samples each fold leaves out: every interior sample in turn
  (*interpolation*: a station between training stations) and the first and the last sample
  (*extrapolation*, reported apart, never used to choose the model).
* :func:`select_spec` — the model (range variable, ray projection, roughness, surface nodes)
  with the smallest interpolation error over the folds, searched one hyper-parameter at a time.
  The candidates are physical alternatives, not a family tuned to one sensor: the error may be a
  function of the ray length or of Z, applied along the ray or in Z, and every roughness is
  chosen from the data.

Leaving a sample out costs one solve: each sample's normal equations (its tilt eliminated) are
subtracted from the total.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from threadpoolctl import threadpool_limits

from tofmetry.calibrate._joint import (
    Cells, JointSpec, Layout, SampleSystem, make_layout, residual, sample_system, solve,
)

#: Range-variable candidates: (variable, gamma).
VARIABLES = (("radial", 1.0), ("radial", 0.0), ("z", 0.0))
LAM_W = (0.03, 0.3, 3.0, 30.0, 300.0)
LAM_S = (1e-3, 1e-2, 1e-1, 1.0)
LAM_K = (1e-3, 1e-2, 0.1, 1.0)
NODES = (1, 2, 3, 5)


@dataclass(eq=False)
class JointFit:
    """A fitted joint model.

    Attributes
    ----------
    layout : Layout; theta : (P,) parameters; weights : per-sample cell weights after robust
    reweighting; systems : per-sample normal equations; P : penalty used; cells : the data
    """

    layout: Layout
    theta: np.ndarray
    weights: list
    systems: list
    P: np.ndarray
    cells: list
    n_data: float
    N_data: np.ndarray | None = None
    r_data: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.N_data is None:
            self.N_data = sum(s.N for s in self.systems)
            self.r_data = sum(s.r for s in self.systems)

    def refit_without(self, drop: list[int]) -> np.ndarray:
        """Parameters fitted without the samples ``drop``."""
        N = self.P + self.N_data
        r = self.r_data.copy()
        for j in drop:
            N = N - self.systems[j].N
            r -= self.systems[j].r
        return solve(N, r)


def _systems(layout: Layout, cells: list[Cells], weights: list[np.ndarray]) -> list[SampleSystem]:
    return [sample_system(layout, c, w) for c, w in zip(cells, weights)]


def _penalty(layout: Layout, n_data: float, spec: JointSpec, cells: list[Cells]) -> np.ndarray:
    return layout.penalty(n_data, spec.lam_w, spec.lam_s, spec.lam_k, any(c.free_tilt for c in cells))


def fit_joint(cells: list[Cells], spec: JointSpec, shape: tuple, cxy: tuple, centers_mm: np.ndarray,
              weights: list[np.ndarray] | None = None, robust: bool = True, huber_k: float = 3.0) -> JointFit:
    """Fit the joint model to the cells of all samples.

    Parameters
    ----------
    cells : one :class:`Cells` per sample
    spec : hyper-parameters
    shape, cxy : image (H, W) and principal point [px]
    centers_mm : (S,) measured central depth of each sample [mm] (places the surface nodes)
    weights : per-sample cell weights (default: the cells' own); ``robust`` reweights once
        (Huber at ``huber_k`` robust sigmas of the standardised residuals)
    """
    layout = make_layout(cells, spec, shape, cxy, centers_mm)
    ws = [c.w.copy() for c in cells] if weights is None else [w.copy() for w in weights]
    norm = np.mean(np.concatenate(ws))
    ws = [w / norm for w in ws]
    n_data = float(sum(len(w) for w in ws))
    P = _penalty(layout, n_data, spec, cells)
    systems = _systems(layout, cells, ws)
    theta = solve(P + sum(s.N for s in systems), sum(s.r for s in systems))
    if robust:
        z = [residual(layout, s, c, theta, w) * np.sqrt(w) for s, c, w in zip(systems, cells, ws)]
        zz = np.concatenate(z)
        sig = 1.4826 * np.median(np.abs(zz - np.median(zz))) + 1e-12
        ws = [w * np.minimum(1.0, huber_k * sig / np.maximum(np.abs(zi), 1e-12)) for w, zi in zip(ws, z)]
        systems = _systems(layout, cells, ws)
        theta = solve(P + sum(s.N for s in systems), sum(s.r for s in systems))
    return JointFit(layout, theta, ws, systems, P, cells, n_data)


def blocked_folds(centers_mm: np.ndarray) -> tuple[list[list[int]], list[list[int]]]:
    """Leave-out folds over samples sorted by distance: ``(interpolation, extrapolation)``.

    Interpolation folds leave out one interior distance (all samples at it); extrapolation folds
    leave out the nearest and the farthest distance. With fewer than 3 distinct distances there
    is no interpolation fold.
    """
    c = np.round(np.asarray(centers_mm, float), -1)  # samples within 10 mm share a distance
    levels = np.unique(c)
    groups = [list(np.flatnonzero(c == lv)) for lv in levels]
    if len(groups) < 3:
        return [], [groups[0], groups[-1]] if len(groups) == 2 else []
    return groups[1:-1], [groups[0], groups[-1]]


@dataclass(eq=False)
class Scored:
    spec: JointSpec
    score: float
    per_fold: list = field(default_factory=list)


def cv_score(fit: JointFit, folds: list[list[int]]) -> tuple[float, list[float]]:
    """Geometric mean over ``folds`` of each fold's weighted mean squared held-out cell residual
    (tilt re-fitted) [mm^2], and the per-fold values.

    Folds differ in difficulty by design: leaving a station out doubles the gap the model must
    bridge there, and where the range error wiggles faster than that gap (often at near range)
    one fold's error can be 10x the others'. A pooled mean is then that one fold's choice; the
    geometric mean asks a candidate to do better across the stations, each by its own measure.
    """
    if not folds:
        return float("nan"), []
    per = []
    for f in folds:
        th = fit.refit_without(f)
        a, b = 0.0, 0.0
        for j in f:
            w = fit.weights[j]
            res = residual(fit.layout, fit.systems[j], fit.cells[j], th, w)
            a += float(np.sum(w * res ** 2))
            b += float(np.sum(w))
        per.append(a / b)
    v = np.maximum(np.asarray(per), 1e-12)
    return float(np.exp(np.mean(np.log(v)))), per


def _rescore(fit: JointFit, spec: JointSpec, folds) -> Scored:
    """Score another set of penalties on the same layout and weights (no rebuild)."""
    f2 = replace(fit, P=_penalty(fit.layout, fit.n_data, spec, fit.cells))
    f2.layout = replace(fit.layout, spec=spec)
    s, per = cv_score(f2, folds)
    return Scored(spec, s, per)


def select_spec(*args, **kwargs):
    """See :func:`_select_spec` (one BLAS thread: many small solves thrash with threads on a busy machine)."""
    with threadpool_limits(1, user_api="blas"):
        return _select_spec(*args, **kwargs)


def _select_spec(cells: list[Cells], shape: tuple, cxy: tuple, centers_mm: np.ndarray, base: JointSpec | None = None,
                 advance=None) -> tuple[JointSpec, list[Scored], list[np.ndarray]]:
    """Choose the hyper-parameters by blocked (interpolation) cross-validation.

    Robust weights come from a fit with ``base`` and are kept for every candidate. Then, one at
    a time: the range variable and ray projection (with a coarse roughness grid), the number of
    surface nodes, the roughness of the surfaces, their change between nodes and, last, the
    roughness of ``W`` on a finer grid.

    Returns
    -------
    (chosen spec, every scored candidate, the robust weights)
    """
    spec = base or JointSpec()
    interp, _ = blocked_folds(centers_mm)
    first = fit_joint(cells, spec, shape, cxy, centers_mm)
    weights = first.weights
    tried: list[Scored] = []
    if not interp:
        return spec, tried, weights
    adv = advance or (lambda n=1: None)
    fits = {(spec.variable, spec.gamma, spec.n_nodes): first}

    def build(sp):
        key = (sp.variable, sp.gamma, sp.n_nodes)
        if key not in fits:
            fits[key] = fit_joint(cells, sp, shape, cxy, centers_mm, weights=weights, robust=False)
        return fits[key]

    best = None
    for var, gam in VARIABLES:  # 1. range variable (each needs its own design)
        sp = replace(spec, variable=var, gamma=gam)
        sc = _best_of(build(sp), sp, "lam_w", LAM_W[1::2], interp, tried)
        adv()
        if best is None or sc.score < best.score:
            best = sc
    spec = best.spec
    n_levels = len(np.unique(np.round(centers_mm, -1)))
    for k in NODES:  # 2. surface nodes (each needs its own design)
        if k == spec.n_nodes or k > n_levels:
            continue
        sp = replace(spec, n_nodes=k)
        sc = _rescore(build(sp), sp, interp)
        tried.append(sc)
        adv()
        if sc.score < best.score:
            best, spec = sc, sc.spec
    fit = build(spec)
    for name, grid in (("lam_s", LAM_S), ("lam_k", LAM_K), ("lam_w", LAM_W)):  # 3. penalties
        grid = [g for g in grid if g != getattr(spec, name)]
        sc = _best_of(fit, spec, name, grid, interp, tried)
        if sc.score < best.score:
            best, spec = sc, sc.spec
    return spec, tried, weights


def _best_of(fit: JointFit, spec: JointSpec, name: str, grid, folds, tried: list) -> Scored:
    best = None
    for val in grid:
        sc = _rescore(fit, replace(spec, **{name: val}), folds)
        tried.append(sc)
        if best is None or sc.score < best.score:
            best = sc
    return best
