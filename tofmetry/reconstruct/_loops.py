"""The loops of the view graph: fundamental cycles and their closure, and the choice of one
registration hypothesis per pair so that every loop closes (:func:`select_hypotheses`).

Pure functions of the pairwise results (:class:`~tofmetry.reconstruct._register.PairResult`) on the
graph's structure (:mod:`~tofmetry.reconstruct._view_graph`: components, bridges, spanning tree);
:class:`~tofmetry.reconstruct._posegraph.PoseGraphBuilder` uses them.
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np

from tofmetry._shared.geometry import displacement_at, rotation_angle_deg
from tofmetry.reconstruct._camera_path import closes_once, path_walk
from tofmetry.reconstruct._register import PairResult
from tofmetry.reconstruct._view_graph import bridges, connected_components, spanning_tree, undecided_drops


def loop_closures(n: int, pairs: list[PairResult], names: list[str] | None = None,
                  centres: np.ndarray | None = None, root: int = 0) -> list[dict]:
    """Fundamental cycles of the edges ``pairs``: every edge outside the breadth-first spanning tree
    compared with the tree's chained relative pose.

    Parameters
    ----------
    centres : (n, 3) optional object centre seen by each view, in its camera frame [m]: the
        closure is then also measured where it matters, as the displacement of the object centre
    root : the view the spanning tree grows from: only the cycles among the views it reaches count

    Returns
    -------
    list of dicts: edge (source, target names), n_edges in the cycle, members (its edges as
    [name, name] pairs, the closing edge first, in either direction), closure_deg / closure_mm
    (translation at the source camera centre), per_edge_deg / per_edge_mm (closure / sqrt(n_edges):
    independent errors add as a random walk), closure_object_mm (with ``centres``)
    """
    names = names or [str(k) for k in range(n)]
    poses, tree, parent, depth = spanning_tree(n, pairs, root)
    in_tree = set(tree)
    out = []
    for k, p in enumerate(pairs):
        if k in in_tree or depth[p.source] < 0 or depth[p.target] < 0:
            continue
        a, b, m = p.source, p.target, 1
        members = [[names[p.source], names[p.target]]]
        while a != b:  # path length through the tree (lowest common ancestor)
            if depth[a] >= depth[b]:
                members.append([names[a], names[parent[a]]])
                a = parent[a]
            else:
                members.append([names[b], names[parent[b]]])
                b = parent[b]
            m += 1
        E = np.linalg.inv(p.transform) @ np.linalg.inv(poses[p.target]) @ poses[p.source]
        c_deg, c_mm = rotation_angle_deg(E), float(np.linalg.norm(E[:3, 3])) * 1e3
        d = {"edge": [names[p.source], names[p.target]], "n_edges": m, "closure_deg": round(c_deg, 4),
             "closure_mm": round(c_mm, 3), "per_edge_deg": round(c_deg / np.sqrt(m), 4),
             "per_edge_mm": round(c_mm / np.sqrt(m), 3), "members": members}
        if centres is not None:
            c = np.asarray(centres[p.source], np.float64)
            d["closure_object_mm"] = round(displacement_at(E, c) * 1e3, 3)
        out.append(d)
    return out


def _poses_differ(A: np.ndarray, B: np.ndarray, max_deg: float, max_mm: float) -> bool:
    for a, b in zip(A, B):
        E = np.linalg.inv(a) @ b
        if rotation_angle_deg(E) > max_deg or np.linalg.norm(E[:3, 3]) * 1e3 > max_mm:
            return True
    return False


def select_hypotheses(n: int, pairs: list[PairResult], names: list[str], max_deg: float = 2.0, max_mm: float = 10.0,
                      margin: float = 0.05, max_combos: int = 1024, ir_min_corr: float = 0.3,
                      ir_margin: float = 0.2, ir_veto_corr: float = 0.5, centres: np.ndarray | None = None,
                      ups: np.ndarray | None = None, path_max_ratio: float | None = None,
                      path_margin: float = 0.3) -> tuple[list[PairResult], dict]:
    """Multi-view choice between the registration hypotheses of every edge.

    A nearly symmetric object matches itself turned over: an edge may have several hypotheses that
    pass the pairwise gates (its ``alternatives``). One hypothesis is chosen per edge (an edge
    between non-successive views may also be dropped: successive views are the nearest in the
    scan order, a direct first -> last or bridging match is the least certain) such that every
    loop of the graph closes within (``max_deg``, ``max_mm``) per edge; among those selections
    the one with the largest summed fitness wins.

    A hypothesis the IR albedo contradicts is not a choice: where another hypothesis of the edge lines
    a painted pattern up (``ir_corr`` at least ``ir_veto_corr``: the primary one, or else the
    alternative lining it up best) and this one lines it up worse by ``ir_margin``
    (``report["ir_vetoed"]`` names these edges). So the primary hypothesis itself is refused where
    it leaves the pattern unmatched and an alternative lines it up: a painted dome's pairs, turned
    half a turn by its symmetry, matched more points (0.986-1.000) than the right poses and lined the
    pattern up at 0.36-0.52, the right poses at 0.94-0.97 (measured, session 21). On a vase the geometric alternatives
    of the yaw-free edges, every camera at the same place on the turned surface, close the loop
    trivially and outscore the pattern's choice in fitness (measured: a painted vase, 9 views, the
    sweep decided all 9 yaws at correlation 0.90-0.96; the selection swapped 8 for alternatives at
    -0.14-0.13 and the run was 142 deg off).

    The cameras walk around the object in scan order (:mod:`tofmetry.reconstruct._camera_path`):
    where ``path_max_ratio`` and ``centres`` ((n, 3) object centre of each view in its camera frame
    [m]) are given, a selection whose cameras step back or leap
    (:func:`~tofmetry.reconstruct._camera_path.path_anomalies`) yields to the closing selection
    with fewer such steps and the most fitness, if that is within ``path_margin`` of the best (``report["decided_by_path"]``); a tied selection with more of them
    than the one chosen is no alternative. The vertical: ``ups`` ((n, 3) the support plane's normal
    in each camera frame) where the root view has one, else the normal of the plane through the
    camera centres.

    Refusal/flags (in ``report["reasons"]``, which makes the run unreliable):

    * no selection closes every loop (the gate reports the failing loops);
    * another closing selection with different poses scores within ``margin`` (summed fitness):
      the geometry cannot decide ("registration ambiguous") -- unless the IR albedo does: among the
      tied selections, one whose edges' albedo correlation (``PairResult.ir_corr``), averaged over
      the edges where it differs from each other tied selection, reaches ``ir_min_corr`` and beats
      the other's by ``ir_margin`` is taken (``report["decided_by_ir"]``);
    * an edge had to be dropped and no loop is left to verify the rest, or the views it joins are
      linked otherwise only through edges no loop checks (:func:`undecided_drops`);
    * an edge between non-successive views is the only link between two parts of the graph
      (no loop verifies it).

    Returns
    -------
    pairs : the edges with the chosen hypotheses (dropped edges: ``accepted=False``)
    report : dict (changed edges, dropped edges, candidates tested, consistent ones, reasons)
    """
    out, report, _ = select_with_tied(n, pairs, names, max_deg, max_mm, margin, max_combos, ir_min_corr, ir_margin,
                                      ir_veto_corr, centres, ups, path_max_ratio, path_margin)
    return out, report


def select_with_tied(n: int, pairs: list[PairResult], names: list[str], max_deg: float = 2.0, max_mm: float = 10.0,
                     margin: float = 0.05, max_combos: int = 1024, ir_min_corr: float = 0.3,
                     ir_margin: float = 0.2, ir_veto_corr: float = 0.5, centres: np.ndarray | None = None,
                     ups: np.ndarray | None = None, path_max_ratio: float | None = None,
                     path_margin: float = 0.3) -> tuple[list[PairResult], dict, list[list[PairResult]]]:
    """As :func:`select_hypotheses`, and the choices tied with the chosen one.

    Returns
    -------
    pairs, report : as :func:`select_hypotheses`
    tied : the edges of each choice tied with the chosen one (``report["ambiguous_with"]``), as ``pairs``
    """
    acc = [k for k, p in enumerate(pairs) if p.accepted]
    opts = []
    vetoed = []
    for k in acc:
        p = pairs[k]
        alts = [a for a in p.alternatives if a.accepted]
        keep = [a for a in alts if not _ir_rejects(p, a, ir_veto_corr, ir_margin)]
        o = [p] + keep
        lined = max(o, key=lambda h: -np.inf if h.ir_corr is None else h.ir_corr)
        if lined is not p and lined.ir_corr >= ir_veto_corr:  # an alternative lines the pattern up better
            o = [h for h in o if h is lined or not _ir_rejects(lined, h, ir_veto_corr, ir_margin)]
        if len(o) < 1 + len(alts):
            vetoed.append(f"{names[p.source]}->{names[p.target]}")
        if abs(p.source - p.target) != 1:
            o.append(None)
        opts.append(o)
    # views no accepted edge links to the largest group are left out of the model afterwards: the
    # choice is made on that group (a view left out must not void every selection, and its checks)
    main = max(connected_components(n, [(pairs[k].source, pairs[k].target) for k in acc]), key=len)
    root = main[0]
    free = [m for m, o in enumerate(opts) if len(o) > 1]
    # bound the search: the edges whose best alternative is closest to the primary first
    while np.prod([len(opts[m]) for m in free], dtype=float) > max_combos:
        m = max(free, key=lambda m: opts[m][0].fitness - (opts[m][1].fitness if opts[m][1] is not None else 0.0))
        alts = [x for x in opts[m][1:] if x is not None]
        if alts:
            opts[m] = [x for x in opts[m] if x is not alts[-1]]
        else:
            opts[m] = opts[m][:1]
        if len(opts[m]) == 1:
            free.remove(m)
    consistent = []
    n_tested = 0
    for combo in itertools.product(*[range(len(o)) for o in opts]):
        sel = [opts[m][c] for m, c in enumerate(combo)]
        kept = [p for p in sel if p is not None]
        poses, _, _, depth = spanning_tree(n, kept, root)
        if (depth[main] < 0).any():
            continue
        poses = poses[main]  # the views a selection places (the others stay NaN)
        n_tested += 1
        loops = loop_closures(n, kept, root=root)
        if all(lp["per_edge_deg"] <= max_deg and lp["per_edge_mm"] <= max_mm for lp in loops):
            consistent.append((sum(p.fitness for p in kept), combo, poses, len(loops)))
    report = {"tested": n_tested, "consistent": len(consistent), "changed": [], "dropped": [], "reasons": [],
              "ambiguous_with": [], "ir_vetoed": vetoed}
    if not consistent:
        report["resolved"] = False
        return pairs, report, []
    consistent.sort(key=lambda c: -c[0])
    best = consistent[0]
    walk = None
    order = sorted(main)
    if path_max_ratio is not None and centres is not None:
        walk = {id(c): _path_anomalies(c[2], main, order, root, centres, ups, path_max_ratio) for c in consistent}
        if walk[id(best)]:
            fewer = [c for c in consistent if len(walk[id(c)]) < len(walk[id(best)]) and c[0] >= best[0] - path_margin]
            if fewer:
                pick = min(fewer, key=lambda c: (len(walk[id(c)]), -c[0]))
                report["decided_by_path"] = {"fitness_given_up": round(best[0] - pick[0], 4),
                                             "steps_before": [f"{names[order[k]]}->{names[order[k + 1]]}"
                                                              for k in walk[id(best)]]}
                best = pick
    score, combo, poses, n_loops = best
    report["resolved"] = True
    report["n_loops"] = n_loops
    tied = [c for c in consistent if c is not best and c[0] >= score - margin
            and _poses_differ(poses, c[2], max_deg, max_mm)
            and (walk is None or len(walk[id(c)]) <= len(walk[id(best)]))]
    if tied:  # the geometry cannot decide: the IR albedo may (a painted pattern lines up at one pose only)
        pick = _ir_decides([best] + tied, opts, max_deg, max_mm, ir_min_corr, ir_margin)
        if pick is not None:
            report["decided_by_ir"] = {"geometric_choice_changed": pick[1] != combo,
                                       "fitness_given_up": round(score - pick[0], 4), "n_tied": len(tied) + 1}
            score, combo, poses, n_loops = best = pick
            tied = []
    for s2, c2, p2, _ in tied:
        diff = [f"{names[pairs[acc[m]].source]}->{names[pairs[acc[m]].target]}" for m in range(len(acc)) if c2[m] != combo[m]]
        report["ambiguous_with"].append({"score_difference": round(score - s2, 4), "edges": diff})
    out = _with_choice(pairs, acc, opts, combo, names, report)
    if report["ambiguous_with"]:
        a = report["ambiguous_with"][0]
        report["ambiguous_reason"] = (
            f"registration ambiguous: {len(report['ambiguous_with'])} other choice(s) of the pairwise hypotheses close "
            f"every loop with a summed fitness within {margin:g} (e.g. changing {', '.join(a['edges'])}: "
            f"{a['score_difference']:.3f} lower) but place the cameras differently; the object looks alike from "
            "different sides (symmetry): the camera poses are not determined by the geometry")
        report["reasons"].append(report["ambiguous_reason"])
    kept = [out[acc[m]] for m, c in enumerate(combo) if opts[m][c] is not None]
    kept_edges = [(p.source, p.target) for p in kept]
    br = bridges(n, kept_edges)
    in_main = set(main)  # views of a smaller group are left out of the model (and said so) anyway
    closing = None  # whether the scan's closing pair (last view, first) walks like a successive pair
    for k, e in enumerate(kept):  # a match between non-successive views that no loop verifies is not trusted
        if abs(e.source - e.target) != 1 and k in br and e.source in in_main:
            if {e.source, e.target} == {0, n - 1} and path_max_ratio is not None and centres is not None:
                if closing is None:
                    P = np.asarray(poses, np.float64)[np.argsort(main)]
                    closing = closes_once(P, order, n, centres, None if ups is None else ups[root], path_max_ratio)
                if closing:
                    report["closing_pair_walks"] = f"{names[e.source]}->{names[e.target]}"
                    continue
            report["unverified"] = report.get("unverified", []) + [f"{names[e.source]}->{names[e.target]}"]
    if report.get("unverified"):
        report["reasons"].append(
            f"edge(s) {', '.join(report['unverified'])} between non-successive views are the only link between parts "
            "of the scan and no closed loop verifies them (a nearly symmetric object matches itself turned over "
            "between distant views); take more views or views with more overlap")
    if walk is not None and walk[id(best)]:
        report["path_steps"] = [f"{names[order[k]]}->{names[order[k + 1]]}" for k in walk[id(best)]]
        report["reasons"].append(
            f"the cameras do not walk around the object in scan order: from view {report['path_steps'][0]} "
            f"({len(walk[id(best)])} step(s)) they step back or leap against the path's other steps, and no "
            "choice of the pairwise hypotheses that closes every loop walks them (a nearly symmetric object "
            "matches itself turned over); take more views, or views of a distinctive feature (views not taken one way "
            "around the object: registration.path_max_step_ratio = null switches this check off)")
    if report["dropped"] and n_loops == 0:
        report["reasons"].append(f"edge(s) {', '.join(report['dropped'])} contradict the chain of successive views and "
                                 "were dropped; no closed loop is left to verify the registration")
    elif report["dropped"]:
        drop = [(pairs[acc[m]].source, pairs[acc[m]].target) for m, c in enumerate(combo) if opts[m][c] is None]
        und = [(a, b) for a, b in undecided_drops(n, kept_edges, drop, br) if a in in_main]
        if und:
            report["undecided"] = [f"{names[a]}->{names[b]}" for a, b in und]
            report["reasons"].append(
                f"edge(s) {', '.join(report['undecided'])} contradict the other views and were dropped, but the views "
                "they join are linked otherwise only through edges no loop checks: one chain against one edge, and "
                "nothing decides which is wrong (a nearly symmetric object matches itself turned over); take more "
                "views or views with more overlap")
    return out, report, [_with_choice(pairs, acc, opts, c2, names) for _, c2, _, _ in tied]


def _with_choice(pairs: list[PairResult], acc: list[int], opts: list, combo, names: list[str],
                 report: dict | None = None) -> list[PairResult]:
    """``pairs`` with the hypothesis ``combo`` picks for each accepted edge (``acc``, ``opts``): an edge
    whose pick is None is dropped; with ``report``, the dropped and changed edges are listed in it."""
    out = list(pairs)
    for m, c in enumerate(combo):
        p = pairs[acc[m]]
        ch = opts[m][c]
        tag = f"{names[p.source]}->{names[p.target]}"
        if ch is None:
            out[acc[m]] = replace(p, accepted=False, method=p.method + " (dropped: contradicts the other views)")
            if report is not None:
                report["dropped"].append(tag)
        elif ch is not p:
            out[acc[m]] = p.with_hypothesis(ch)
            if report is not None:
                report["changed"].append(tag)
    return out


def _path_anomalies(poses_main: np.ndarray, main: list[int], order: list[int], root: int, centres: np.ndarray,
                    ups: np.ndarray | None, max_ratio: float) -> list[int]:
    """:func:`~tofmetry.reconstruct._camera_path.path_walk`'s steps that do not walk, of a selection's
    cameras (``poses_main``: the views of ``main``, in its order; the root's pose the identity), in
    scan order ``order``; indices into its steps."""
    P = np.asarray(poses_main, np.float64)[np.argsort(main)]  # rows in the order of sorted(main)
    return path_walk(P, order, centres, None if ups is None else ups[root], max_ratio)[1]


def _ir_rejects(primary: PairResult, alt: PairResult, min_corr: float, margin: float) -> bool:
    """True where the IR albedo contradicts the alternative ``alt`` of an edge: its primary hypothesis
    lines the painted pattern up (``ir_corr`` at least ``min_corr``, or a decided photometric yaw
    sweep) and the alternative lines it up worse by ``margin`` or more. On a yaw-free object the
    geometric alternatives (every view at the same place on the turned surface) close every loop
    trivially, and would win on summed fitness over the pattern's choice."""
    c0 = primary.ir_corr
    if c0 is None or c0 < min_corr:
        return False
    if alt.ir_corr is None:
        return bool(primary.ir_yaw and primary.ir_yaw.get("decided"))
    return c0 - alt.ir_corr >= margin


def _ir_decides(tied: list, opts: list, max_deg: float, max_mm: float, min_corr: float, margin: float):
    """The one selection of ``tied`` [(score, combo, poses, n_loops)] that the IR albedo prefers to
    every other with different poses (see :func:`select_hypotheses`), or None."""
    def corr(m, c):
        h = opts[m][c]
        return None if h is None else h.ir_corr

    winners = []
    for a in tied:
        ok = True
        for b in tied:
            if b is a or not _poses_differ(a[2], b[2], max_deg, max_mm):
                continue
            diff = [m for m in range(len(opts)) if a[1][m] != b[1][m]]
            ca = [corr(m, a[1][m]) for m in diff]
            cb = [corr(m, b[1][m]) for m in diff]
            if not diff or any(x is None for x in ca):  # a dropped edge or no albedo contrast: no evidence
                ok = False
                break
            ma = float(np.mean(ca))
            mb = float(np.mean([0.0 if x is None else x for x in cb]))
            if ma < min_corr or ma - mb < margin:
                ok = False
                break
        if ok:
            winners.append(a)
    return winners[0] if len(winners) == 1 else None
