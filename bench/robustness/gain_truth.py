"""The depth gain a wall calibration truly leaves against what its folds predict, over family sensors.

``.venv/bin/python -m bench.robustness.gain_truth --seeds S1,S2 [--stations family,dense] [--span 150]``

For each seed's sensor (:func:`tofmetry.simulate.family.random_sensor`, the family's for that seed) and
each station set (:data:`bench.robustness.family.STATION_SETS`), the sensor is calibrated as the
family does (:func:`bench.robustness.family.calibrate_sensor`, no tilt boards), then noise-free walls
every 25 mm over 0.55-1.65 m are corrected by that calibration and compared with the true depth
(the mean over the image's central ninth). The gain it leaves is the least-squares slope of that
residual over windows of ``--span`` mm (the object's depth span) within 0.6-1.6 m, RMS over the
windows; it is printed beside :func:`tofmetry.reconstruct._calibration_support.calibration_gain_sigma`
without and with that span. The residual's RMS shows its size.
"""

from __future__ import annotations

import argparse

import numpy as np

from bench.robustness.family import STATION_SETS, calibrate_sensor
from tofmetry.calibrate import apply_depth_calibration
from tofmetry.reconstruct._calibration_support import calibration_gain_sigma
from tofmetry.simulate.family import random_sensor
from tofmetry.simulate.walls import wall_station_means


def residual_curve(sensor, cal, distances_mm) -> np.ndarray:
    """(S, 2): true depth [mm] at the image's central ninth and the calibrated depth's mean error there [mm]."""
    clean = sensor.with_errors(sensor.errors.without("noise", "warmup", "flying", "invalid"))
    out = []
    for st in wall_station_means(clean, distances_mm, 1, seed=5):
        H, W = st.mean_mm.shape
        win = (slice(H // 3, 2 * H // 3), slice(W // 3, 2 * W // 3))
        m = st.mean_mm[win]
        ok = np.isfinite(m)
        err = apply_depth_calibration(np.where(np.isfinite(st.mean_mm), st.mean_mm, 0.0), cal)[win] - st.true_depth_mm[win]
        out.append((float(np.mean(st.true_depth_mm[win])), float(np.mean(err[ok]))))
    return np.array(out)


def window_slopes(curve: np.ndarray, span_mm: float, lo: float = 600.0, hi: float = 1600.0) -> np.ndarray:
    """Least-squares slopes of the residual over windows of ``span_mm`` centred every 25 mm within lo-hi."""
    z, e = curve[:, 0], curve[:, 1]
    g = []
    for c in np.arange(lo + span_mm / 2, hi - span_mm / 2 + 1, 25.0):
        k = np.abs(z - c) <= span_mm / 2
        if k.sum() >= 3:
            g.append(np.polyfit(z[k], e[k], 1)[0])
    return np.array(g)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--stations", default="family,dense")
    ap.add_argument("--span", type=float, default=150.0, help="object depth span [mm]")
    a = ap.parse_args(argv)
    print("seed stations | truth: residual RMS [mm], gain RMS [%] | predicted gain [%]: by the spacing, with the span")
    for seed in (int(s) for s in a.seeds.split(",")):
        sensor = random_sensor(seed)
        for st in a.stations.split(","):
            cal, _, _ = calibrate_sensor(sensor, seed, distances_mm=STATION_SETS[st])
            curve = residual_curve(sensor, cal, list(range(550, 1651, 25)))
            g = window_slopes(curve, a.span)
            p0 = calibration_gain_sigma(cal.prediction)
            p1 = calibration_gain_sigma(cal.prediction, (1000.0 - a.span / 2, 1000.0 + a.span / 2))
            t = float(np.sqrt(np.mean(g ** 2)))
            print(f"{seed} {st:6s} | {np.sqrt(np.mean(curve[:, 1] ** 2)):.2f} mm, {100 * t:.3f} % | "
                  f"{100 * p0:.3f} % ({p0 / t:.1f}x), {100 * p1:.3f} % ({p1 / t:.1f}x)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
