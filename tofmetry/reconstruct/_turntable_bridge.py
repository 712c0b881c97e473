"""Links that a declared turntable gives where the pairwise registrations failed, and the
messages of a turntable that no registration confirms (:mod:`._turntable` holds the geometry)."""

from __future__ import annotations

import numpy as np

from tofmetry.errors import EstimationError
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._view_graph import connected_components
from tofmetry.reconstruct._register import PairResult, register_pair
from tofmetry.reconstruct._regview import RegView, object_fitness, registration_conditioning, visibility_violation
from tofmetry.reconstruct._turntable import TurntablePrior, fit_turntable, turn_about

#: the run's reason when only rejected registrations turn by the declared step
UNCONFIRMED_REASON = ("no registration of successive views passed the gates: the declared turntable's axis is fitted "
                      "to registrations that failed them, and its step alone links the views: check the declared "
                      "step (--turntable-step), or take views closer together")


def no_turn_error(step_deg: float, tol_deg: float, n_views: int) -> EstimationError:
    """The refusal when no registration of successive views turns by the declared step."""
    even = 360.0 / n_views
    hint = (f"the step is that of {n_views} views evenly round the table: the views overlap too little for any "
            "registration (take more views)" if abs(step_deg - even) < 1e-6 else
            f"check the step (--turntable-step; {n_views} views evenly round the table turn by {even:g} deg) and "
            "that the views are named in capture order")
    return EstimationError(f"no registration of successive views turns by the declared turntable step ({step_deg:g} "
                           f"deg, within {tol_deg:g} deg, either sense): {hint}. No model is written")


def turntable_bridges(regs: list[RegView], pairs: list[PairResult], links: list[tuple[int, int]],
                      cfg: RegistrationConfig) -> tuple[list[PairResult], dict | None]:
    """Links that a declared turntable gives where the registrations failed (:mod:`._turntable`).

    The turntable's axis and sense are fitted to the accepted registrations (``pairs``). Each pair
    of ``links`` (successive views, then the closing pair) whose views no accepted registration
    connects yet is registered again from the declared turn about that axis (ICP, no global
    search); where that fails the gates, the declared turn itself links the views (method
    ``turntable-step``: their relative pose is then as accurate as the turntable's steps,
    ``cfg.turntable_accuracy_deg``, and the global adjustment refines it where the points allow).

    When no registration was accepted, the axis is fitted to the rejected ones that turn by the
    declared step (within ``cfg.turntable_tol_deg``; they failed the overlap gates): the report's
    ``axis_from`` says so and the run is flagged.

    Returns
    -------
    (the new pairs, the axis fit as a JSON-able dict or None when no registration turns by the step)
    """
    step = cfg.turntable_step_deg
    acc = [p for p in pairs if p.accepted]
    normals = [r.plane[:3] for r in regs if r.plane is not None]
    if step is None or not normals:
        return [], None
    axis = np.sum([n if n @ normals[0] >= 0 else -n for n in normals], axis=0)
    basis = acc or [p for p in pairs if p.method != "none" and TurntablePrior(
        p.source, p.target, step, cfg.turntable_tol_deg, axis).allows(p.transform)]
    fit = fit_turntable([p.transform for p in basis], [p.target - p.source for p in basis], step, axis) if basis else None
    if fit is None:
        return [], None
    r_final = cfg.icp_radii_mm[-1] * 1e-3
    tol = cfg.see_through_tol_mm * 1e-3
    sig_r = np.radians(cfg.turntable_accuracy_deg)
    info = np.diag([sig_r ** -2] * 3 + [(sig_r * 0.2 + 5e-4) ** -2] * 3)  # the steps' accuracy, at 0.2 m
    edges = [(p.source, p.target) for p in acc]
    out = []
    for i, j in links:
        if j in next(c for c in connected_components(len(regs), edges) if i in c):
            continue
        T0 = turn_about(fit["centre"], fit["axis"], fit["sense"] * (j - i) * step)
        p = register_pair(regs[i], regs[j], i, j, cfg, init=T0, global_search=False)
        if not p.accepted:
            f, rmse = object_fitness(regs[i], regs[j], T0, r_final)
            p = PairResult(i, j, T0, f, rmse * 1e3, info, "turntable-step", True,
                           conditioning=registration_conditioning(regs[i], regs[j], T0, r_final),
                           see_through=visibility_violation(regs[i], regs[j], T0, tol))
        out.append(p)
        edges.append((i, j))
    report = {"axis": [round(float(x), 5) for x in fit["axis"]], "centre_m": [round(float(x), 4) for x in fit["centre"]],
              "axis_from": "accepted registrations" if acc else "rejected registrations that turn by the declared step",
              "sense": int(fit["sense"]), "residual_deg": round(fit["residual_deg"], 3), "n_registrations": fit["n"],
              "bridged": [[p.source, p.target, p.method] for p in out]}
    return out, report
