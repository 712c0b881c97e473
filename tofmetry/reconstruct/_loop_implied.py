"""Registration hypotheses a loop implies: when the selection had to drop an edge, the pairs of
the loop it would close are registered again from the pose the rest of that loop gives them.

The pairwise global search can miss the right pose of a pair and return a wrong one that passes
the gates (an igea's first two views, 45 deg apart: the search's best pose was 49.5 deg off with
68 % of the points matched; ICP from the true pose matched 99 %). The loop through that pair then
does not close, and :func:`~tofmetry.reconstruct._loops.select_hypotheses`, which may only drop
edges between non-successive views, drops the right closing edge instead: the chain keeps the
wrong pair and nothing is left to check it.

Here, for every dropped edge, each kept edge on the path it would close is given the pose that
the other edges and the dropped one imply, refined by the pair's ICP (no global search, the
loop-closure jump bound). That pose becomes one more hypothesis of the edge only where the
pair's own points fit it clearly better than the hypothesis kept: a fitness higher by at least
``min_gain`` (the selection's ambiguity margin). That test is the pair's data, not the loop's:
a loop whose edge was derived from the loop would close by construction. The selection is then
run again with the new hypotheses (:meth:`~tofmetry.reconstruct._posegraph.PoseGraphBuilder.select_hypotheses`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace
from typing import Callable

import numpy as np

from tofmetry.reconstruct._view_graph import spanning_tree
from tofmetry.reconstruct._register import PairResult, _same_pose

#: method tag of a hypothesis found here
METHOD = "loop-implied+icp"


def _path(n: int, edges: list[PairResult], a: int, b: int) -> list[int] | None:
    """Indices into ``edges`` of a shortest path from view ``a`` to view ``b`` (None: not connected)."""
    adj: dict[int, list[tuple[int, int]]] = {k: [] for k in range(n)}
    for k, e in enumerate(edges):
        adj[e.source].append((e.target, k))
        adj[e.target].append((e.source, k))
    prev: dict[int, tuple[int, int]] = {a: (-1, -1)}
    todo = deque([a])
    while todo:
        v = todo.popleft()
        for w, k in adj[v]:
            if w not in prev:
                prev[w] = (v, k)
                todo.append(w)
    if b not in prev:
        return None
    out = []
    while b != a:
        b, k = prev[b]
        out.append(k)
    return out[::-1]


def loop_implied_hypotheses(n: int, before: list[PairResult], selected: list[PairResult],
                            register: Callable[[int, int, np.ndarray], PairResult],
                            min_gain: float) -> tuple[list[PairResult], list[dict]]:
    """The pairs ``before`` the selection, with the hypotheses the loops of the dropped edges imply.

    Parameters
    ----------
    n : number of views
    before : the pairwise results the selection chose from (same order as ``selected``)
    selected : the selection's output: dropped edges have ``accepted=False`` and "dropped" in
        their method, kept ones carry the hypothesis chosen
    register : ``register(i, j, init) -> PairResult``: the pair (i, j) refined from ``init``
        (source -> target, (4, 4) [m]) without a global search
    min_gain : a loop-implied pose is added only where its fitness exceeds the kept hypothesis's
        by at least this (share of the source object points matched)

    Returns
    -------
    pairs : ``before`` with the new hypotheses appended to their edges' ``alternatives`` (a new list)
    found : one dict per hypothesis added: edge (i, j), its fitness, the kept one's, and the
        dropped edge whose loop implied it
    """
    out = list(before)
    found: list[dict] = []
    kept_idx = [k for k, p in enumerate(selected) if p.accepted]
    kept = [selected[k] for k in kept_idx]
    for kd, d in enumerate(selected):
        if d.accepted or "dropped" not in d.method:
            continue
        closing = before[kd]
        path = _path(n, kept, closing.source, closing.target)
        if not path:
            continue
        for m in path:
            e = kept[m]
            ke = kept_idx[m]
            others = [p for q, p in enumerate(kept) if q != m] + [closing]
            poses, _, _, depth = spanning_tree(n, others)
            if depth[e.source] < 0 or depth[e.target] < 0:
                continue
            init = np.linalg.inv(poses[e.target]) @ poses[e.source]  # pose_source = pose_target @ T
            if _same_pose(init, e.transform):
                continue
            q = register(e.source, e.target, init)
            if not q.accepted or q.fitness < e.fitness + min_gain:
                continue
            if any(_same_pose(q.transform, h.transform) for h in [out[ke], *out[ke].alternatives]):
                continue
            q = replace(q, method=METHOD, alternatives=[])
            out[ke] = replace(out[ke], alternatives=[*out[ke].alternatives, q])
            found.append({"edge": (e.source, e.target), "fitness": round(float(q.fitness), 4),
                          "kept_fitness": round(float(e.fitness), 4), "implied_by": (closing.source, closing.target)})
    return out, found
