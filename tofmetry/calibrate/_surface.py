"""Smooth surfaces over the image fitted to masked residual maps (per-pixel deformation).

The residual map is first averaged over ``block x block`` pixel cells (weights = summed
pixel weights), so a fit costs the same whatever the coverage and never holds an
(N_pixels x N_basis) matrix. Two models:

* ``"poly"``: all monomials of total degree <= ``degree`` in normalised coordinates
  ``((u - cx) / (W/2), (v - cy) / (H/2))`` (the study's choice).
* ``"spline"``: cubic tensor-product B-spline with ``knots`` uniform interior knots per axis
  and a small second-difference penalty on the coefficients.

Where there is no data (partial maps, e.g. a board covering part of the image) the
polynomial extrapolates as a polynomial; the spline, through the penalty, continues
linearly from the nearest data (well-posed for any coverage pattern). The penalty weight
``smooth`` is relative to the data weight, so it does not depend on the pixel count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline

from tofmetry.errors import EstimationError


@dataclass(frozen=True)
class SurfaceSpec:
    """Which surface model to fit.

    Attributes
    ----------
    model : "spline" | "poly" | "none"
    degree : int  (poly) total degree
    knots : (int, int)  (spline) interior knots along u and v
    smooth : float  (spline) second-difference penalty, relative to the mean data weight
    block : int  cell size [px] of the averaging before the fit
    """

    model: str = "spline"
    degree: int = 3
    knots: tuple[int, int] = (6, 5)
    smooth: float = 1e-3
    block: int = 4

    @property
    def label(self) -> str:
        if self.model == "poly":
            return f"poly{self.degree}"
        if self.model == "spline":
            return f"spline{self.knots[0]}x{self.knots[1]}"
        return self.model


def block_average(values: np.ndarray, weights: np.ndarray, block: int):
    """Weighted block means of an (H, W) map.

    Returns
    -------
    mean : (Hb, Wb) float64 (0 where no weight), wsum : (Hb, Wb) float64,
    uc, vc : (Wb,), (Hb,) float64 cell-centre pixel coordinates [px]
    """
    h, w = values.shape
    hb, wb = -(-h // block), -(-w // block)
    vals = np.zeros((hb * block, wb * block))
    wts = np.zeros((hb * block, wb * block))
    good = weights > 0
    vals[:h, :w] = np.where(good, values, 0.0) * np.where(good, weights, 0.0)
    wts[:h, :w] = np.where(good, weights, 0.0)
    s = vals.reshape(hb, block, wb, block).sum(axis=(1, 3))
    ws = wts.reshape(hb, block, wb, block).sum(axis=(1, 3))
    u = np.arange(wb * block, dtype=np.float64)
    v = np.arange(hb * block, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(ws > 0, s / ws, 0.0)
    uc = u.reshape(wb, block).mean(axis=1)
    vc = v.reshape(hb, block).mean(axis=1)
    return mean, ws, uc, vc


def _spline_basis(x: np.ndarray, lo: float, hi: float, n_interior: int) -> np.ndarray:
    k = 3
    inner = np.linspace(lo, hi, n_interior + 2)
    t = np.concatenate([[lo] * k, inner, [hi] * k])
    xx = np.clip(x, lo, hi)
    return BSpline.design_matrix(xx, t, k).toarray()


def _poly_basis(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    cols = [x ** i * y ** j for i in range(degree + 1) for j in range(degree + 1 - i)]
    return np.stack(cols, axis=-1)


def _second_diff(n: int) -> np.ndarray:
    d = np.zeros((max(n - 2, 0), n))
    for i in range(n - 2):
        d[i, i:i + 3] = (1.0, -2.0, 1.0)
    return d


def fit_surface(values: np.ndarray, weights: np.ndarray, spec: SurfaceSpec,
                cx: float, cy: float) -> np.ndarray:
    """Fit a smooth surface to a masked residual map and evaluate it on the full grid.

    Parameters
    ----------
    values : (H, W) float [mm] residuals (any value where ``weights == 0``)
    weights : (H, W) float >= 0 (0 = no data)
    spec : SurfaceSpec
    cx, cy : principal point [px] (centre of the polynomial coordinates)

    Returns
    -------
    (H, W) float64 [mm]

    Raises
    ------
    EstimationError
        Fewer data cells than basis functions (poly) or no data at all.
    """
    h, w = values.shape
    if spec.model == "none":
        return np.zeros((h, w))
    mean, ws, uc, vc = block_average(values, weights, spec.block)
    good = ws > 0
    if not good.any():
        raise EstimationError("surface fit: the residual map has no valid pixel")
    # Normal equations are built with einsum over the separable (row, column) structure:
    # no (cells x basis) matrix, no multi-threaded BLAS call (which thrashes on a busy machine).
    W = np.where(good, ws / ws[good].mean(), 0.0)
    WY = W * mean
    if spec.model == "poly":
        sx, sy = w / 2.0, h / 2.0
        xs, ys = (uc - cx) / sx, (vc - cy) / sy
        terms = [(a, b) for a in range(spec.degree + 1) for b in range(spec.degree + 1 - a)]
        if int(good.sum()) < len(terms):
            raise EstimationError(
                f"surface fit: {int(good.sum())} data cells for a degree-{spec.degree} polynomial "
                f"({len(terms)} terms); coverage too small"
            )
        P = 2 * spec.degree + 1
        Xp = xs[:, None] ** np.arange(P)  # (Wb, P)
        Yp = ys[:, None] ** np.arange(P)  # (Hb, P)
        M = np.einsum("ip,iq->pq", np.einsum("ij,jp->ip", W, Xp), Yp)   # moments sum W x^p y^q
        Mr = np.einsum("ip,iq->pq", np.einsum("ij,jp->ip", WY, Xp), Yp)
        N = np.array([[M[a + c, b + d] for (c, d) in terms] for (a, b) in terms])
        rhs = np.array([Mr[a, b] for (a, b) in terms])
        N += 1e-10 * np.trace(N) / len(terms) * np.eye(len(terms))
        coef = np.linalg.solve(N, rhs)
        C = np.zeros((spec.degree + 1, spec.degree + 1))  # C[b, a] coefficient of x^a y^b
        for (a, b), c in zip(terms, coef):
            C[b, a] = c
        Fx = ((np.arange(w) - cx) / sx)[:, None] ** np.arange(spec.degree + 1)
        Fy = ((np.arange(h) - cy) / sy)[:, None] ** np.arange(spec.degree + 1)
        return np.einsum("ia,ja->ij", np.einsum("ib,ba->ia", Fy, C), Fx)
    if spec.model == "spline":
        nu, nv = spec.knots
        Bu = _spline_basis(uc, -0.5, w - 0.5, nu)  # (Wb, mu)
        Bv = _spline_basis(vc, -0.5, h - 0.5, nv)  # (Hb, mv)
        mu, mv = Bu.shape[1], Bv.shape[1]
        G = np.einsum("ijb,jd->ibd", np.einsum("ij,jb->ijb", W, Bu), Bu)            # (Hb, mu, mu)
        N = np.einsum("ia,ic,ibd->abcd", Bv, Bv, G).reshape(mv * mu, mv * mu)
        rhs = np.einsum("ia,ib->ab", Bv, np.einsum("ij,jb->ib", WY, Bu)).reshape(mv * mu)
        Dv, Du = _second_diff(mv), _second_diff(mu)
        P = np.kron(Dv.T @ Dv, np.eye(mu)) + np.kron(np.eye(mv), Du.T @ Du)
        lam = spec.smooth * float(good.sum()) / (mu * mv)
        N += lam * P + 1e-9 * np.trace(N) / N.shape[0] * np.eye(N.shape[0])
        coef = np.linalg.solve(N, rhs).reshape(mv, mu)
        Fu = _spline_basis(np.arange(w, dtype=np.float64), -0.5, w - 0.5, nu)
        Fv = _spline_basis(np.arange(h, dtype=np.float64), -0.5, h - 0.5, nv)
        return np.einsum("ib,jb->ij", np.einsum("ia,ab->ib", Fv, coef), Fu)
    raise EstimationError(f"surface model must be 'spline', 'poly' or 'none', found {spec.model!r}")
