"""Whether an object's geometry can fix the views' turn about the vertical, before it is scanned.

Registration matches the surface two views share. On a surface of revolution (a vase, a dome)
that surface matches itself turned about the vertical, so no set of views fixes their turn from the
geometry: the pairwise registrations slide, the loops do not close, and the reconstruction flags
the run (or it comes out wrong). More views do not help; a pattern on the surface (the IR albedo
then fixes the turn) or a declared turntable step does.

The test (:func:`turn_about_vertical`) is the point-to-plane stiffness of the whole surface (Gelfand
et al. 2003; :func:`tofmetry.reconstruct.point_to_plane_rows`, rotations as displacements at the
surface's RMS radius): the stiffness of a turn about the vertical through its centroid, the other
five motions left free, over the mean stiffness of the three translations. A surface of revolution
scores 0: turning it moves no point off the surface. The registration's own test for a pair
(``yaw_free_ratio``) divides by the tilts' stiffness instead, which a dome or a round pebble also
leaves nearly free (ratios of 1.5-22 there), so it cannot tell them from a bust.

Measured on the family of ``bench/robustness`` (2026-11-30, as drawn, one run per seed):

* chosen on the first 60 seeds of draws 35-47: vases 0.007-0.015, round pebbles 0.06-0.11, domes
  0.11-0.15, then igeas from 0.236 (bunnies 0.34, balusters 0.49, boxes 0.58-0.66, rocker arms
  0.68-0.72, fandisks 0.83-0.86, bars 1.1-1.4, plaques 1.9-4.3): :data:`TURN_FREE_BELOW` = 0.2 in the gap;
* held out, the 164 seeds of draws 25-34: below 0.2, 2 of 26 scans came out right and reliable (9
  flagged, 15 wrong: every vase, 9 of 11 domes, 2 of 7 pebbles); above, 77 of 138. The test does
  not claim that an object above it registers (bars and plaques fail for other reasons: a long
  axis the views slide along, a slab's faces that meet only at its rim), only that one below it
  rarely does; igeas (a bust) sit at 0.23-0.25, close above it.
"""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct import constrained_stiffness, point_to_plane_rows

#: below this ratio of stiffnesses the surface leaves a turn about the vertical free (module docstring)
TURN_FREE_BELOW = 0.2


def turn_about_vertical(points: np.ndarray, normals: np.ndarray, free_below: float = TURN_FREE_BELOW) -> dict:
    """Whether the object's surface fixes a turn about the vertical (module docstring).

    Parameters
    ----------
    points : (N, 3) [m] samples of the object's surface (its base left out), z up
    normals : (N, 3) their unit normals
    free_below : the stiffness ratio below which the turn is free

    Returns
    -------
    dict: ``ratio`` (the turn's stiffness over the translations' mean, dimensionless; NaN with fewer
    than 10 samples or a surface that fixes no motion), ``free_below``, ``free`` (``ratio < free_below``)
    """
    limit = float(free_below)
    p = np.asarray(points, np.float64)
    nan = {"ratio": float("nan"), "free_below": limit, "free": False}
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 10:
        return nan
    J = point_to_plane_rows(p, normals)
    try:  # the turn about z, then the three shifts, each with the other five motions left free
        k = constrained_stiffness(J.T @ J / len(J), np.eye(6)[[2, 3, 4, 5]])
    except np.linalg.LinAlgError:
        return nan
    ratio = float(k[0]) / float(np.mean(k[1:]))
    return {"ratio": round(ratio, 4), "free_below": limit, "free": bool(ratio < limit)}
