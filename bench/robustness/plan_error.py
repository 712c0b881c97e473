"""How far ``tofmetry plan``'s predicted completeness lies from what stored family runs achieved,
under the plan's rule and under other single-view chances.

Each right, reliable run of the given row files (``bench/results/object_family_*_rows.jsonl``) is
rebuilt from its seed: the object, and the views as the family drew them (``--planned`` paths
re-planned as they were). Its views' incidences are computed once; the prediction is then evaluated
for every chance in ``--single-view`` (:func:`tofmetry.plan.reconstructed_share`) against the
completeness the run achieved. The rows were written under the rule before 2026-12-02 (a
single-view chance of 1): ``--planned`` paths are re-planned under it, and a run is used only when
the prediction under it reproduces the row's stored prediction, so that the rebuilt views are the
run's.

Usage::

    python -m bench.robustness.plan_error --set mat=ROWS1,ROWS2 --set chain=ROWS3 [--single-view 1,0.9,0.85] [--fit]

Prints per set and chance: mean, p5, p95, p90 of |error| and the share within 5 points (prediction
minus achieved, in points), the worst run; ``--fit``: the chance that minimises each set's squared
error (grid 0.70-1.00), and each fit judged on the other sets.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from bench.robustness.family import MESH_DIR, draw_case
from tofmetry.plan import PlanObject, predict, reconstructed_share, seen_cosines
from tofmetry.plan._plan import GRAZING_KEEP, SURE_INCIDENCE_DEG


#: the plan's prediction as the stored rows were planned: a single-view chance of 1 (before 2026-12-02)
RULE_BEFORE_2026_12_02 = {"single_view": 1.0}


def rebuilt_runs(paths: list[str], planned: bool = True) -> list[dict]:
    """The right, reliable runs of ``paths`` whose views rebuild: their incidence cosines (V, N), the
    achieved completeness, seed and object."""
    out = []
    for p in paths:
        for line in Path(p).read_text().splitlines():
            r = json.loads(line)
            if not r.get("reliable") or r.get("truly_wrong") or r.get("plan_error_pts") is None:
                continue
            kind = r["path"]["kind"]
            if "+planned" in kind or ("+plan" in kind and not planned):
                continue
            target = r["path"].get("plan_target") if "+plan" in kind else None
            d = draw_case(r["seed"], MESH_DIR, False, None, target, plan_kw=RULE_BEFORE_2026_12_02)
            obj = PlanObject(d.object.vertices, d.object.triangles, "mesh")
            cos = seen_cosines(obj, d.path.poses, d.sensor.intrinsics, grazing_limit_deg=GRAZING_KEEP[-1][0])
            old = float(reconstructed_share(cos, SURE_INCIDENCE_DEG, GRAZING_KEEP, **RULE_BEFORE_2026_12_02).mean())
            if abs(old - r["plan_completeness"]) > 2e-4:
                print(f"  {Path(p).name} {r['seed']}: views not rebuilt ({old:.4f} vs {r['plan_completeness']}), left out")
                continue
            assert abs(predict(obj, d.path.poses, d.sensor.intrinsics, cosines=cos).completeness
                       - float(reconstructed_share(cos).mean())) < 1e-9
            out.append({"cos": cos, "achieved": r["completeness"], "seed": r["seed"], "object": r["object"]["name"],
                        "distance_m": r["path"]["distance_m"]})
    return out


def errors_pts(runs: list[dict], single_view: float) -> np.ndarray:
    """Predicted minus achieved completeness [points] per run."""
    return np.array([100 * (float(reconstructed_share(r["cos"], single_view=single_view).mean()) - r["achieved"])
                     for r in runs])


def line(name: str, runs: list[dict], q: float) -> str:
    e = errors_pts(runs, q)
    w = int(np.argmax(np.abs(e)))
    return (f"{name:<10} q={q:.2f}  n={len(e):3d}  mean {e.mean():+.2f}  p5 {np.percentile(e, 5):+.2f}  "
            f"p95 {np.percentile(e, 95):+.2f}  |e| p90 {np.percentile(np.abs(e), 90):.2f}  "
            f"within 5: {np.mean(np.abs(e) <= 5):.3f}  worst {e[w]:+.2f} ({runs[w]['object']} {runs[w]['seed']}, "
            f"{runs[w]['distance_m']:.2f} m)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", action="append", required=True, metavar="NAME=ROWS,ROWS",
                    help="a named set of row files (repeat)")
    ap.add_argument("--single-view", default="1,0.9", help="chances to judge, comma-separated")
    ap.add_argument("--fit", action="store_true", help="fit the chance on each set, judge it on the others")
    ap.add_argument("--no-planned", action="store_true", help="leave out runs along the plan's views")
    a = ap.parse_args(argv)
    sets = {}
    for s in a.set:
        name, files = s.split("=", 1)
        sets[name] = rebuilt_runs(files.split(","), not a.no_planned)
    qs = [float(x) for x in a.single_view.split(",")]
    for name, runs in sets.items():
        for q in qs:
            print(line(name, runs, q))
    if len(sets) > 1:
        every = [r for runs in sets.values() for r in runs]
        for q in qs:
            print(line("all", every, q))
    if a.fit:
        grid = np.round(np.arange(0.70, 1.0001, 0.01), 2)
        for name, runs in sets.items():
            q = float(grid[np.argmin([np.sum(errors_pts(runs, g) ** 2) for g in grid])])
            print(f"fitted on {name}: {q:.2f}")
            for other, ro in sets.items():
                if other != name:
                    print("   " + line(other, ro, q))


if __name__ == "__main__":
    main()
