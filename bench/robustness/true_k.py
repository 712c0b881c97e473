"""The family with the amplitude-bias coefficient set to the sensor's own (an oracle; a diagnostic).

``OMP_NUM_THREADS=1 PYTHONPATH=$PWD .venv/bin/python -m bench.robustness.true_k --seeds S1,... --mat --planned 0.9 --plan-distance -o DIR``

Runs :mod:`bench.robustness.family` (same arguments) with the preprocessing's ``k`` (what the grey-level boards
measured, :func:`tofmetry.pipelines.reconstruct.with_measured_amplitude_slope`) replaced by the simulated sensor's
true coefficient; the rows still report the boards' reading (``amplitude_slope``) beside ``true_k_mm_per_ln``. It
changes no code path of tofmetry but that one function as the pipeline sees it.

Measured (2026-12-06, session 57) on the 15 runs of held-out draws 113-115 whose placements stood unrefined, against
their stored rows (``bench/results/object_family_dev113_115_true_k_rows.jsonl``): the placements' lift in the mat's
frame (:mod:`bench.robustness.mat_sight`) +0.306 -> +0.306 mm up and +0.341 -> +0.343 mm out (mean over the runs), the
models' mean signed deviation +0.168 -> +0.170 mm, |scale| p90 0.436 -> 0.433 % (5 -> 4 of 13 beyond 0.2 %). The
lift's correlation with the boards' k error (-0.72 over 120 runs) is not the correction's doing: with the true k
the lift stays.
"""

from __future__ import annotations

import sys

import tofmetry.pipelines.reconstruct as _reconstruct
from bench.robustness import family


def main(argv=None) -> int:
    calibrate, measured = family.calibrate_sensor, _reconstruct.with_measured_amplitude_slope
    true = {}  # the coefficient of the draw being run

    def calibrate_sensor(sensor, *args, **kwargs):  # the draw's sensor: its true coefficient
        true["k"] = sensor.errors.amplitude_slope_mm_per_ln()
        return calibrate(sensor, *args, **kwargs)

    def with_true_slope(config, slope):
        cfg = measured(config, slope)
        cfg.preprocess.amplitude_k_mm_per_ln = true["k"]
        return cfg

    family.calibrate_sensor = calibrate_sensor
    _reconstruct.with_measured_amplitude_slope = with_true_slope
    return family.main(argv)


if __name__ == "__main__":
    sys.exit(main())
