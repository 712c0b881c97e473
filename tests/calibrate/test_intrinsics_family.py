"""IR intrinsics on a family of random Kinect-v2-class lenses, judged by the ray error.

A reduced version of ``bench/intrinsics_family.py`` (whose functions it uses): 8 lenses drawn with
``tofmetry.simulate.random_sensor`` (seeds drawn at random at every run and printed; set
``TOFMETRY_FAMILY_SEEDS="1 2 3"`` to replay), 8 rendered IR images each, calibrated by tofmetry
and, on the same images, by plain OpenCV (the textbook recipe, and two better set-ups of it).

Targets (issue: IR intrinsics at OpenCV's accuracy or better):
* ray error (RMS over the full image grid, corners included) <= 0.5 px at the family's p90;
* per lens, never worse than any OpenCV recipe beyond a tolerance of twice tofmetry's own
  predicted 1-sigma ray error (two equally good estimates from the same images differ by about
  sqrt(2) sigma);
* the predicted ray error (from the parameter covariance) is of the size of the true one.

Measured with ``python -m bench.intrinsics_family`` on 20 lenses x 15 images (medians, p90 in
brackets): tofmetry ray RMS 0.064 (0.093) px; OpenCV SB + cornerSubPix half cell 0.245 (0.336) px;
SB corners alone 0.62 (0.91) px; textbook 15 (94) px: its 11x11 window is wider than half the
18-30 px squares and jumps to neighbouring corners.
"""

from __future__ import annotations

import importlib.util
import os
import random
import sys
import time
from pathlib import Path

import numpy as np
import pytest

N_LENSES, N_IMAGES = 8, 8


def _bench():
    path = Path(__file__).resolve().parents[2] / "bench" / "intrinsics_family.py"
    spec = importlib.util.spec_from_file_location("_bench_intrinsics_family", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def family():
    env = os.environ.get("TOFMETRY_FAMILY_SEEDS")
    seeds = [int(s) for s in env.split()] if env else sorted(random.SystemRandom().sample(range(1, 2 ** 31 - 1),
                                                                                            N_LENSES))
    print(f"\nintrinsics family seeds: {' '.join(map(str, seeds))}", file=sys.stderr)
    b = _bench()
    t0 = time.perf_counter()
    rows = [b.evaluate_lens(s, N_IMAGES) for s in seeds]
    return b, seeds, rows, time.perf_counter() - t0


def _fmt(rows, key):
    return ", ".join(f"{r['seed']}: {r[key].get('rms_px', float('nan')):.3f}" for r in rows)


def test_family_ray_error_target(family):
    b, seeds, rows, seconds = family
    tof = np.array([r["tofmetry"]["rms_px"] for r in rows])
    corners = np.array([r["tofmetry"]["corners_max_px"] for r in rows])
    msg = f"seeds {seeds}; tofmetry ray RMS per lens {_fmt(rows, 'tofmetry')}"
    # every image of these sets shows a whole board: all are detected and kept
    assert all(r["tofmetry"]["detected"] >= N_IMAGES - 1 for r in rows), msg
    # target 0.5 px at p90. Measured with 8 images: median 0.08, p90 0.22 px; with 15: 0.06 / 0.13 px
    assert np.percentile(tof, 90) <= 0.5, msg
    # the image corners (10 % regions, extrapolated: no inner corner reaches them) stay below 1 px at
    # the median (measured 0.13-0.28 px; single lenses up to 4.6 px with 10 images, predicted 3.8 px)
    assert np.median(corners) <= 1.0, msg
    # corners: measured 0.02-0.04 px RMS against the true projections (3x better than cornerSubPix)
    assert np.median([r["tofmetry"]["corner_rms_px"] for r in rows]) < 0.06, msg
    print(b.table(rows, b.summarize(rows)), file=sys.stderr)
    print(f"family of {len(rows)} lenses x {N_IMAGES} images: {seconds:.0f} s", file=sys.stderr)


def test_family_never_worse_than_opencv(family):
    b, seeds, rows, _ = family
    for r in rows:
        tol = b.tolerance_px(r)
        for m in b.METHODS[1:]:
            if "rms_px" not in r[m]:          # OpenCV found fewer than 3 boards: nothing to beat
                continue
            assert r["tofmetry"]["rms_px"] <= r[m]["rms_px"] + tol, (
                f"seed {r['seed']}: tofmetry {r['tofmetry']['rms_px']:.3f} px vs {b.LABELS[m]} {r[m]['rms_px']:.3f} px "
                f"(tolerance {tol:.3f} px); all seeds {seeds}")
    # and better at the median than the best OpenCV set-up (measured: 0.06 against 0.22 px)
    best = np.median([r["opencv_sb_csp"]["rms_px"] for r in rows])
    assert np.median([r["tofmetry"]["rms_px"] for r in rows]) < best, f"seeds {seeds}"


def test_family_predicted_ray_error_has_the_right_size(family):
    b, seeds, rows, _ = family
    ratio = np.array([r["ratio_rms"] for r in rows])
    # one draw per lens of an error made of a few parameter modes: true / predicted scatters like
    # sqrt(chi2_k / k) with k ~ 3 (10-90 %: 0.3-1.5). Measured on 20 lenses: median 0.64,
    # p10 0.34, p90 1.45; since the renderer's n-rooks edge sampling: 0.87, p10 0.45, p90 1.50.
    # The prediction must be of the right size: median within 0.3-2
    assert 0.3 < np.median(ratio) < 2.0, f"seeds {seeds}: ratios {np.round(ratio, 2)}"
    assert ratio.max() < 5.0, f"seeds {seeds}: ratios {np.round(ratio, 2)}"
