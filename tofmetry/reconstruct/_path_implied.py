"""Registration hypotheses the scan's path implies: where the cameras of the chosen registrations
step back or leap (:mod:`tofmetry.reconstruct._camera_path`), the pair of views at that step is
registered again from the pose the path's own steps give it.

A nearly symmetric object matches itself turned by a half or a quarter turn, and the pairwise
global search may return only that turned pose for a pair; no choice among the pairs' hypotheses
then walks the cameras (measured: a box of 7 hand-held views had edges 00->01 and 03->04 both
turned over, 116 and 121 deg back against steps of 38-64 deg; a pebble's last pair leapt 58 deg
back where the search found nothing else). Here the pair is searched again as a turntable's pair whose
step is the path's median step, give or take half of it (the registration's yaw search about the
support plane's normal, seeded by that turn; hypotheses farther from it refused): half or a
quarter turn, where the symmetric object's turned match lies, is out of reach. The result becomes one more hypothesis of the
edge where the pair's points fit it about as well as the hypothesis kept (fitness within
``margin``: on a symmetric object the turned and the right pose match alike); the selection,
which prefers closing choices that walk, is then run again.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from tofmetry.reconstruct._camera_path import path_anomalies, path_frame, path_steps
from tofmetry.reconstruct._loops import connected_components, spanning_tree
from tofmetry.reconstruct._register import PairResult, _same_pose

#: method tag of a hypothesis found here
METHOD = "path-implied+icp"
#: the turn searched for, in median steps either side of the path's step (a hand-held path's steps vary)
TOLERANCE = 0.5


def path_implied_hypotheses(n: int, pairs: list[PairResult], selected: list[PairResult], centres: np.ndarray,
                            ups: np.ndarray | None, register: Callable[[int, int, float, float], PairResult],
                            max_ratio: float, margin: float) -> tuple[list[PairResult], list[dict]]:
    """The pairs the selection chose from, with the hypotheses the path implies at its anomalies.

    Parameters
    ----------
    n : number of views
    pairs : the pairwise results the selection chose from (same order as ``selected``)
    selected : the selection's output (kept edges ``accepted``, carrying the hypothesis chosen)
    centres : (n, 3) object centre of each view, in its camera frame [m]
    ups : (n, 3) the support plane's normal in each camera frame (NaN rows: none), or None
    register : ``register(i, j, step_deg, tol_deg) -> PairResult``: the pair (i, j) searched for
        as a turntable's pair of that step and tolerance (:class:`~tofmetry.reconstruct._turntable.TurntablePrior`:
        the yaw search about the support plane's normal seeded by the turn, hypotheses off it refused)
    max_ratio : :func:`path_anomalies`' leap bound
    margin : a hypothesis is added where its fitness is at least the kept one's minus this

    Returns
    -------
    pairs : ``pairs`` with the new hypotheses appended to their edges' ``alternatives`` (a new list)
    found : one dict per hypothesis added: edge (i, j), its fitness, the kept one's, the step it
        was implied at (degrees)
    """
    kept = [p for p in selected if p.accepted]
    main = sorted(max(connected_components(n, [(p.source, p.target) for p in kept]), key=len))
    poses = spanning_tree(n, kept, main[0])[0]
    frame = path_frame(poses[main], main, centres, None if ups is None else ups[main[0]])
    if frame is None:
        return list(pairs), []
    c, up = frame
    steps = path_steps(poses[main], c, up)
    bad = path_anomalies(steps, max_ratio, gaps=np.diff(main))
    if not bad:
        return list(pairs), []
    per = steps / np.diff(main)
    step = float(np.median(per[np.isfinite(per)]))  # per scan step
    out = list(pairs)
    found: list[dict] = []
    for k in bad:
        a, b = main[k], main[k + 1]
        ke = next((q for q, p in enumerate(out) if {p.source, p.target} == {a, b}), None)
        if ke is None:
            continue
        e = out[ke]
        q = register(e.source, e.target, abs(step), TOLERANCE * abs(step))  # the prior takes the gap j - i
        tried = [h for h in [q, *q.alternatives] if h.accepted] if q.accepted else []
        if not tried:
            continue
        q = max(tried, key=lambda h: (h.fitness, -h.inlier_rmse_mm))
        if e.accepted and q.fitness < e.fitness - margin:
            continue
        if any(_same_pose(q.transform, h.transform) for h in [e, *e.alternatives]):
            continue
        q = replace(q, method=METHOD, alternatives=[])
        out[ke] = replace(e, alternatives=[*e.alternatives, q]) if e.accepted else \
            replace(q, alternatives=[*e.alternatives])
        found.append({"edge": (e.source, e.target), "fitness": round(float(q.fitness), 4),
                      "kept_fitness": round(float(e.fitness), 4) if e.accepted else None,
                      "step_deg": round(float(steps[k]), 1)})
    return out, found
