"""Deviation statistics, completeness, F-score and a unit sanity check (pure numpy)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from tofmetry.errors import InputError

PERCENTILES = (50, 90, 95, 99)


@dataclass
class DeviationStats:
    """Statistics of signed deviations, all in millimetres.

    Attributes
    ----------
    n : number of deviations
    mean_signed_mm, std_signed_mm : mean / sample std of the signed distance
    mean_abs_mm, std_abs_mm : mean / sample std of |d|
    rms_mm, max_abs_mm : root mean square and maximum of |d|
    percentiles_abs_mm : {"p50": .., "p90": .., "p95": .., "p99": ..} of |d|
    share_within : {"1.0": share of |d| <= 1 mm, ...} in [0, 1]
    """

    n: int
    mean_signed_mm: float
    std_signed_mm: float
    mean_abs_mm: float
    std_abs_mm: float
    rms_mm: float
    max_abs_mm: float
    percentiles_abs_mm: dict
    share_within: dict

    def to_dict(self) -> dict:
        return asdict(self)


def deviation_stats(d_m: np.ndarray, thresholds_mm=(1.0, 2.0, 5.0, 10.0)) -> DeviationStats:
    """Statistics of signed deviations.

    Parameters
    ----------
    d_m : (N,) float [m] signed deviations (model to reference)
    thresholds_mm : thresholds for the "share within" figures [mm]
    """
    d = np.asarray(d_m, dtype=np.float64).ravel() * 1e3
    d = d[np.isfinite(d)]
    if d.size == 0:
        raise InputError("deviation_stats: no finite deviations")
    a = np.abs(d)
    ddof = 1 if d.size > 1 else 0
    pct = np.percentile(a, PERCENTILES)
    return DeviationStats(
        n=int(d.size),
        mean_signed_mm=float(d.mean()), std_signed_mm=float(d.std(ddof=ddof)),
        mean_abs_mm=float(a.mean()), std_abs_mm=float(a.std(ddof=ddof)),
        rms_mm=float(np.sqrt(np.mean(d * d))), max_abs_mm=float(a.max()),
        percentiles_abs_mm={f"p{p}": float(v) for p, v in zip(PERCENTILES, pct)},
        share_within={f"{t:g}": float(np.mean(a <= t)) for t in thresholds_mm},
    )


def completeness_fscore(precision_d_m: np.ndarray, recall_d_m: np.ndarray, thresholds_mm) -> dict:
    """Precision (model -> reference), completeness/recall (reference -> model) and F-score.

    Parameters
    ----------
    precision_d_m : (N,) [m] distances from model samples to the reference
    recall_d_m : (K,) [m] distances from reference surface samples to the model

    Returns
    -------
    {"1": {"precision": p, "completeness": r, "fscore": 2pr/(p+r)}, ...} shares in [0, 1]
    """
    pa = np.abs(np.asarray(precision_d_m)) * 1e3
    ra = np.abs(np.asarray(recall_d_m)) * 1e3
    out = {}
    for t in thresholds_mm:
        p = float(np.mean(pa <= t)) if pa.size else 0.0
        r = float(np.mean(ra <= t)) if ra.size else 0.0
        f = 2 * p * r / (p + r) if p + r > 0 else 0.0
        out[f"{t:g}"] = {"precision": p, "completeness": r, "fscore": f}
    return out


def check_units(points: np.ndarray, what: str, expected_extent_m: tuple[float, float] = (0.005, 20.0)) -> float:
    """Check that a cloud/mesh is in metres from its size; return its bounding-box diagonal [m].

    A small object scanned by a ToF camera is centimetres to metres across. A diagonal over
    ``expected_extent_m[1]`` means the file is very probably in millimetres (a 40 cm object
    in mm has a diagonal of ~450 "m").

    Raises
    ------
    InputError naming the file role, the size found and the likely unit.
    """
    p = np.asarray(points)
    diag = float(np.linalg.norm(p.max(0) - p.min(0)))
    lo, hi = expected_extent_m
    if diag > hi:
        guess = "millimetres" if diag / 1000 <= hi else "an unknown unit"
        raise InputError(
            f"{what}: bounding-box diagonal is {diag:.4g} units; in metres that is too large for a scanned object "
            f"(expected {lo:g}..{hi:g} m). The file looks like it is in {guess}: convert it to metres "
            "(scale by 0.001) before evaluating"
        )
    if diag < lo:
        raise InputError(
            f"{what}: bounding-box diagonal is {diag:.4g} units, smaller than {lo:g} m; the file is either "
            "degenerate or in kilometres/another unit (expected metres)"
        )
    return diag
