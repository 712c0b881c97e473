"""The registration stage: successive views registered pairwise into a pose graph, which is optimised.

:func:`register_views` owns the loop over pairs (with progress); the pair registration itself is
:func:`~tofmetry.reconstruct._register.register_pair`, the graph :class:`~tofmetry.reconstruct._posegraph.PoseGraphBuilder`.
The joint fit of all views (:mod:`tofmetry.reconstruct._adjust_stage`) refines what this stage returns.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._pattern_search import search_by_pattern
from tofmetry.reconstruct._posegraph import PoseGraphBuilder
from tofmetry.reconstruct._register import register_pair, rejection_reason
from tofmetry.reconstruct._regview import RegView
from tofmetry.reconstruct._select_stage import select_with_implied
from tofmetry.reconstruct._turntable_bridge import no_turn_error, turntable_bridges


@dataclass
class Registered:
    """What the registration stage found.

    Attributes
    ----------
    graph : the optimised pose graph (``poses`` (V', 4, 4) camera-to-world of the views kept, in the frame
        of the first kept view; ``edges``, ``consistency``)
    kept : indices of the views kept (those linked to the largest group of views)
    left_out : view name -> why it was left out of the model
    other_edges : the pairs of views left out, as dicts (``kept`` False, their verdict and reason)
    tied_starts : pose-graph poses of the choices tied with the chosen one (all views kept, no turntable)
    pattern : the edges the IR pattern searched again (:func:`search_by_pattern`), or None
    turntable : the declared turntable's axis fit and bridges (:func:`turntable_bridges`), or None
    """

    graph: object
    kept: list[int]
    left_out: dict[str, str] = field(default_factory=dict)
    other_edges: list[dict] = field(default_factory=list)
    tied_starts: list[np.ndarray] = field(default_factory=list)
    pattern: dict | None = None
    turntable: dict | None = None


def _successive_pairs(n: int) -> list[tuple[int, int]]:
    """The pairs of successive views, and last -> first (more than two views)."""
    return [(i, i + 1) for i in range(n - 1)] + ([(0, n - 1)] if n > 2 else [])


def _successive(pg: PoseGraphBuilder, regs: list[RegView], rc: RegistrationConfig, progress) -> set:
    """Successive pairs (and last -> first) with the global search; a failed successive pair is bridged
    by a global search to the view after next. Returns the pairs tried."""
    n = len(regs)
    succ = _successive_pairs(n)
    done = set()
    with progress("registering successive views", len(succ)) as adv:
        for i, j in succ:
            p = register_pair(regs[i], regs[j], i, j, rc)
            pg.add(p)
            done.add((i, j))
            if not p.accepted and j == i + 1:
                for a, b in ((i - 1, j), (i, j + 1)):
                    if 0 <= a < b < n and (a, b) not in done:
                        pg.add(register_pair(regs[a], regs[b], a, b, rc))
                        done.add((a, b))
            adv()
    return done


def _all_pairs(pg: PoseGraphBuilder, regs: list[RegView], rc: RegistrationConfig, done: set, progress) -> None:
    """Every pair not tried yet, ICP only from the chained poses (bounded jump)."""
    n = len(regs)
    chain = pg.chain_poses()
    rest = [(i, j) for i in range(n) for j in range(i + 1, n) if (i, j) not in done]
    with progress("loop closures (all pairs)", len(rest)) as adv:
        for i, j in rest:
            if np.isfinite(chain[i]).all() and np.isfinite(chain[j]).all():
                init = np.linalg.inv(chain[j]) @ chain[i]
                pg.add(register_pair(regs[i], regs[j], i, j, rc, init=init, global_search=False))
            adv()


def register_views(regs: list[RegView], names: list[str], rc: RegistrationConfig, progress) -> Registered:
    """Register the views into an optimised pose graph.

    Successive pairs (and last -> first) with the global search; a failed successive pair is
    bridged by a global search to the view after next; with ``rc.all_pairs`` every other pair is a
    loop-closure candidate seeded by the chained poses (ICP only, bounded jump; off by default: the
    joint fit matches all overlapping views afterwards). Global search between distant views is never
    used: a nearly symmetric object seen from opposite sides matches itself rotated by 180 degrees.

    Views that no accepted registration links to the largest group of views are left out of the
    model (with the reason); it raises only when no two views register.

    Parameters
    ----------
    regs : per view, its registration cloud (:func:`~tofmetry.reconstruct._regview.make_reg_view`)
    names : the views' names, in the order of ``regs``
    rc : the registration stage's configuration
    progress : callable(description, total) -> context manager yielding ``advance(n=1)``

    Returns
    -------
    Registered
    """
    n = len(regs)
    pg = PoseGraphBuilder(n, names)
    pg.centres = np.array([r.obj_points.mean(0) if len(r.obj_points) else np.zeros(3) for r in regs])
    pg.ups = np.array([np.full(3, np.nan) if r.plane is None else np.asarray(r.plane[:3], np.float64) for r in regs])
    done = _successive(pg, regs, rc, progress)
    pattern = turntable = None
    if rc.pattern_search and rc.turntable_step_deg is None:  # a declared turntable's turns place the views
        with progress("edges the IR pattern contradicts", 1) as adv:
            pg.pairs, pattern = search_by_pattern(pg.pairs, regs, rc, names)
            adv()
    if rc.turntable_step_deg is not None:
        bridges, turntable = turntable_bridges(regs, pg.pairs, _successive_pairs(n), rc)
        if turntable:
            turntable["bridged"] = [[names[i], names[j], how] for i, j, how in turntable["bridged"]]
        new = {(b.source, b.target) for b in bridges}
        pg.pairs = [p for p in pg.pairs if (p.source, p.target) not in new] + bridges
    if rc.all_pairs:
        _all_pairs(pg, regs, rc, done, progress)
    select_with_implied(pg, regs, rc)
    keep = pg.components()[0]
    if len(keep) < 2 and rc.turntable_step_deg is not None:
        raise no_turn_error(rc.turntable_step_deg, rc.turntable_tol_deg, n)
    if len(keep) < 2:
        pg.check_connected()  # raises, naming the groups of views and the rejected pairs
    left_out, other_edges = {}, []
    if len(keep) < n:
        for k in range(n):
            if k not in keep:
                tried = [p for p in pg.pairs if k in (p.source, p.target)]
                why = "; ".join(f"{names[p.source]}->{names[p.target]} {rejection_reason(p, rc)}" for p in tried)
                left_out[names[k]] = ("no accepted registration links it to the other views: "
                                      + (why or "no pair tried"))
        other_edges = [p.to_dict(names) | {"kept": False, "verdict": "left out with its view",
                                           "reason": rejection_reason(p, rc)}
                       for p in pg.pairs if not (p.source in keep and p.target in keep)]
        pg = pg.subgraph(keep)
    graph = pg.optimize(rc.icp_radii_mm[-1] * 1e-3, rc.edge_prune, rc.gate_max_deg, rc.gate_max_mm)
    # the choices tied with the chosen one, for the joint fit to decide between (all views kept only;
    # a declared turntable places the views itself)
    tied = [] if len(keep) < n or turntable else pg.tied_poses(rc.icp_radii_mm[-1] * 1e-3, rc.edge_prune)
    for d, p in zip(graph.edges, pg.pairs):  # why a pair failed, with its figures and the gates
        if not p.accepted:
            d["reason"] = rejection_reason(p, rc)
    return Registered(graph, keep, left_out, other_edges, tied, pattern, turntable)
