"""Registration hypotheses the scan's path implies: where the cameras of the chosen registrations
step back or leap (:mod:`tofmetry.reconstruct._camera_path`), the pairs at that step are searched
again for the turn the path's own steps give them.

A nearly symmetric object matches itself turned by a half or a quarter turn, and the pairwise
global search may return only that turned pose for a pair; no choice among the pairs' hypotheses
then walks the cameras (measured: a 6-view pebble's last pair leapt 58 deg back where the search
had found nothing else; a 7-view box stepped back 116 and 121 deg against 47-53 deg steps, where
the skip edges 00->02 and 03->05 bridging two failed successive pairs were turned over).

The pairs searched again at a step from view a to view b: (a, b) itself, kept or not, and every
kept skip edge (i, j) spanning it (i <= a < b <= j) over less than half the scan. Each is searched
as a turntable's pair whose step is the path's median step, give or take half of it (the
registration's yaw search about the support plane's normal, seeded by that turn, hypotheses
farther from it refused): a half or a quarter turn, where the symmetric object's turned match
lies, is out of reach. What it finds becomes one more hypothesis of the edge where the pair's
points fit it about as well as the hypothesis kept (fitness within ``margin``: on a symmetric
object the turned and the right pose match alike); the selection, which prefers closing choices
that walk, is then run again.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from tofmetry.reconstruct._camera_path import path_walk
from tofmetry.reconstruct._view_graph import connected_components, spanning_tree
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
    max_ratio : :func:`~tofmetry.reconstruct._camera_path.path_anomalies`' leap bound
    margin : a hypothesis is added where its fitness is at least the kept one's minus this

    Returns
    -------
    pairs : ``pairs`` with the new hypotheses appended to their edges' ``alternatives`` (a new list)
    found : one dict per hypothesis added: edge (i, j), its fitness, the kept one's (None where the
        pair was not kept), the step it was implied at (degrees)
    """
    kept = [p for p in selected if p.accepted]
    main = sorted(max(connected_components(n, [(p.source, p.target) for p in kept]), key=len))
    poses = spanning_tree(n, kept, main[0])[0]
    steps, bad = path_walk(poses[main], main, centres, None if ups is None else ups[main[0]], max_ratio)
    if not bad:
        return list(pairs), []
    per = steps / np.diff(main)
    step = float(np.median(per[np.isfinite(per)]))  # per scan step
    out = list(pairs)
    found: list[dict] = []
    done: set[int] = set()
    for k in bad:
        a, b = main[k], main[k + 1]
        for ke in _edges_at(out, kept, a, b, n):
            if ke in done:
                continue
            done.add(ke)
            e = out[ke]
            q = register(e.source, e.target, abs(step), TOLERANCE * abs(step))  # the prior takes the gap j - i
            new: list[PairResult] = []
            have = [e, *e.alternatives] if e.accepted else []  # a pair the gates refused is no hypothesis
            for h in ([q, *q.alternatives] if q.accepted else []):
                if not h.accepted or (e.accepted and h.fitness < e.fitness - margin):
                    continue
                if any(_same_pose(h.transform, x.transform) for x in [*have, *new]):
                    continue
                new.append(replace(h, method=METHOD, alternatives=[]))
            if not new:
                continue
            out[ke] = replace(e, alternatives=[*e.alternatives, *new]) if e.accepted else \
                replace(new[0], alternatives=[*e.alternatives, *new[1:]])
            found.extend({"edge": (e.source, e.target), "fitness": round(float(h.fitness), 4),
                          "kept_fitness": round(float(e.fitness), 4) if e.accepted else None,
                          "step_deg": round(float(steps[k]), 1)} for h in new)
    return out, found


def _edges_at(pairs: list[PairResult], kept: list[PairResult], a: int, b: int, n: int) -> list[int]:
    """Indices into ``pairs`` of the edges to search again at the step from view ``a`` to ``b``:
    the pair (a, b) itself (kept or not), and every kept edge between non-successive views that
    spans the step (i <= a < b <= j) over less than half the scan (a turned-over skip edge puts a
    run of views on the far side just as a successive one does)."""
    out = [q for q, p in enumerate(pairs) if {p.source, p.target} == {a, b}][:1]
    spans = {(min(p.source, p.target), max(p.source, p.target)) for p in kept}
    for q, p in enumerate(pairs):
        i, j = min(p.source, p.target), max(p.source, p.target)
        if (i, j) in spans and j - i >= 2 and 2 * (j - i) <= n and i <= a and b <= j and q not in out:
            out.append(q)
    return out
