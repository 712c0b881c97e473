"""The depth calibration on a family of random sensors, judged at stations it never saw.

Seeds are drawn at random on every run and printed (pin them with ``TOFMETRY_FAMILY_SEEDS=1,2,3``
to reproduce a run); nothing here is tuned to one sensor. The full family (>= 20 sensors, 50
frames) is ``python -m bench.depth_family``; CI runs a reduced one (5 sensors, 20 frames per
station).

Targets (the accuracy issue): at held-out stations the central deviation stays within 1.5 mm and
the systematic per-pixel error falls >= 4x (or to a floor no user could see), at the median and the
90th percentile (tested as a share of the stations, with a 25-station sample's binomial slack); each
calibration's own predicted error holds. Some draws of the family have a range error that is a
function of Z with a period shorter than twice the station spacing: no station between two
others can see it, so no method calibrates it between stations. The calibration must then say
so (its prediction warns); the targets are asked of the sensors it vouches for.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from scipy.stats import binom

from tofmetry.pipelines.depth_family import SHAPE_FLOOR_MM, evaluate_sensor, summarize_family
from tofmetry.simulate.family import random_sensor

N_SENSORS, N_FRAMES = 5, 20
SPACING_MM = 250.0  # of the training stations (tofmetry.simulate.walls.DEFAULT_DISTANCES_MM)


def _unobservable(seed: int) -> bool:
    """Truth: a range error of Z with a component (or harmonic) of at least 1 mm whose period is
    shorter than twice the station spacing (the sampling limit of stations on the axis)."""
    re = random_sensor(seed).describe()["range_error"]
    return re["variable"] == "z" and any(c["period_m"] * 1000 / k < 2 * SPACING_MM and a >= 1.0
                                         for c in re["components"] for k, a in enumerate(c["amplitudes_mm"], 1))


@pytest.fixture(scope="module")
def family():
    env = os.environ.get("TOFMETRY_FAMILY_SEEDS")
    seeds = [int(s) for s in env.split(",")] if env else \
        [int(s) for s in np.random.default_rng().integers(0, 2**31 - 1, N_SENSORS)]
    print(f"\ndepth family seeds: TOFMETRY_FAMILY_SEEDS={','.join(map(str, seeds))}")
    results = [evaluate_sensor(s, n_frames=N_FRAMES) for s in seeds]
    for r in results:
        print(r.seed, r.model, "warned" if r.warnings else "", [round(x["central_true_mm"], 2) for x in r.rows])
    return results


def _allowed_misses(n: int, share: float = 0.1, alpha: float = 0.01) -> int:
    """Most stations out of ``n`` that may miss a target met by ``1 - share`` of the family's
    stations: the largest k with P(Binomial(n, share) >= k) >= alpha (5 random sensors are a small
    sample of the family; a test of "90 % of stations" must not fail on sampling alone)."""
    k = 0
    while binom.sf(k, n, share) >= alpha:  # sf(k) = P(X > k) = P(X >= k + 1)
        k += 1
    return k


def test_targets_hold_on_the_sensors_the_calibration_vouches_for(family):
    """The accuracy issue's targets at the median and the 90th percentile of the family's
    held-out stations: the 90 % is tested as a share, with the binomial slack of a 25-station sample."""
    s = summarize_family(family, warned=False)
    if s["n_sensors"] == 0:
        pytest.skip("every drawn sensor warned")
    st = [r for f in family if not f.warnings for r in f.rows if r["kind"] == "interp"]
    allowed = _allowed_misses(len(st))
    # central deviation within 1.5 mm
    assert s["central_abs_mm"]["median"] <= 1.5, s["central_abs_mm"]
    missed = [(r["distance_mm"], round(r["central_true_mm"], 2)) for r in st if abs(r["central_true_mm"]) > 1.5]
    assert len(missed) <= allowed, (missed, allowed)
    # the systematic per-pixel shape error (best plane removed) falls >= 4x, or to the floor
    before = np.array([r["sys_rms_plane_before_mm"] for r in st])
    after = np.array([r["sys_rms_plane_after_mm"] for r in st])
    big = before > 4 * SHAPE_FLOOR_MM
    if big.any():
        assert np.median(before[big] / after[big]) >= 4.0, (before, after)
    short = [(r["distance_mm"], round(b, 2), round(a, 2)) for r, b, a in zip(st, before, after)
             if a > max(b / 4.0, SHAPE_FLOOR_MM)]
    assert len(short) <= allowed, (short, allowed)
    # no station visibly worse: a larger plane RMS with a shape error left above the floor (on a station
    # whose shape was already below it, the surfaces' own estimation noise can add a few hundredths)
    assert s["worse_than_before"] == 0


def test_the_prediction_holds(family):
    """No calibration's measured error exceeds twice its own prediction; the per-pixel RMS is
    predicted within 1.5x (with 5 held-out stations a measured RMS itself scatters by ~30 %)."""
    s = summarize_family(family, warned=False)
    if s["n_sensors"] == 0:
        pytest.skip("every drawn sensor warned")
    for key in ("rms_mm", "rms_systematic_mm", "p95_mm", "central_abs_mm"):
        assert s[f"prediction_{key}"]["over_2"] == 0, (key, s[f"prediction_{key}"])
    assert s["prediction_rms_mm"]["ratio_max"] <= 1.5, s["prediction_rms_mm"]


def test_unobservable_range_errors_are_flagged(family):
    """A sensor whose range error the stations cannot sample must warn. (A warning may be a false
    alarm: leaving a station out doubles the gap the model must bridge, so a wiggle of Z that
    the full set of stations resolves can still be predicted too large; the bench reports the
    false-alarm rate over the full family.)"""
    for r in family:
        if _unobservable(r.seed):
            assert r.warnings, f"seed {r.seed}: range error not sampled by the stations, but no warning"
