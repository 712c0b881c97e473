"""Pose graph over all accepted pairwise registrations, globally optimised (Open3D LM)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.errors import EstimationError
from tofmetry.reconstruct._loops import loop_closures, select_with_tied
from tofmetry.reconstruct._register import PairResult
from tofmetry.reconstruct._view_graph import connected_components, spanning_tree


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
        self.ups: np.ndarray | None = None  # (n, 3) support plane's normal per view, camera frame (NaN: none)
        self.tied: list[list[PairResult]] = []  # the pairs of each choice the selection found tied with its own

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
        sub.ups = None if self.ups is None else self.ups[keep]
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
                          spread_mm: float | None = None, path_max_ratio: float | None = None,
                          path_margin: float = 0.3) -> dict:
        """Choose one hypothesis per edge so that every loop closes (see :func:`select_hypotheses`);
        replaces :attr:`pairs` by the selection (and :attr:`tied` by the choices tied with it). Returns
        the selection report.

        When the loops close within (``max_deg``, ``max_mm``) per edge only by dropping an edge and
        ``spread_deg`` / ``spread_mm`` are given, the selection is tried again within these wider
        bounds (still far below the tens of degrees of a turned-over match): if it keeps more edges,
        it is taken and the report says ``spread``: the loops' error is then spread over the edges
        by the pose-graph optimisation and the global adjustment, instead of the closing edge being
        dropped (a few millimetres of depth-calibration residual make a loop of 8 views close only
        to a few degrees, measured)."""
        path = {"centres": self.centres, "ups": self.ups, "path_max_ratio": path_max_ratio, "path_margin": path_margin}
        pairs, report, tied = select_with_tied(self.n, self.pairs, self.names, max_deg, max_mm, margin, max_combos,
                                               **path)
        report["spread"] = False
        if report.get("dropped") and spread_deg is not None and spread_mm is not None:
            pairs2, rep2, tied2 = select_with_tied(self.n, self.pairs, self.names, spread_deg, spread_mm, margin,
                                                   max_combos, **path)
            if rep2.get("resolved") and len(rep2.get("dropped", [])) < len(report["dropped"]):
                pairs, report, tied = pairs2, rep2, tied2
                report["spread"] = True
                report["spread_bounds"] = {"deg": spread_deg, "mm": spread_mm}
        self.pairs, self.tied = pairs, tied
        self.selection = report
        return report

    def tied_poses(self, max_corr_m: float, edge_prune: float = 0.25, limit: int = 2) -> list[np.ndarray]:
        """The optimised poses (V, 4, 4) of each choice the selection found tied with its own
        (:attr:`tied`), as :meth:`optimize` gives the chosen one's; empty when there are more than
        ``limit`` (they cannot all be checked) or one leaves the views apart."""
        if not self.tied or len(self.tied) > limit:
            return []
        out = []
        for pairs in self.tied:
            alt = PoseGraphBuilder(self.n, self.names)
            alt.pairs, alt.centres, alt.ups = list(pairs), self.centres, self.ups
            if len(alt.components()[0]) < self.n:
                return []
            out.append(alt.optimize(max_corr_m, edge_prune).poses)
        return out

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
    dict: reliable (bool), reasons (list of str), loop_reasons (those of the two loop tests),
    max_kept_residual_deg / _mm, cycle_closure_deg / _mm, cycle_per_edge_deg / _mm, n_pruned, thresholds.
    """
    kept = [e for e in edges if e.get("kept")]
    r_deg = max((e.get("residual_rot_deg", 0.0) for e in kept), default=0.0)
    r_mm = max((e.get("residual_trans_mm", 0.0) for e in kept), default=0.0)
    reasons, loop_reasons = [], []
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
            loop_reasons.append(f"the circle of successive views does not close: {c_deg:.2f} deg / {c_mm:.1f} mm over "
                                f"{n} edges ({pe_deg:.2f} deg / {pe_mm:.1f} mm per edge; limit {max_deg:g} deg / "
                                f"{max_mm:g} mm)")
    else:
        out.update(cycle_closure_deg=None, cycle_closure_mm=None, cycle_per_edge_deg=None, cycle_per_edge_mm=None)
    loops = loops or []
    bad = [lp for lp in loops if lp["per_edge_deg"] > max_deg or lp["per_edge_mm"] > max_mm]
    if bad:
        w = max(bad, key=lambda lp: max(lp["per_edge_deg"] / max_deg, lp["per_edge_mm"] / max_mm))
        loop_reasons.append(f"the loop closed by edge {w['edge'][0]}->{w['edge'][1]} ({w['n_edges']} edges) does not "
                            f"close: {w['closure_deg']:.2f} deg / {w['closure_mm']:.1f} mm ({len(bad)} failing loop(s) of "
                            f"{len(loops)})")
    reasons.extend(loop_reasons)
    out["loop_reasons"] = list(loop_reasons)
    out["loops"] = loops
    if selection is not None:
        out["selection"] = selection
        reasons.extend(selection.get("reasons", []))
    out["n_loops_verified"] = int(len(loops) - len(bad))
    out["reliable"] = not reasons
    out["reasons"] = reasons
    return out
