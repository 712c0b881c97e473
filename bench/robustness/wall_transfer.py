"""How well the range error a support shows below an object carries over to the object: in Z, or in the ray length.

``OMP_NUM_THREADS=1 PYTHONPATH=$PWD .venv/bin/python -m bench.robustness.wall_transfer --seeds S1,S2,... -o DIR``

A diagnostic of the support curve's variable (``preprocess.support_curve_variable``). Per seed, the family's sensor is
calibrated as the family does (:func:`bench.robustness.family.calibrate_sensor`, tilt boards left out), then
fronto-parallel walls every 5 mm over 550-1500 mm are rendered without noise and corrected: the residual the
calibration leaves at every pixel and depth. The object stands at the image's centre (``|x|, |y| < 0.1``); the support
at its depths is seen on the rows below it. Per band of rows, the band's residual is carried to the centre

* in Z: the band's median residual at each wall's Z, read at the same Z;
* in the ray length: each pixel's residual at its ray length ``Z sqrt(1 + x^2 + y^2)``, binned, read at the
  centre's ray length;

and the slope each gives over 150 mm windows (an object's depth) centred every 25 mm over 700-1250 mm is set against
the centre's own. Per seed (``rows.jsonl``): the sensor's range variable and how its error reaches Z (the
simulator's ``range_variable`` / ``range_apply``), the centre's own slope RMS [%] (what no curve leaves), and per
band the RMS of the slope error carried in Z and in the ray length [%].

Measured (2026-12-07, session 62) on eleven development sensors (``bench/results/wall_transfer_dev_rows.jsonl``):
on the nine whose range error is a function of the ray length, carried in the ray length the slope error fell or
stayed on every band (the rows 0.25-0.45 below the centre: median 0.130 -> 0.034 % RMS, fandisk 1301630555's 0.223
-> 0.018 %); on the two whose error is in Z it rose there (0.071 -> 0.081 and 0.124 -> 0.157 %). End to end the
support curve's variable moved the models' scale far less (``preprocess.support_curve_variable``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from bench.robustness import family
from tofmetry._shared.geometry import ray_factor
from tofmetry.simulate import scenes
from tofmetry.simulate.family import random_sensor

#: the object's image region and the support's bands of rows below it, on normalised rays (x, y)
CENTRE = (0.1, 0.1)
BANDS = {"cols_y0.10-0.25": lambda x, y: (np.abs(x) < 0.1) & (y > 0.1) & (y < 0.25),
         "cols_y0.25-0.45": lambda x, y: (np.abs(x) < 0.1) & (y > 0.25) & (y < 0.45),
         "wide_y0.10-0.45": lambda x, y: (np.abs(x) < 0.6) & (y > 0.1) & (y < 0.45)}
WALLS_MM = np.arange(550.0, 1500.0, 5.0)
WINDOW_CENTRES_MM = np.arange(700.0, 1251.0, 25.0)


def window_slopes_pct(curve: np.ndarray, z_mm: np.ndarray, half_mm: float = 75.0) -> np.ndarray:
    """The slope [%] of ``curve`` [mm] over ``z_mm`` in windows of +-``half_mm`` about :data:`WINDOW_CENTRES_MM`."""
    out = []
    for c in WINDOW_CENTRES_MM:
        m = (z_mm >= c - half_mm) & (z_mm <= c + half_mm)
        out.append(100.0 * np.polyfit(z_mm[m], curve[m], 1)[0])
    return np.array(out)


def residuals(seed: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """(walls, H, W) noise-free residual [mm] of the calibrated sensor of ``seed``, the normalised rays (H, W, 2) and
    the sensor's range-error form."""
    draw = random_sensor(seed)
    cal, _, _ = family.calibrate_sensor(draw, seed)
    cam = draw.camera(seed)
    out = []
    for z in WALLS_MM:
        rd = cam.render(scenes.wall(z / 1000.0))
        measured = rd.depth0 + cam.systematic_mm(rd)
        corr, _ = cal.correction(measured)
        out.append(np.where(rd.depth0 > 0, measured - corr - rd.true_depth, np.nan))
    em = draw.errors
    return np.array(out), np.asarray(draw.intrinsics.ray_table(True)), {"variable": em.range_variable,
                                                                         "apply": em.range_apply}


def transfer(seed: int) -> dict:
    """The row of ``seed`` (module docstring)."""
    R, rays, form = residuals(seed)
    x, y = rays[..., 0], rays[..., 1]
    rho = ray_factor(rays)
    centre = (np.abs(x) < CENTRE[0]) & (np.abs(y) < CENTRE[1])
    own = window_slopes_pct(np.nanmedian(R[:, centre], axis=1), WALLS_MM)
    rho_c = float(np.median(rho[centre]))
    row = {"seed": int(seed), **form, "centre_slope_rms_pct": round(float(np.sqrt(np.mean(own ** 2))), 4)}
    bins = np.arange(500.0, 1700.0, 5.0)
    mid = 0.5 * (bins[1:] + bins[:-1])
    for name, band in BANDS.items():
        msk = band(x, y)
        in_z = window_slopes_pct(np.nanmedian(R[:, msk], axis=1), WALLS_MM)
        r = (WALLS_MM[:, None] * rho[msk][None, :]).ravel()
        v = R[:, msk].ravel()
        ok = np.isfinite(v)
        idx = np.digitize(r[ok], bins)
        med = np.array([np.median(v[ok][idx == i]) if (idx == i).sum() > 20 else np.nan for i in range(1, len(bins))])
        good = np.isfinite(med)
        in_r = window_slopes_pct(np.interp(WALLS_MM * rho_c, mid[good], med[good]), WALLS_MM)
        row[name] = {"rho": round(float(np.median(rho[msk])), 4),
                     "slope_error_z_rms_pct": round(float(np.sqrt(np.mean((own - in_z) ** 2))), 4),
                     "slope_error_ray_rms_pct": round(float(np.sqrt(np.mean((own - in_r) ** 2))), 4)}
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True, help="comma-separated seeds")
    ap.add_argument("-o", "--output", type=Path, default=Path("bench/results"))
    args = ap.parse_args(argv)
    args.output.mkdir(parents=True, exist_ok=True)
    path = args.output / "rows.jsonl"
    for s in (int(v) for v in args.seeds.split(",")):
        row = transfer(s)
        with open(path, "a") as fh:
            fh.write(json.dumps(row) + "\n")
        bands = "  ".join(f"{k}: Z {v['slope_error_z_rms_pct']:.3f} / ray {v['slope_error_ray_rms_pct']:.3f} %"
                          for k, v in row.items() if isinstance(v, dict))
        print(f"{s} {row['variable']}/{row['apply']} centre {row['centre_slope_rms_pct']:.3f} %  {bands}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
