"""The scale a set of views leaves to the model through the noise of their poses, predicted before the scan.

Why: a model's scale error on the family (``bench/robustness``) comes mostly from its poses, not from its
depth. On the box 2038867571 (held-out draw 83, 8 views at 1.43 m) the views fused at the *true* poses read
+0.03 %, the model -0.32 %; its views' pose errors were 0.17-0.55 mm RMS on the object. Removing one
error term of the sensor at a time moved that model to -0.47 % or +0.25 %: noise along a weakly held mode
of the poses, not a bias. On a box the faces' offsets and the scale are nearly the same move (their
correlation -0.96), so a few tenths of a millimetre on each face are a few tenths of a percent. The same box
scanned with 16 views read -0.01 %, the box 1047249317 (draw 80, 0.96 m) +0.48 % with 8 views and -0.20 %
with 16; the chain's own prediction of that term halved (0.28 -> 0.13 %, 0.17 -> 0.09 %).

The prediction mirrors the joint fit's (:mod:`tofmetry.reconstruct._scale_budget`, ``poses``): every pair of
views that see the same surface samples is tied point to plane, each sample weighted by the depth noise
the two views read it with (``noise_1m_mm`` (z / 1 m)^1.5 per pixel, averaged over the frames and over the
pixels that fall on the sample at its incidence); each view is held by a prior, the dot mat's placement
(:data:`PRIOR_DEG`, :data:`PRIOR_MM`). The covariance of the poses is carried to the scale of the fused
surface (each sample moved by the views that see it, in proportion to their weights) through the same
scale-and-offset fit the evaluation uses (:func:`~tofmetry._shared.geometry.similarity_scale_rows`).

Measured on 59 right, reliable runs of the family's draws 80-83 on the mat (``plan_scale`` rows of the
development scripts, 2026-12-04): against the chain's own term after the scan, Spearman 0.88, the chain's
:data:`CHAIN_RATIO` times larger (median; the chain's pairs also carry the calibration's residual and the
fusion's model as noise, which this leaves out), and the prediction is scaled by it. Against the scale
errors achieved, Spearman 0.49: of the 8 runs predicted above 0.17 % (boxes, plaques and bars at 8
views), 6 came out past 0.2 %; of the 51 below, 4 (the chain's other terms, and placements the calibration
kept unrefined).
"""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import similarity_scale_rows
from tofmetry.sensor import CameraIntrinsics

#: each view's prior: the dot mat's placement of one view (its dots' fit, measured on the family's draws:
#: typically 0.08 deg and 0.3 mm at the object)
PRIOR_DEG, PRIOR_MM = 0.08, 0.3
#: the chain's pose-noise scale term after the scan over this prediction, median of 44 family runs
CHAIN_RATIO = 2.0
#: a pair of views is tied by the joint fit when it shares at least this many surface samples
MIN_SHARED = 50


def pose_scale_sigma(points: np.ndarray, normals: np.ndarray, cosines: np.ndarray, poses, centre: np.ndarray,
                     intr: CameraIntrinsics, *, n_frames: int, noise_1m_mm: float, spacing_mm: float,
                     max_incidence_deg: float = 70.0, prior_deg: float = PRIOR_DEG,
                     prior_mm: float = PRIOR_MM) -> tuple[float, float]:
    """Predicted standard deviation of the model's relative scale from its poses' noise (module docstring).

    Parameters
    ----------
    points, normals : (N, 3) [m] surface samples of the object, ``spacing_mm`` apart, and their
        outward unit normals (z up, the object's frame)
    cosines : (V, N) cos(incidence) where each view sees each sample, NaN where it does not
        (:func:`tofmetry.plan.seen_cosines`)
    poses : V camera-to-world (4, 4) [m] (camera x right, y down, z forward)
    centre : (3,) [m] the object's centre (the rotations act about it)
    n_frames : frames averaged per view; noise_1m_mm : one frame's depth noise at 1 m [mm]
    max_incidence_deg : samples seen more obliquely do not tie the views

    Returns
    -------
    (sigma, correlation): the relative scale's standard deviation (0.001 = 0.1 %), times
    :data:`CHAIN_RATIO`; NaN where scale and surface offset are not separable on this shape (a
    sphere: ``|correlation|`` above the evaluation's limit) or no two views share the surface; and
    the correlation of the scale and offset estimates on the seen surface.
    """
    P = np.asarray(points, np.float64)
    N = np.asarray(normals, np.float64)
    C = np.asarray(cosines, np.float64)
    with np.errstate(invalid="ignore"):
        seen = C >= np.cos(np.radians(max_incidence_deg))
    V = len(poses)
    var = np.full(C.shape, np.inf)  # each view's variance of each sample along its normal [m^2]
    for v, T in enumerate(poses):
        m = seen[v]
        z = (P[m] - T[:3, 3]) @ T[:3, 2]
        pixels = (spacing_mm * 1e-3) ** 2 * C[v, m] / (z / float(intr.fx)) / (z / float(intr.fy))
        noise = noise_1m_mm * 1e-3 * z ** 1.5
        var[v, m] = noise ** 2 / n_frames / np.maximum(pixels, 1e-3)
    J = np.c_[np.cross(P - centre, N), N]  # a view's rotation about the centre [rad] and translation [m]
    H = np.zeros((6 * V, 6 * V))
    tied = 0
    for v in range(V):
        for w in range(v + 1, V):
            m = seen[v] & seen[w]
            if m.sum() < MIN_SHARED:
                continue
            A = (J[m] / (var[v, m] + var[w, m])[:, None]).T @ J[m]
            a, b = slice(6 * v, 6 * v + 6), slice(6 * w, 6 * w + 6)
            H[a, a] += A
            H[b, b] += A
            H[a, b] -= A
            H[b, a] -= A
            tied += 1
    anyv = seen.any(0)
    rows, corr = similarity_scale_rows(P[anyv], N[anyv])
    if rows is None or tied == 0:
        return float("nan"), corr
    H += np.diag(np.tile(np.r_[[np.radians(prior_deg) ** -2] * 3, [(prior_mm * 1e-3) ** -2] * 3], V))
    weight = np.where(seen, 1.0 / var, 0.0)[:, anyv]
    share = weight / weight.sum(0)  # how much of each fused sample each view carries
    a = np.concatenate([(rows[0] * share[v]) @ J[anyv] for v in range(V)])
    return CHAIN_RATIO * float(np.sqrt(a @ np.linalg.solve(H, a))), corr
