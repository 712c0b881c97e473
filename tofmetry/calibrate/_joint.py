"""The joint depth-error model and its penalised least-squares fit.

Every calibration sample (a wall station, a board pose...) gives, per pixel ``p``, the measured
depth ``m`` [mm] and a reference depth; their difference ``e = m - ref`` [mm] is modelled as

    ``e(p) = c0 + W(q) / rho(p)**gamma + sum_k phi_k(m) S_k(p) + [tilt of the sample]``

* ``rho = sqrt(1 + x^2 + y^2)`` for the undistorted normalised ray ``(x, y)`` of the pixel, and
  ``q = m rho`` (the measured *ray length*, ``variable="radial"``) or ``q = m``
  (``variable="z"``). A continuous-wave ToF camera measures the phase of the path length, so its
  range error ("wiggling") is a function of the ray length, and a camera that converts the ray
  length to Z divides that error by ``rho`` (``gamma = 1``). One wall station then samples ``W``
  over 1 to ~1.35 times its distance (the corners see farther), so all pixels of all stations
  sample the range error far more densely than the station spacing.
* ``W`` is a cubic B-spline with knots every ``knot_mm`` and a second-difference roughness
  penalty (a P-spline), ``c0`` a constant.
* ``S_k`` are smooth per-pixel surfaces (cubic tensor-product B-splines over the image, roughness
  penalised) at ``n_nodes`` measured depths, linearly interpolated in ``m`` (hats ``phi_k``, held
  constant beyond the first and the last node). A penalty on the change between neighbouring
  nodes keeps them from following noise where the support is thin. Each surface is zero at the
  principal point (``c0 + W`` own the axis) and, when samples carry a free tilt, has no linear
  component in ``x`` or ``y`` over the image: such a component cannot be told from the tilt of a
  wall, so it is not calibrated (said in the calibration's diagnostics).
* A free tilt per sample (walls): two columns ``ref x`` and ``ref y`` (the first-order change of
  the depth of a plane anchored on the optical axis when it turns), eliminated per sample
  (Schur complement) so that a sample can be left out of the fit by subtracting its normal
  equations: blocked cross-validation costs one small solve per fold.

The data are averaged over ``block x block`` pixel cells first (the model is smooth at that
scale: the curvature of ``W`` over a cell changes a cell mean by < 0.05 mm). Cells are weighted
by the inverse variance of their mean (temporal noise of the sample) plus a model floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from scipy import sparse
from scipy.interpolate import BSpline

from tofmetry._shared.geometry import ray_factor
from tofmetry.errors import InputError


@dataclass(frozen=True)
class JointSpec:
    """Hyper-parameters of the joint model (see the module docstring)."""

    variable: str = "radial"
    gamma: float = 1.0
    knot_mm: float = 40.0
    lam_w: float = 1.0
    n_nodes: int = 3
    knots_uv: tuple = (8, 7)
    lam_s: float = 0.01
    lam_k: float = 0.1
    block: int = 8

    def __post_init__(self) -> None:
        if self.variable not in ("radial", "z"):
            raise InputError(f"range variable must be 'radial' or 'z', found {self.variable!r}")
        if self.n_nodes < 1 or self.block < 1 or not self.knot_mm > 0:
            raise InputError(f"n_nodes, block >= 1 and knot_mm > 0 needed, found {self.n_nodes}, {self.block}, {self.knot_mm}")

    @property
    def label(self) -> str:
        g = f"/rho^{self.gamma:g}" if self.gamma else ""
        return (f"W({'ray length' if self.variable == 'radial' else 'Z'}){g}, knots {self.knot_mm:g} mm, "
                f"lam_w {self.lam_w:g}; {self.n_nodes} surface nodes, lam_s {self.lam_s:g}, lam_k {self.lam_k:g}")


@dataclass(eq=False)
class Cells:
    """Block-averaged data of one sample (all (n,) float64).

    e : measured - reference [mm]; m : measured Z [mm]; x, y : normalised ray; rho : ray length
    per unit Z; u, v : cell centre [px]; ref : reference Z [mm]; w : weight; var : variance of
    the cell mean [mm^2]; npx : pixels averaged; var_q : {"radial", "z"} -> (n,) spread
    (variance) of the range variable over the pixels of each cell [mm^2].
    """

    e: np.ndarray
    m: np.ndarray
    x: np.ndarray
    y: np.ndarray
    rho: np.ndarray
    u: np.ndarray
    v: np.ndarray
    ref: np.ndarray
    w: np.ndarray
    var: np.ndarray
    npx: np.ndarray
    free_tilt: bool
    name: str = ""
    var_q: dict | None = None


def block_cells(measured: np.ndarray, reference: np.ndarray, weight: np.ndarray, sem: np.ndarray | None,
                rays: np.ndarray, block: int, free_tilt: bool, name: str = "", floor_mm: float = 0.1,
                min_pixels: int = 4) -> Cells:
    """Average one sample over ``block x block`` cells.

    Parameters
    ----------
    measured, reference : (H, W) float [mm], NaN where unknown
    weight : (H, W) float >= 0 (0 = unused pixel)
    sem : (H, W) float [mm] standard error of ``measured`` (temporal std / sqrt(n)), or None
    rays : (H, W, 2) undistorted normalised rays
    floor_mm : model-error floor added to the noise of a cell mean for its weight [mm]
    """
    h, w = measured.shape
    ok = np.isfinite(measured) & (measured > 0) & np.isfinite(reference) & (weight > 0)
    hb, wb = -(-h // block), -(-w // block)

    def bsum(a):
        z = np.zeros((hb * block, wb * block))
        z[:h, :w] = np.where(ok, a, 0.0)
        return z.reshape(hb, block, wb, block).sum(axis=(1, 3)).ravel()

    n = bsum(np.ones((h, w)))
    keep = n >= min(min_pixels, block * block)
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = {k: bsum(a)[keep] / n[keep] for k, a in
                (("e", measured - reference), ("m", measured), ("x", rays[..., 0]), ("y", rays[..., 1]),
                 ("u", uu), ("v", vv), ("ref", reference))}
        s2 = np.square(np.nan_to_num(sem)) if sem is not None else np.ones((h, w))
        var = bsum(s2)[keep] / n[keep] ** 2
        q_r = measured * ray_factor(rays)
        var_q = {}
        for key, q in (("radial", q_r), ("z", measured)):
            mq = bsum(q)[keep] / n[keep]
            var_q[key] = np.maximum(bsum(q * q)[keep] / n[keep] - mq * mq, 0.0)
    nk = n[keep]
    if sem is None:
        var = 1.0 / nk  # unknown noise: weight by the pixel count
    wt = 1.0 / (var + (floor_mm ** 2 if sem is not None else 0.0))
    rho = ray_factor(np.stack([mean["x"], mean["y"]], axis=-1))
    return Cells(mean["e"], mean["m"], mean["x"], mean["y"], rho, mean["u"], mean["v"], mean["ref"], wt, var, nk,
                 bool(free_tilt), name, var_q)


# ----------------------------------------------------------------------------- bases
def uniform_knots(lo: float, hi: float, step: float, k: int = 3) -> np.ndarray:
    """Clamped uniform B-spline knots covering ``[lo, hi]`` with interior spacing about ``step``."""
    n = max(1, int(np.ceil((hi - lo) / step)))
    inner = np.linspace(lo, hi, n + 1)
    return np.concatenate([[lo] * k, inner, [hi] * k])


def bspline_rows(x: np.ndarray, t: np.ndarray, k: int = 3) -> sparse.csr_matrix:
    """(n, len(t) - k - 1) sparse B-spline basis at ``x`` (clamped into the knot span)."""
    xx = np.clip(np.asarray(x, float), t[k], t[-k - 1])
    return BSpline.design_matrix(xx, t, k).tocsr()


def bspline_cell_rows(x: np.ndarray, var: np.ndarray | None, t: np.ndarray, h: float = 1.0) -> sparse.csr_matrix:
    """Cubic B-spline basis averaged over a cell: ``B(x) + var/2 B''(x)`` (second order in the
    spread ``var`` of ``x`` over the cell's pixels). ``B''`` by a central difference of step
    ``h`` (exact inside a cubic piece)."""
    B = bspline_rows(x, t)
    if var is None or not np.any(var > 0):
        return B
    d2 = (bspline_rows(x + h, t) - 2.0 * B + bspline_rows(x - h, t)) / (h * h)
    return (B + d2.multiply(0.5 * np.asarray(var, float)[:, None])).tocsr()


def hat_weights(nodes: np.ndarray, m: np.ndarray):
    """Bracketing node indices ``k0, k1`` and weight of ``k1`` (held constant outside the nodes)."""
    kk = len(nodes)
    if kk == 1:
        z = np.zeros(m.shape, np.int64)
        return z, z, np.zeros(m.shape)
    k0 = np.clip(np.searchsorted(nodes, m, side="right") - 1, 0, kk - 2)
    w = np.clip((m - nodes[k0]) / (nodes[k0 + 1] - nodes[k0]), 0.0, 1.0)
    return k0, k0 + 1, w


@dataclass(eq=False)
class Layout:
    """Column layout of the joint model for one spec and one data set."""

    spec: JointSpec
    t_w: np.ndarray          # knots of W [mm of q]
    t_u: np.ndarray          # knots of the surfaces along u [px]
    t_v: np.ndarray          # ... along v [px]
    nodes: np.ndarray        # surface nodes [mm of measured Z]
    shape: tuple
    cxy: tuple

    @property
    def n_w(self) -> int:
        return len(self.t_w) - 4

    @property
    def n_uv(self) -> tuple[int, int]:
        return len(self.t_u) - 4, len(self.t_v) - 4

    @property
    def n_s(self) -> int:
        mu, mv = self.n_uv
        return mu * mv

    @property
    def n_params(self) -> int:
        return 1 + self.n_w + len(self.nodes) * self.n_s

    def q(self, m: np.ndarray, rho: np.ndarray) -> np.ndarray:
        return m * rho if self.spec.variable == "radial" else m

    def design(self, c: Cells) -> sparse.csr_matrix:
        """(n, n_params) sparse design of the shared parameters for cells ``c``."""
        n = len(c.e)
        vq = c.var_q.get(self.spec.variable) if c.var_q else None
        bw = bspline_cell_rows(self.q(c.m, c.rho), vq, self.t_w).multiply((c.rho ** -self.spec.gamma)[:, None]).tocsr()
        bu = bspline_rows(c.u, self.t_u)
        bv = bspline_rows(c.v, self.t_v)
        mu, _ = self.n_uv
        # tensor rows: 4 x 4 non-zeros per cell
        cu, wu = bu.indices.reshape(n, 4), bu.data.reshape(n, 4)
        cv, wv = bv.indices.reshape(n, 4), bv.data.reshape(n, 4)
        cols = (cv[:, :, None] * mu + cu[:, None, :]).reshape(n, 16)
        vals = (wv[:, :, None] * wu[:, None, :]).reshape(n, 16)
        k0, k1, hw = hat_weights(self.nodes, c.m)
        off = 1 + self.n_w
        rows = np.repeat(np.arange(n), 32)
        scol = np.concatenate([off + k0[:, None] * self.n_s + cols, off + k1[:, None] * self.n_s + cols], axis=1)
        sval = np.concatenate([(1 - hw)[:, None] * vals, hw[:, None] * vals], axis=1)
        S = sparse.csr_matrix((sval.ravel(), (rows, scol.ravel())), shape=(n, self.n_params))
        C = sparse.csr_matrix((np.ones(n), (np.arange(n), np.zeros(n, int))), shape=(n, self.n_params))
        Wm = sparse.hstack([sparse.csr_matrix((n, 1)), bw, sparse.csr_matrix((n, len(self.nodes) * self.n_s))]).tocsr()
        return (C + Wm + S).tocsr()

    def penalty(self, n_data: float, lam_w: float, lam_s: float, lam_k: float, tilt_free: bool) -> np.ndarray:
        """(P, P) penalty: roughness of W and of the surfaces, change across nodes, constraints."""
        p = self.n_params
        P = np.zeros((p, p))
        nw = self.n_w
        d2 = np.diff(np.eye(nw), 2, axis=0)
        P[1:1 + nw, 1:1 + nw] += lam_w * n_data / nw * (d2.T @ d2)
        mu, mv = self.n_uv
        du = np.diff(np.eye(mu), 2, axis=0)
        dv = np.diff(np.eye(mv), 2, axis=0)
        rough = np.kron(dv.T @ dv, np.eye(mu)) + np.kron(np.eye(mv), du.T @ du)
        kk = len(self.nodes)
        scale = n_data / (kk * self.n_s)
        off = 1 + nw
        for k in range(kk):
            sl = slice(off + k * self.n_s, off + (k + 1) * self.n_s)
            P[sl, sl] += lam_s * scale * rough
        if kk > 2:  # curvature of each pixel's surface value along depth (a linear change is free)
            d2k = np.kron(np.diff(np.eye(kk), 2, axis=0), np.eye(self.n_s))
            P[off:, off:] += lam_k * scale * (d2k.T @ d2k)
        # constraints: each surface zero at the principal point and, with free tilts, free of a
        # linear component in x and y (heavy penalty rows)
        big = 10.0 * n_data
        cons = self._constraint_rows(tilt_free)
        for k in range(kk):
            sl = slice(off + k * self.n_s, off + (k + 1) * self.n_s)
            P[sl, sl] += big * (cons.T @ cons)
        P[np.diag_indices(p)] += 1e-9 * max(float(np.trace(P)) / p, 1.0)
        return P

    def _constraint_rows(self, tilt_free: bool) -> np.ndarray:
        h, w = self.shape
        cx, cy = self.cxy
        mu, _ = self.n_uv
        rows = [_tensor_row(np.array([cx]), np.array([cy]), self.t_u, self.t_v, mu).ravel()]
        if tilt_free:
            vv, uu = np.mgrid[0:h:8, 0:w:8].astype(float)
            uu, vv = uu.ravel(), vv.ravel()
            B = _tensor_row(uu, vv, self.t_u, self.t_v, mu)  # (n, n_s)
            for a in ((uu - cx) / w, (vv - cy) / h):
                rows.append((a @ B) / len(uu))
        return np.array(rows)

    def surfaces(self, theta: np.ndarray) -> np.ndarray:
        """(K, H, W) float64 surfaces ``S_k`` [mm] from the parameters."""
        h, w = self.shape
        mu, mv = self.n_uv
        Fu = bspline_rows(np.arange(w, dtype=float), self.t_u).toarray()
        Fv = bspline_rows(np.arange(h, dtype=float), self.t_v).toarray()
        off = 1 + self.n_w
        out = np.empty((len(self.nodes), h, w))
        for k in range(len(self.nodes)):
            C = theta[off + k * self.n_s: off + (k + 1) * self.n_s].reshape(mv, mu)
            out[k] = Fv @ C @ Fu.T
        return out

    def w_spline(self, theta: np.ndarray) -> BSpline:
        return BSpline(self.t_w, theta[1:1 + self.n_w], 3, extrapolate=False)


def _tensor_row(u: np.ndarray, v: np.ndarray, t_u: np.ndarray, t_v: np.ndarray, mu: int) -> np.ndarray:
    bu = bspline_rows(u, t_u).toarray()
    bv = bspline_rows(v, t_v).toarray()
    return np.einsum("na,nb->nab", bv, bu).reshape(len(u), -1)


def make_layout(cells: list[Cells], spec: JointSpec, shape: tuple, cxy: tuple, centers_mm: np.ndarray) -> Layout:
    """Knots of W over the data's q range, surface knots over the image, nodes over the centres."""
    qs = np.concatenate([(c.m * c.rho if spec.variable == "radial" else c.m) for c in cells])
    lo, hi = float(np.min(qs)) - 1.0, float(np.max(qs)) + 1.0
    t_w = uniform_knots(lo, hi, spec.knot_mm)
    h, w = shape
    nu, nv = spec.knots_uv
    t_u = uniform_knots(-0.5, w - 0.5, w / (nu + 1))
    t_v = uniform_knots(-0.5, h - 0.5, h / (nv + 1))
    c = np.sort(np.asarray(centers_mm, float))
    k = int(min(spec.n_nodes, len(np.unique(np.round(c)))))
    nodes = np.linspace(c[0], c[-1], k) if k > 1 else np.array([float(np.median(c))])
    return Layout(spec, t_w, t_u, t_v, nodes, tuple(shape), tuple(cxy))


@dataclass(eq=False)
class SampleSystem:
    """Normal equations of one sample with its tilt eliminated (for leave-out folds)."""

    A: sparse.csr_matrix
    T: np.ndarray | None
    N: np.ndarray
    r: np.ndarray


def sample_system(layout: Layout, c: Cells, w: np.ndarray) -> SampleSystem:
    A = layout.design(c)
    Aw = A.multiply(w[:, None]).tocsr()
    N = (A.T @ Aw).toarray()
    r = Aw.T @ c.e
    T = None
    if c.free_tilt:
        T = np.column_stack([c.ref * c.x, c.ref * c.y])
        G = T.T @ (w[:, None] * T)
        H = Aw.T @ T
        Gi = np.linalg.pinv(G)
        N = N - H @ Gi @ H.T
        r = r - H @ (Gi @ (T.T @ (w * c.e)))
    return SampleSystem(A, T, N, np.asarray(r).ravel())


def solve(N: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Solve the symmetric positive (semi-)definite system (Cholesky, least squares fallback)."""
    try:
        return sla.cho_solve(sla.cho_factor(N, check_finite=False), r, check_finite=False)
    except (np.linalg.LinAlgError, sla.LinAlgError):
        sol, *_ = np.linalg.lstsq(N, r, rcond=None)
        return sol


def residual(layout: Layout, sys: SampleSystem, c: Cells, theta: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Cell residuals [mm] of a sample with its own tilt re-fitted (weighted)."""
    res = c.e - sys.A @ theta
    if sys.T is not None:
        G = sys.T.T @ (w[:, None] * sys.T)
        tau = np.linalg.lstsq(G, sys.T.T @ (w * res), rcond=None)[0]
        res = res - sys.T @ tau
    return res


#: fewest image cells with data a sample needs to enter the fit
MIN_CELLS = 8


def unusable_cells(cells: list[Cells]) -> dict[int, str]:
    """Samples (by index) with too few usable image cells, and why."""
    return {j: f"only {len(c.e)} usable image cells with a reference depth (at least {MIN_CELLS} needed: pixels "
               "invalid in some frames, e.g. beyond the sensor's range, are left out)"
            for j, c in enumerate(cells) if len(c.e) < MIN_CELLS}
