"""The depth tilt the dot mat measured, against the tilt the family's sensor truly left.

``reconstruct --mat`` measures the depth's tilt across the image from the dots
(:mod:`tofmetry.reconstruct._mat_tilt`, ``diagnostics.mat_depth_tilt``, kept in the family's rows as
``mat_depth_tilt``). The truth is the sensor's: the least-squares plane over the image of its whole
per-pixel deformation at the scan's distance, less the tilt its calibration folded in from boards
(:func:`bench.robustness.family.tilt_left_mm`; rows written since session 38 carry it as
``calibration.tilt_left_true_mm``). The mat sees the deformation where the sheet lies in each view,
not over the whole image, so a sensor with a strong non-linear deformation can read a local tilt
that differs from the truth's plane; the per-seed lines say which.

Usage::

    PYTHONPATH=$PWD python -m bench.robustness.mat_tilt bench/results/object_family_fresh80_mat_planned_rows.jsonl
"""

from __future__ import annotations

import argparse
import glob
import json

import numpy as np

from bench.robustness.family import tilt_left_mm


def tilt_rows(paths: list[str]) -> list[dict]:
    """One dict per row with a measured tilt: seed, object, truth, measured, its sigma, applied, z-scores."""
    from tofmetry.simulate.family import random_sensor

    out = []
    for pattern in paths:
        for f in sorted(glob.glob(pattern)):
            for line in open(f, encoding="utf-8"):
                r = json.loads(line)
                mt = r.get("mat_depth_tilt")
                if not mt:
                    continue
                cal = r["calibration"]
                true = cal.get("tilt_left_true_mm") or tilt_left_mm(
                    random_sensor(r["seed"]), cal["tilt"] if cal.get("tilt_folded") else None,
                    1e3 * r["path"]["distance_m"])
                m, s = np.array(mt["measured_mm"]), np.array(mt["measured_sigma_mm"])
                a = np.array(mt["applied_mm"])
                out.append({"seed": r["seed"], "object": r["object"]["name"], "true": np.array(true), "measured": m,
                            "sigma": s, "applied": a, "prior": mt["prior_sigma_mm"], "chi2": mt["chi2_per_dof"],
                            "z": (m - np.array(true)) / s, "left_before": np.linalg.norm(true),
                            "left_after": float(np.linalg.norm(np.array(true) - a))})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rows", nargs="+", help="family rows (.jsonl, globs allowed)")
    rows = tilt_rows(ap.parse_args(argv).rows)
    if not rows:
        print("no row carries mat_depth_tilt")
        return 1
    for r in rows:
        print(f"{r['seed']:>10} {r['object'][:10]:<10} true ({r['true'][0]:+6.2f}, {r['true'][1]:+6.2f})  measured "
              f"({r['measured'][0]:+6.2f}, {r['measured'][1]:+6.2f}) +- ({r['sigma'][0]:.2f}, {r['sigma'][1]:.2f})  "
              f"z ({r['z'][0]:+.1f}, {r['z'][1]:+.1f})  prior {r['prior']:.1f}  applied ({r['applied'][0]:+.2f}, "
              f"{r['applied'][1]:+.2f})  |left| {r['left_before']:.2f} -> {r['left_after']:.2f}  chi2 {r['chi2']:.2f}")
    z = np.array([r["z"] for r in rows])
    before = np.array([r["left_before"] for r in rows])
    after = np.array([r["left_after"] for r in rows])
    print(f"{len(rows)} runs: z RMS (x, y) {np.sqrt(np.mean(z ** 2, 0)).round(2).tolist()}, within 2 sigma "
          f"{(np.abs(z) < 2).mean(0).round(2).tolist()}; |tilt left| RMS {np.sqrt(np.mean(before ** 2)):.2f} -> "
          f"{np.sqrt(np.mean(after ** 2)):.2f} mm per unit, worse after on {int((after > before).sum())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
