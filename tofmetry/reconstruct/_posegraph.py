"""Pose graph over all accepted pairwise registrations, globally optimised (Open3D LM)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofmetry.errors import EstimationError
from tofmetry.reconstruct._register import PairResult


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation matrix [deg]."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R[:3, :3]) - 1) / 2, -1, 1))))


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

    def add(self, pair: PairResult) -> None:
        self.pairs.append(pair)

    def accepted(self) -> list[PairResult]:
        return [p for p in self.pairs if p.accepted]

    def chain_poses(self) -> np.ndarray:
        """Initial camera-to-world poses by a breadth-first walk over accepted edges from view 0."""
        poses = np.full((self.n, 4, 4), np.nan)
        poses[0] = np.eye(4)
        done = {0}
        changed = True
        while changed:
            changed = False
            for p in self.accepted():
                # T maps source -> target: pose_source = pose_target @ T
                if p.target in done and p.source not in done:
                    poses[p.source] = poses[p.target] @ p.transform
                elif p.source in done and p.target not in done:
                    poses[p.target] = poses[p.source] @ np.linalg.inv(p.transform)
                else:
                    continue
                done |= {p.source, p.target}
                changed = True
        return poses

    def check_connected(self) -> None:
        """Raise EstimationError naming the view groups when the accepted edges do not connect all views."""
        comps = connected_components(self.n, [(p.source, p.target) for p in self.accepted()])
        if len(comps) > 1:
            groups = "; ".join("{" + ", ".join(self.names[k] for k in c) + "}" for c in comps)
            worst = ", ".join(f"{self.names[p.source]}->{self.names[p.target]} fitness {p.fitness:.2f} rmse "
                              f"{p.inlier_rmse_mm:.1f} mm" for p in self.pairs if not p.accepted)[:600]
            raise EstimationError(
                f"registration graph is disconnected: {len(comps)} groups of views that do not overlap each other: "
                f"{groups}. No model is written. Rejected pairs: {worst}. Take views with more overlap "
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
            # successive views (and the loop closure of the circle) are "certain" odometry-like edges
            uncertain = abs(p.source - p.target) != 1
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
        return PoseGraphResult(poses, edges, consistency_gate(edges, self.cycle_closure(), gate_deg, gate_mm))


def consistency_gate(edges: list[dict], cycle: tuple[float, float, int] | None, max_deg: float = 2.0,
                     max_mm: float = 10.0) -> dict:
    """Is the optimised pose graph self-consistent? (the run is flagged unreliable otherwise)

    Two tests, both against (``max_deg``, ``max_mm``):

    * every *kept* edge: its pairwise transform vs the optimised relative pose (residual);
    * the circle of successive edges vs the direct first -> last edge, before optimisation,
      per edge: closure / sqrt(number of edges) (independent pairwise errors add up as a random
      walk). A symmetric object registered flipped, or depth with a scale error (raw data),
      leaves a circle that does not close.

    Edges pruned by the optimisation (line process) are counted but do not fail the gate: the
    solution does not use them.

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
    out["reliable"] = not reasons
    out["reasons"] = reasons
    return out
