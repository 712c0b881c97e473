"""The multi-view choice of registration hypotheses, with the hypotheses the scan itself implies.

:meth:`~tofmetry.reconstruct._posegraph.PoseGraphBuilder.select_hypotheses` chooses one hypothesis
per edge so that every loop closes and the cameras walk around the object in scan order. Where it
had to drop an edge, the pairs of that edge's loop are registered again from the pose the loop
implies (:mod:`tofmetry.reconstruct._loop_implied`); where the cameras of its choice still step
back or leap, the pairs at those steps are registered again from the pose the path's other steps
imply (:mod:`tofmetry.reconstruct._path_implied`). Each retry is kept only where the choice then
improves (fewer edges dropped; fewer steps that do not walk), and the selection report names the
pairs so registered (``loop_implied``, ``path_implied``).
"""

from __future__ import annotations

from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._loop_implied import METHOD as LOOP_IMPLIED, loop_implied_hypotheses
from tofmetry.reconstruct._path_implied import METHOD as PATH_IMPLIED, path_implied_hypotheses
from tofmetry.reconstruct._posegraph import PoseGraphBuilder
from tofmetry.reconstruct._register import register_pair
from tofmetry.reconstruct._regview import RegView


def select_with_implied(pg: PoseGraphBuilder, regs: list[RegView], rc: RegistrationConfig) -> None:
    """Choose the hypotheses of ``pg`` (in place: ``pg.pairs``, ``pg.selection``), retrying with the
    loop- and the path-implied hypotheses (module docstring)."""
    names = pg.names

    def select() -> dict:
        return pg.select_hypotheses(rc.gate_max_deg, rc.gate_max_mm, rc.ambiguity_margin,
                                    spread_deg=rc.spread_max_deg, spread_mm=rc.spread_max_mm,
                                    path_max_ratio=rc.path_max_step_ratio, path_margin=rc.path_fitness_margin)

    def register(i: int, j: int, init):
        return register_pair(regs[i], regs[j], i, j, rc, init=init, global_search=False)

    def register_turn(i: int, j: int, step_deg: float, tol_deg: float):
        c = rc.model_copy(update={"turntable_step_deg": step_deg, "turntable_tol_deg": tol_deg})
        return register_pair(regs[i], regs[j], i, j, c)

    def retry(first: dict, pairs: list, found: list[dict], method: str, key: str, count: str, entry) -> dict:
        """Select again from ``pairs``; kept (and returned) where it resolves, has fewer of the report's
        ``count`` and chose a hypothesis tagged ``method`` (named under ``key``, with ``entry(f)``);
        else the selection ``first`` is restored (and returned)."""
        chosen, tied = list(pg.pairs), pg.tied
        pg.pairs = pairs
        again = select()
        now = {(q.source, q.target): (q.method, round(float(q.fitness), 4)) for q in pg.pairs if q.accepted}
        took = [f for f in found if now.get(tuple(f["edge"])) == (method, f["fitness"])]  # the hypothesis chosen
        if again.get("resolved") and len(again.get(count, [])) < len(first[count]) and took:
            again[key] = [{"edge": f"{names[f['edge'][0]]}->{names[f['edge'][1]]}", "fitness": f["fitness"],
                           "replaced_fitness": f["kept_fitness"], **entry(f)} for f in took]
            if first.get("loop_implied"):
                again.setdefault("loop_implied", first["loop_implied"])
            return again
        pg.pairs, pg.selection, pg.tied = chosen, first, tied
        return first

    before = list(pg.pairs)
    first = select()
    if first.get("dropped") and rc.loop_implied_min_gain is not None:
        pairs, found = loop_implied_hypotheses(len(regs), before, list(pg.pairs), register, rc.loop_implied_min_gain)
        if found:
            kept = retry(first, pairs, found, LOOP_IMPLIED, "loop_implied", "dropped",
                         lambda f: {"implied_by": f"{names[f['implied_by'][0]]}->{names[f['implied_by'][1]]}"})
            if kept is not first:
                before, first = pairs, kept
    if not first.get("path_steps") or rc.path_max_step_ratio is None or pg.centres is None:
        return
    pairs, found = path_implied_hypotheses(len(regs), before, list(pg.pairs), pg.centres, pg.ups, register_turn,
                                           rc.path_max_step_ratio, rc.path_fitness_margin)
    if found:
        retry(first, pairs, found, PATH_IMPLIED, "path_implied", "path_steps", lambda f: {"step_deg": f["step_deg"]})
