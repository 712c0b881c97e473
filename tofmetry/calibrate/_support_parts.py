"""The parts of a flat support's range curve that a plane absorbs (its ``1``, ``Z`` and ``Z^2``), measured otherwise.

A view's support plane takes up a range error's offset, gain and inverse-depth shift
(:mod:`tofmetry.calibrate._flat_support`); two things can give them back: the calibration's stations, where its
own residual is about nought (:func:`station_tie`), and each view's plane measured without the depth, from a
printed pattern's perspective (:func:`anchor_samples`, :func:`anchored_part`). Depths in mm; ``u = (Z - z0) /
span`` the span's normalised depth.
"""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import ray_factor


def station_tie(zs: np.ndarray, Bs: np.ndarray, to_coef: np.ndarray, z0: float,
                span: float) -> tuple[np.ndarray, np.ndarray]:
    """The curve tied to nought at the stations ``zs`` [mm]: ``M`` (B, B) maps its coefficients to those
    with ``k0 + k1 u + k2 u^2`` (``u = (Z - z0) / span``; ``k2`` held at 0 with two stations) added, fitted
    by least squares to minus the curve there; ``G`` (B, S) maps the stations' own residuals [mm] to the
    coefficients (their covariance). ``Bs`` (S, B): the curve's basis functions at the stations; ``to_coef``
    (B, 3): ``(1, u, u^2)`` to spline coefficients."""
    u = (zs - z0) / span
    A = np.column_stack([np.ones_like(u), u, u ** 2])[:, :min(3, len(zs))]
    G = to_coef[:, :A.shape[1]] @ np.linalg.pinv(A)
    return np.eye(Bs.shape[1]) - G @ Bs, G


def anchor_samples(xy: np.ndarray, p: np.ndarray, anchor: np.ndarray, anchor_cov: np.ndarray,
                    n: int = 40, radial: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One anchored view's evidence on the curve's parts a plane absorbs: at ``n`` of its support rays
    ``xy`` (sorted by depth, evenly), the depth its fitted plane ``p`` gives less the depth its anchor
    gives [mm] (the plane took up what the fitted curve left of the range error; the anchor did not), the
    anchor's depth [mm] (its ray length with ``radial``, a curve's variable) and that difference's covariance
    from the anchor's (n, n) [mm^2]."""
    R = np.column_stack([xy, np.ones(len(xy))])
    za = 1e3 / (R @ np.asarray(anchor, np.float64))
    pick = np.argsort(za)[np.linspace(0, len(za) - 1, n).astype(int)]
    R, za = R[pick], za[pick]
    delta = 1e3 / (R @ p) - za
    G = -(za[:, None] ** 2) * 1e-3 * R  # d(1e3 / (R . a)) / da [mm m]
    at = za * ray_factor(R[:, :2]) if radial else za
    return delta, at, G @ anchor_cov @ G.T


def anchored_part(samples: list, z0: float, span: float) -> np.ndarray:
    """``(k0, k1, k2)`` of ``k0 + k1 u + k2 u^2`` (``u = (Z - z0) / span``, [mm]) fitted to the anchored
    views' plane-minus-anchor depths (:func:`anchor_samples`), each view weighed by its anchor's
    covariance (a generalised least squares: an anchor's error is one error over its whole view)."""
    N, r = np.zeros((3, 3)), np.zeros(3)
    for delta, za, C in samples:
        u = (za - z0) / span
        A = np.column_stack([np.ones_like(u), u, u ** 2])
        W = np.linalg.pinv(C + 1e-4 * np.eye(len(za)))  # 0.01 mm: the planes' own rounding
        N += A.T @ W @ A
        r += A.T @ W @ delta
    return np.linalg.lstsq(N, r, rcond=None)[0]
