"""The family with the dot mat's placements never preferred to the joint fit (a diagnostic).

``OMP_NUM_THREADS=1 PYTHONPATH=$PWD .venv/bin/python -m bench.robustness.fit_kept --seeds S1,... --mat --planned 0.9 -o DIR``

On a mat, a scan's placements stand unrefined (the joint fit set aside) where the fit moved a view beyond the pose
gate plus the placements' own p99 and beyond its placement's reach (:func:`tofmetry.reconstruct._mat_stage.departures`;
the gate alone before session 52), or where the depth
calibration's residual could move the fit beyond the gate (:func:`~tofmetry.reconstruct._mat_stage.calibration_beyond_gate`).
This runs :mod:`bench.robustness.family` (same arguments) with both rules off, so that the rows show what the fit
would have given. It changes no code path of tofmetry but those two functions as the pipeline sees them.

Measured on held-out draw 103's 8 runs whose placements stood unrefined (session 51; rows
``bench/results/object_family_dev103_fit_kept_*``): where the fit moved a view just beyond the gate (two rocker arms,
3.1 and 3.2 mm) the kept fit was better (0.44 deg / 3.44 mm -> 0.16 deg / 0.47 mm, scale +0.67 -> -0.11 %; 2.31 ->
0.98 mm, +0.34 -> +0.09 %); where the calibration could move it, or the fit moved views 0.8-1.2 deg, it was worse on
4 of 6 (an igea 1.00 -> 3.16 mm and another 1.55 -> 8.36 mm, both then flagged; a baluster, a bunny), the same on a
bar, and mixed on a rocker arm (3.36 -> 2.71 mm at the object, 0.27 -> 0.58 deg). On the 21 runs of draws 96-102
whose placements stood unrefined, all because the calibration could move the fit beyond the gate (rows
``bench/results/object_family_dev96_102_fit_kept_*``, against their stored rows, made on the code of their draws): the
kept fit was worse on 15, better on 3 and the same on 3, and 6 runs became truly wrong (3 of them reliable: misses).
That rule holds; the departure rule was the one to refine (session 52: a departure now needs the gate plus
``_mat_stage.PLACEMENT_P99``, and the two rocker arms keep their fit).
"""

from __future__ import annotations

import sys

import tofmetry.reconstruct._pipeline as _pipeline
from bench.robustness import family


def main(argv=None) -> int:
    _pipeline.departures = lambda *a, **k: {}
    _pipeline.calibration_beyond_gate = lambda *a, **k: None
    return family.main(argv)


if __name__ == "__main__":
    sys.exit(main())
