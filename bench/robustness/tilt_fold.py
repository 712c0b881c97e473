"""The depth tilt left after the fold, under each folding rule, against what the walls left.

``PYTHONPATH=$PWD .venv/bin/python -m bench.robustness.tilt_fold ROWS.jsonl [ROWS.jsonl ...]``

Reads family rows (:mod:`bench.robustness.family`) whose tilt fit carries its held-out check
(``carried``), recomputes the truth with :func:`bench.robustness.family.residual_tilt_mm` at the
fit's distance, and prints, per rule, the RMS (x / y) of the tilt left in the calibration, the p90
and largest of its size, and how many sensors keep more than 2 mm per unit [mm per unit of x / z].
Rules: nothing folded; the whole fit when the held-out error confirms it (the rule until 4a1a76c);
every uncontradicted fit shrunk by ``t^2 / (t^2 + sigma^2)`` (:attr:`tofmetry.calibrate.TiltFit.shrink`,
the rule since); every fit whole. ``contradicted`` is recomputed from the check's figures where a
row predates that key. Rows of code before 8f62e64 (draws 30-31) have a sigma without the
systematic part (``SYSTEMATIC_MM`` of :mod:`tofmetry.calibrate`'s tilt fit, 1.2 mm per unit):
pass ``--add-systematic 1.2`` for them.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from bench.robustness.family import residual_tilt_mm
from tofmetry.calibrate import tilt_contradicted
from tofmetry.simulate.family import random_sensor


def _cases(paths, add_systematic: float):
    for p in paths:
        for line in open(p):
            r = json.loads(line)
            t = (r.get("calibration") or {}).get("tilt") or {}
            h = t.get("held_out") or {}
            if h.get("carried") is None:
                continue
            tt, sg = np.array(t["tilt_mm"]), np.array(t["sigma_mm"])
            sg = np.hypot(sg, add_systematic)
            f, sf = h["carried"], h["carried_se"]
            contra = h.get("contradicted")
            if contra is None:  # rows from before the key: held_out_check's rule on their figures
                contra = tilt_contradicted(f, sf, tt, sg)
            true = np.array(residual_tilt_mm(random_sensor(r["seed"]), t["z_ref_mm"]))
            yield tt, sg, true, contra, h["rms_mm"] < h["rms_none_mm"] and not contra


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+")
    ap.add_argument("--add-systematic", type=float, default=0.0, metavar="MM",
                    help="added in quadrature to the rows' sigma (1.2 for rows of code before 8f62e64)")
    a = ap.parse_args(argv)
    cases = list(_cases(a.rows, a.add_systematic))
    rules = {"nothing": lambda tt, sg, c, cf: np.zeros(2),
             "whole when confirmed": lambda tt, sg, c, cf: np.full(2, float(cf)),
             "shrunk unless contradicted": lambda tt, sg, c, cf: (not c) * tt ** 2 / (tt ** 2 + sg ** 2),
             "whole, always": lambda tt, sg, c, cf: np.ones(2)}
    print(f"{len(cases)} sensors ({sum(c for _, _, _, c, _ in cases)} contradicted)")
    for name, w in rules.items():
        left = np.array([true - w(tt, sg, c, cf) * tt for tt, sg, true, c, cf in cases])
        n = np.linalg.norm(left, axis=1)
        print(f"{name:>28}: left RMS {np.sqrt((left ** 2).mean(0)).round(2).tolist()}, size p90 "
              f"{np.percentile(n, 90):.2f}, max {n.max():.2f}, above 2: {int((n > 2).sum())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
