"""Pose graph over all accepted pairwise registrations, globally optimised (Open3D LM)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.errors import EstimationError
from tofmetry.reconstruct._register import PairResult


def relative_pose_errors(poses, true_poses) -> np.ndarray:
    """Errors of estimated camera poses against true ones, both relative to view 0.

    Parameters
    ----------
    poses : (N, 4, 4) estimated camera-to-world [m] in any world frame (taken relative to view 0)
    true_poses : (N, 4, 4) true camera-to-world [m] in any world frame

    Returns
    -------
    (N, 2) float64: rotation error [deg] and camera-centre error [mm] of each view
    (``E = inv(inv(T0) Tk) Pk``; view 0 is exact by construction).
    """
    true_poses = [np.asarray(T, np.float64) for T in true_poses]
    if len(poses) != len(true_poses):
        raise ValueError(f"relative_pose_errors: {len(poses)} poses for {len(true_poses)} true poses")
    inv0 = np.linalg.inv(true_poses[0])
    est0 = np.linalg.inv(np.asarray(poses[0], np.float64))
    out = []
    for P, T in zip(poses, true_poses):
        E = np.linalg.inv(inv0 @ T) @ est0 @ np.asarray(P, np.float64)
        out.append((rotation_angle_deg(E), float(np.linalg.norm(E[:3, 3])) * 1e3))
    return np.array(out)


def connected_components(n: int, edges: list[tuple[int, int]]) -> list[list[int]]:
    """Connected components of an undirected graph on nodes 0..n-1 (union-find)."""
    parent = list(range(n))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in edges:
        parent[find(a)] = find(b)
    comps: dict[int, list[int]] = {}
    for k in range(n):
        comps.setdefault(find(k), []).append(k)
    return sorted(comps.values(), key=lambda c: c[0])


@dataclass
class PoseGraphResult:
    """Optimised poses and per-edge consistency.

    Attributes
    ----------
    poses : (V, 4, 4) camera-to-world, world = camera frame of view 0
    edges : list of dicts: source, target, fitness, inlier_rmse_mm, method, kept (after pruning),
        residual_rot_deg / residual_trans_mm (edge transform vs optimised poses)
    consistency : output of :func:`consistency_gate` (reliable flag, reasons, figures)
    """

    poses: np.ndarray
    edges: list
    consistency: dict | None = None


class PoseGraphBuilder:
    """Collects pairwise results and optimises the poses (one ``add`` per registered pair)."""

    def __init__(self, n_views: int, names: list[str]):
        self.n = n_views
        self.names = names
        self.pairs: list[PairResult] = []
        self.selection: dict | None = None
        self.centres: np.ndarray | None = None  # (n, 3) object centre per view, camera frame [m]

    def add(self, pair: PairResult) -> None:
        self.pairs.append(pair)

    def accepted(self) -> list[PairResult]:
        return [p for p in self.pairs if p.accepted]

    def components(self) -> list[list[int]]:
        """Connected components of the accepted edges (lists of view indices, the largest first;
        ties: the one holding the lowest view index)."""
        comps = connected_components(self.n, [(p.source, p.target) for p in self.accepted()])
        return sorted(comps, key=lambda c: (-len(c), c[0]))

    def subgraph(self, keep: list[int]) -> PoseGraphBuilder:
        """A builder over the views ``keep`` only (renumbered in that order), with the pairs
        between them; the selection report is carried over."""
        idx = {v: k for k, v in enumerate(keep)}
        sub = PoseGraphBuilder(len(keep), [self.names[v] for v in keep])
        for p in self.pairs:
            if p.source in idx and p.target in idx:
                sub.add(_renumber(p, idx))
        sub.selection = self.selection
        sub.centres = None if self.centres is None else self.centres[keep]
        return sub

    def chain_poses(self) -> np.ndarray:
        """Initial camera-to-world poses by a breadth-first walk over accepted edges from view 0."""
        return spanning_tree(self.n, self.accepted())[0]

    def check_connected(self) -> None:
        """Raise EstimationError naming the view groups when the accepted edges do not connect all views."""
        comps = connected_components(self.n, [(p.source, p.target) for p in self.accepted()])
        if len(comps) > 1:
            groups = "; ".join("{" + ", ".join(self.names[k] for k in c) + "}" for c in comps)
            worst = ", ".join(f"{self.names[p.source]}->{self.names[p.target]} fitness {p.fitness:.2f} rmse "
                              f"{p.inlier_rmse_mm:.1f} mm seen-through {p.see_through:.0%}" for p in self.pairs
                              if not p.accepted)[:700]
            raise EstimationError(
                f"registration graph is disconnected: {len(comps)} groups of views that do not overlap each other: "
                f"{groups}. No model is written. Rejected pairs: {worst} (a pair is rejected below the fitness / "
                "RMSE gates, or when the other camera sees through more than the allowed share of the matched "
                "object: a false match of a nearly symmetric object). Take views with more overlap "
                "(successive views should share most of the object)"
            )

    def cycle_closure(self) -> tuple[float, float, int] | None:
        """Closure error of the circle of successive edges 0 -> 1 -> ... -> n-1 compared with the
        direct edge 0 -> n-1 (before optimisation): (rotation [deg], translation [mm], edges in the
        cycle), or None when one of them is missing."""
        d = {(p.source, p.target): p for p in self.accepted()}
        if self.n < 3 or (0, self.n - 1) not in d or any((i, i + 1) not in d for i in range(self.n - 1)):
            return None
        C = np.eye(4)
        for i in range(self.n - 1):
            C = d[(i, i + 1)].transform @ C
        E = np.linalg.inv(d[(0, self.n - 1)].transform) @ C
        return rotation_angle_deg(E), float(np.linalg.norm(E[:3, 3])) * 1e3, self.n

    def loop_closures(self) -> list[dict]:
        """Closure of every fundamental cycle of the accepted edges (see :func:`loop_closures`)."""
        return loop_closures(self.n, self.accepted(), self.names, self.centres)

    def select_hypotheses(self, max_deg: float = 2.0, max_mm: float = 10.0, margin: float = 0.05,
                          max_combos: int = 1024, spread_deg: float | None = None,
                          spread_mm: float | None = None) -> dict:
        """Choose one hypothesis per edge so that every loop closes (see :func:`select_hypotheses`);
        replaces :attr:`pairs` by the selection. Returns the selection report.

        When the loops close within (``max_deg``, ``max_mm``) per edge only by dropping an edge and
        ``spread_deg`` / ``spread_mm`` are given, the selection is tried again within these wider
        bounds (still far below the tens of degrees of a turned-over match): if it keeps more edges,
        it is taken and the report says ``spread``: the loops' error is then spread over the edges
        by the pose-graph optimisation and the global adjustment, instead of the closing edge being
        dropped (a few millimetres of depth-calibration residual make a loop of 8 views close only
        to a few degrees, measured)."""
        pairs, report = select_hypotheses(self.n, self.pairs, self.names, max_deg, max_mm, margin, max_combos)
        report["spread"] = False
        if report.get("dropped") and spread_deg is not None and spread_mm is not None:
            pairs2, rep2 = select_hypotheses(self.n, self.pairs, self.names, spread_deg, spread_mm, margin, max_combos)
            if rep2.get("resolved") and len(rep2.get("dropped", [])) < len(report["dropped"]):
                pairs, report = pairs2, rep2
                report["spread"] = True
                report["spread_bounds"] = {"deg": spread_deg, "mm": spread_mm}
        self.pairs = pairs
        self.selection = report
        return report

    def optimize(self, max_corr_m: float, edge_prune: float = 0.25, gate_deg: float = 2.0,
                 gate_mm: float = 10.0) -> PoseGraphResult:
        """Global optimisation (Levenberg-Marquardt, line-process pruning), view 0 fixed."""
        import open3d as o3d

        reg = o3d.pipelines.registration
        self.check_connected()
        init = self.chain_poses()
        pg = reg.PoseGraph()
        for k in range(self.n):
            pg.nodes.append(reg.PoseGraphNode(init[k]))
        acc = self.accepted()
        for p in acc:
            # the edges of the circle of views (successive pairs, the closing pair last -> first and
            # the bridges over a failed pair) were chosen by the multi-view selection so that every
            # loop closes: they are all "certain", and the optimisation spreads the loops' remaining
            # error over them (weighted by their information) instead of pruning the closing edge.
            # Only loop-closure candidates between other views (``all_pairs``) may be pruned.
            uncertain = abs(p.source - p.target) > 2 and {p.source, p.target} != {0, self.n - 1}
            pg.edges.append(reg.PoseGraphEdge(p.source, p.target, p.transform, p.information, uncertain=uncertain))
        if len(acc) > self.n - 1:
            opt = reg.GlobalOptimizationOption(max_correspondence_distance=max_corr_m, edge_prune_threshold=edge_prune,
                                               preference_loop_closure=2.0, reference_node=0)
            reg.global_optimization(pg, reg.GlobalOptimizationLevenbergMarquardt(),
                                    reg.GlobalOptimizationConvergenceCriteria(), opt)
        poses = np.stack([np.asarray(nd.pose) for nd in pg.nodes])
        poses = np.linalg.inv(poses[0]) @ poses  # world = view 0 exactly
        kept = {(e.source_node_id, e.target_node_id) for e in pg.edges}
        edges = []
        for p in self.pairs:
            d = p.to_dict(self.names)
            d["kept"] = bool(p.accepted and (p.source, p.target) in kept)
            if p.accepted:
                rel = np.linalg.inv(poses[p.target]) @ poses[p.source]
                E = np.linalg.inv(p.transform) @ rel
                d["residual_rot_deg"] = round(rotation_angle_deg(E), 4)
                d["residual_trans_mm"] = round(float(np.linalg.norm(E[:3, 3])) * 1e3, 3)
            edges.append(d)
        return PoseGraphResult(poses, edges, consistency_gate(edges, self.cycle_closure(), gate_deg, gate_mm,
                                                              self.loop_closures(), self.selection))


def _renumber(p: PairResult, idx: dict) -> PairResult:
    return replace(p, source=idx[p.source], target=idx[p.target],
                   alternatives=[_renumber(a, idx) for a in p.alternatives])


def consistency_gate(edges: list[dict], cycle: tuple[float, float, int] | None, max_deg: float = 2.0,
                     max_mm: float = 10.0, loops: list[dict] | None = None, selection: dict | None = None) -> dict:
    """Is the optimised pose graph self-consistent? (the run is flagged unreliable otherwise)

    Two tests, both against (``max_deg``, ``max_mm``):

    * every *kept* edge: its pairwise transform vs the optimised relative pose (residual);
    * the circle of successive edges vs the direct first -> last edge, before optimisation,
      per edge: closure / sqrt(number of edges) (independent pairwise errors add up as a random
      walk). A symmetric object registered flipped, or depth with a scale error (raw data),
      leaves a circle that does not close.

    * every fundamental cycle of the accepted edges (``loops``, from :func:`loop_closures`: each
      accepted edge outside the breadth-first spanning tree closes one), per edge as above. An
      edge pruned by the optimisation still fails the gate when its loop does not close: either it
      or an edge of the tree is wrong, and the data do not say which.

    Returns
    -------
    dict: reliable (bool), reasons (list of str), max_kept_residual_deg / _mm, cycle_closure_deg / _mm,
    cycle_per_edge_deg / _mm, n_pruned, thresholds.
    """
    kept = [e for e in edges if e.get("kept")]
    r_deg = max((e.get("residual_rot_deg", 0.0) for e in kept), default=0.0)
    r_mm = max((e.get("residual_trans_mm", 0.0) for e in kept), default=0.0)
    reasons = []
    if r_deg > max_deg or r_mm > max_mm:
        worst = max(kept, key=lambda e: max(e.get("residual_rot_deg", 0) / max_deg, e.get("residual_trans_mm", 0) / max_mm))
        reasons.append(f"kept edge {worst['source']}->{worst['target']} disagrees with the optimised poses by "
                       f"{worst.get('residual_rot_deg', 0):.2f} deg / {worst.get('residual_trans_mm', 0):.1f} mm "
                       f"(limit {max_deg:g} deg / {max_mm:g} mm)")
    out = {"max_kept_residual_deg": float(r_deg), "max_kept_residual_mm": float(r_mm),
           "n_pruned": int(sum(bool(e.get("accepted")) and not e.get("kept") for e in edges)),
           "thresholds": {"deg": max_deg, "mm": max_mm}}
    if cycle is not None:
        c_deg, c_mm, n = cycle
        pe_deg, pe_mm = c_deg / np.sqrt(n), c_mm / np.sqrt(n)
        out.update(cycle_closure_deg=float(c_deg), cycle_closure_mm=float(c_mm), cycle_per_edge_deg=float(pe_deg),
                   cycle_per_edge_mm=float(pe_mm))
        if pe_deg > max_deg or pe_mm > max_mm:
            reasons.append(f"the circle of successive views does not close: {c_deg:.2f} deg / {c_mm:.1f} mm over {n} "
                           f"edges ({pe_deg:.2f} deg / {pe_mm:.1f} mm per edge; limit {max_deg:g} deg / {max_mm:g} mm)")
    else:
        out.update(cycle_closure_deg=None, cycle_closure_mm=None, cycle_per_edge_deg=None, cycle_per_edge_mm=None)
    loops = loops or []
    bad = [lp for lp in loops if lp["per_edge_deg"] > max_deg or lp["per_edge_mm"] > max_mm]
    if bad:
        w = max(bad, key=lambda lp: max(lp["per_edge_deg"] / max_deg, lp["per_edge_mm"] / max_mm))
        reasons.append(f"the loop closed by edge {w['edge'][0]}->{w['edge'][1]} ({w['n_edges']} edges) does not close: "
                       f"{w['closure_deg']:.2f} deg / {w['closure_mm']:.1f} mm ({len(bad)} failing loop(s) of {len(loops)})")
    out["loops"] = loops
    if selection is not None:
        out["selection"] = selection
        reasons.extend(selection.get("reasons", []))
    out["n_loops_verified"] = int(len(loops) - len(bad))
    out["reliable"] = not reasons
    out["reasons"] = reasons
    return out


def spanning_tree(n: int, pairs: list[PairResult]) -> tuple[np.ndarray, list[int], np.ndarray, np.ndarray]:
    """Breadth-first spanning tree of the edges ``pairs`` from view 0 (in edge order).

    Returns
    -------
    poses : (n, 4, 4) chained camera-to-world (NaN for views not reached)
    tree : indices into ``pairs`` of the tree edges
    parent : (n,) parent view in the tree (-1 for the root / unreached)
    depth : (n,) edges from view 0 (-1 unreached)
    """
    poses = np.full((n, 4, 4), np.nan)
    poses[0] = np.eye(4)
    parent, depth = np.full(n, -1), np.full(n, -1)
    depth[0] = 0
    tree = []
    changed = True
    while changed:
        changed = False
        for k, p in enumerate(pairs):
            # T maps source -> target: pose_source = pose_target @ T
            if depth[p.target] >= 0 and depth[p.source] < 0:
                poses[p.source] = poses[p.target] @ p.transform
                parent[p.source], depth[p.source] = p.target, depth[p.target] + 1
            elif depth[p.source] >= 0 and depth[p.target] < 0:
                poses[p.target] = poses[p.source] @ np.linalg.inv(p.transform)
                parent[p.target], depth[p.target] = p.source, depth[p.source] + 1
            else:
                continue
            tree.append(k)
            changed = True
    return poses, tree, parent, depth


def loop_closures(n: int, pairs: list[PairResult], names: list[str] | None = None,
                  centres: np.ndarray | None = None) -> list[dict]:
    """Fundamental cycles of the edges ``pairs``: every edge outside the breadth-first spanning tree
    compared with the tree's chained relative pose.

    Parameters
    ----------
    centres : (n, 3) optional object centre seen by each view, in its camera frame [m]: the
        closure is then also measured where it matters, as the displacement of the object centre

    Returns
    -------
    list of dicts: edge (source, target names), n_edges in the cycle, closure_deg / closure_mm
    (translation at the source camera centre), per_edge_deg / per_edge_mm (closure / sqrt(n_edges):
    independent errors add as a random walk), closure_object_mm (with ``centres``)
    """
    names = names or [str(k) for k in range(n)]
    poses, tree, parent, depth = spanning_tree(n, pairs)
    in_tree = set(tree)
    out = []
    for k, p in enumerate(pairs):
        if k in in_tree or depth[p.source] < 0 or depth[p.target] < 0:
            continue
        a, b, m = p.source, p.target, 1
        while a != b:  # path length through the tree (lowest common ancestor)
            if depth[a] >= depth[b]:
                a = parent[a]
            else:
                b = parent[b]
            m += 1
        E = np.linalg.inv(p.transform) @ np.linalg.inv(poses[p.target]) @ poses[p.source]
        c_deg, c_mm = rotation_angle_deg(E), float(np.linalg.norm(E[:3, 3])) * 1e3
        d = {"edge": [names[p.source], names[p.target]], "n_edges": m, "closure_deg": round(c_deg, 4),
             "closure_mm": round(c_mm, 3), "per_edge_deg": round(c_deg / np.sqrt(m), 4),
             "per_edge_mm": round(c_mm / np.sqrt(m), 3)}
        if centres is not None:
            c = np.asarray(centres[p.source], np.float64)
            d["closure_object_mm"] = round(float(np.linalg.norm(E[:3, :3] @ c + E[:3, 3] - c)) * 1e3, 3)
        out.append(d)
    return out


def _poses_differ(A: np.ndarray, B: np.ndarray, max_deg: float, max_mm: float) -> bool:
    for a, b in zip(A, B):
        E = np.linalg.inv(a) @ b
        if rotation_angle_deg(E) > max_deg or np.linalg.norm(E[:3, 3]) * 1e3 > max_mm:
            return True
    return False


def select_hypotheses(n: int, pairs: list[PairResult], names: list[str], max_deg: float = 2.0, max_mm: float = 10.0,
                      margin: float = 0.05, max_combos: int = 1024) -> tuple[list[PairResult], dict]:
    """Multi-view choice between the registration hypotheses of every edge.

    A nearly symmetric object matches itself turned over: an edge may have several hypotheses that
    pass the pairwise gates (its ``alternatives``). One hypothesis is chosen per edge (an edge
    between non-successive views may also be dropped: successive views are the nearest in the
    scan order, a direct first -> last or bridging match is the least certain) such that every
    loop of the graph closes within (``max_deg``, ``max_mm``) per edge; among those selections
    the one with the largest summed fitness wins.

    Refusal/flags (in ``report["reasons"]``, which makes the run unreliable):

    * no selection closes every loop (the gate reports the failing loops);
    * another closing selection with different poses scores within ``margin`` (summed fitness):
      the geometry cannot decide ("registration ambiguous");
    * an edge had to be dropped and no loop is left to verify the rest;
    * an edge between non-successive views is the only link between two parts of the graph
      (no loop verifies it).

    Returns
    -------
    pairs : the edges with the chosen hypotheses (dropped edges: ``accepted=False``)
    report : dict (changed edges, dropped edges, candidates tested, consistent ones, reasons)
    """
    acc = [k for k, p in enumerate(pairs) if p.accepted]
    opts = []
    for k in acc:
        p = pairs[k]
        o = [p] + [a for a in p.alternatives if a.accepted]
        if abs(p.source - p.target) != 1:
            o.append(None)
        opts.append(o)
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
        poses, _, _, depth = spanning_tree(n, kept)
        if (depth < 0).any():
            continue
        n_tested += 1
        loops = loop_closures(n, kept)
        if all(lp["per_edge_deg"] <= max_deg and lp["per_edge_mm"] <= max_mm for lp in loops):
            consistent.append((sum(p.fitness for p in kept), combo, poses, len(loops)))
    report = {"tested": n_tested, "consistent": len(consistent), "changed": [], "dropped": [], "reasons": [],
              "ambiguous_with": []}
    if not consistent:
        report["resolved"] = False
        return pairs, report
    consistent.sort(key=lambda c: -c[0])
    score, combo, poses, n_loops = consistent[0]
    report["resolved"] = True
    report["n_loops"] = n_loops
    for s2, c2, p2, _ in consistent[1:]:
        if s2 >= score - margin and _poses_differ(poses, p2, max_deg, max_mm):
            diff = [f"{names[pairs[acc[m]].source]}->{names[pairs[acc[m]].target]}" for m in range(len(acc)) if c2[m] != combo[m]]
            report["ambiguous_with"].append({"score_difference": round(score - s2, 4), "edges": diff})
    out = list(pairs)
    for m, c in enumerate(combo):
        p = pairs[acc[m]]
        ch = opts[m][c]
        tag = f"{names[p.source]}->{names[p.target]}"
        if ch is None:
            out[acc[m]] = replace(p, accepted=False, method=p.method + " (dropped: contradicts the other views)")
            report["dropped"].append(tag)
        elif ch is not p:
            out[acc[m]] = p.with_hypothesis(ch)
            report["changed"].append(tag)
    if report["ambiguous_with"]:
        a = report["ambiguous_with"][0]
        report["reasons"].append(
            f"registration ambiguous: {len(report['ambiguous_with'])} other choice(s) of the pairwise hypotheses close "
            f"every loop with a summed fitness within {margin:g} (e.g. changing {', '.join(a['edges'])}: "
            f"{a['score_difference']:.3f} lower) but place the cameras differently; the object looks alike from "
            "different sides (symmetry): the camera poses are not determined by the geometry")
    kept = [out[acc[m]] for m, c in enumerate(combo) if opts[m][c] is not None]
    for e in kept:  # a match between non-successive views that no loop verifies is not trusted
        if abs(e.source - e.target) != 1 and len(connected_components(n, [(p.source, p.target) for p in kept
                                                                         if p is not e])) > 1:
            report["unverified"] = report.get("unverified", []) + [f"{names[e.source]}->{names[e.target]}"]
    if report.get("unverified"):
        report["reasons"].append(
            f"edge(s) {', '.join(report['unverified'])} between non-successive views are the only link between parts "
            "of the scan and no closed loop verifies them (a nearly symmetric object matches itself turned over "
            "between distant views); take more views or views with more overlap")
    if report["dropped"] and n_loops == 0:
        report["reasons"].append(f"edge(s) {', '.join(report['dropped'])} contradict the chain of successive views and "
                                 "were dropped; no closed loop is left to verify the registration")
    return out, report
