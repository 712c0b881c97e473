"""Prior of the global adjustment: each view stays near its pose-graph pose where the points leave it free.

Why: the joint point-to-plane adjustment only sees geometry. On a surface of revolution (a vase, a
dome) the rotation about its axis is (nearly) unobserved: Gauss-Newton then moves the views along
that direction by whatever the noise asks. The pose graph placed them there from the pairwise
registrations, whose yaw the IR pattern may have decided. Started at the *true* poses of a painted
vase with only noise as depth error, the adjustment walked 1.75 deg along its axis, while the pose
graph alone was 0.27 deg off. A Gaussian prior on each view's displacement from its pose-graph pose
keeps that information: where the points determine a pose (thousands of correspondences), the prior
is orders of magnitude weaker than the data and changes nothing; where they do not, it holds the
pose graph's value.

The displacement of view ``v`` is ``E = P_v P0_v^-1`` (world frame, left increments as in
:func:`tofmetry.reconstruct._adjust.global_adjust`); its residuals are the rotation vector of ``E``
[rad] and the displacement of the object centre ``c`` [m], ``E c - c`` (so a rotation about the
object is not also charged as a translation of the far-away camera-0 origin).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tofmetry._shared.geometry import skew


def pose_prior_terms(P: np.ndarray, P0: np.ndarray, centre_m: np.ndarray, sigma_rad: float, sigma_m: float,
                     weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton terms of the pose prior, in the adjustment's residual units.

    Parameters
    ----------
    P, P0 : (V, 4, 4) current and prior camera-to-world poses; view 0 is fixed (not an unknown)
    centre_m : (3,) object centre, world frame [m]
    sigma_rad : prior standard deviation of each view's rotation [rad]; or (3,), one per world axis
        (a view placed on a dot mat knows its turn about the vertical far better than its tilt); or
        (V, 3), per view and axis
    sigma_m : prior standard deviation of the object centre's displacement [m]; or (3,) or (V, 3), as
        ``sigma_rad``
    weight : the data term's residual variance times the square of its sigma inflation [m^2]:
        the prior enters as ``weight / sigma^2`` beside the data's unscaled normal equations, so
        that both are compared at the data's honest (inflated) uncertainty

    Returns
    -------
    H : (6 (V - 1), 6 (V - 1)) block-diagonal addition to the normal matrix
    b : (6 (V - 1),) addition to the gradient (``dx = -H^-1 b`` moves back towards ``P0``)
    """
    V = len(P)
    H = np.zeros((6 * (V - 1), 6 * (V - 1)))
    b = np.zeros(6 * (V - 1))
    c = np.asarray(centre_m, np.float64)
    Jc = np.hstack([-skew(c), np.eye(3)])  # d(E c) / d(left increment (w, t)) at E ~ I
    Jr = np.hstack([np.eye(3), np.zeros((3, 3))])
    wr = weight / _per_view(sigma_rad, V) ** 2
    wc = weight / _per_view(sigma_m, V) ** 2
    for v in range(1, V):
        E = P[v] @ np.linalg.inv(P0[v])
        r_rot = Rotation.from_matrix(E[:3, :3]).as_rotvec()
        r_c = E[:3, :3] @ c + E[:3, 3] - c
        s = slice(6 * (v - 1), 6 * v)
        H[s, s] = Jr.T @ (wr[v][:, None] * Jr) + Jc.T @ (wc[v][:, None] * Jc)
        b[s] = Jr.T @ (wr[v] * r_rot) + Jc.T @ (wc[v] * r_c)
    return H, b


def _per_view(sigma, n_views: int) -> np.ndarray:
    """(V, 3) standard deviations from a scalar, a (3,) per world axis or a (V, 3) per view and axis."""
    a = np.asarray(sigma, np.float64)
    return np.broadcast_to(a if a.ndim == 2 else np.broadcast_to(a, (3,)), (n_views, 3))
