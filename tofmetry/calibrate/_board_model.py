"""Board depth-correction model and its penalised least-squares fit (see :mod:`tofmetry.calibrate.board`).

Model (all values in mm, added to the measured depth ``Z``)::

    c(u, v, Z) = a(x) + s(u, v) + zeta(x) g(u, v)

* ``x`` is the **range variable**: the radial path length ``x = Z rho(u, v)`` with
  ``rho = |(x_n, y_n, 1)|`` the length of the pixel's undistorted ray (a continuous-wave ToF
  camera's range error is a function of the light's path, not of Z), or ``x = Z``.
* ``a`` is piecewise linear on knots over the training range of ``x`` and **constant beyond
  them** (no extrapolated trend). One knot: a constant; two knots: constant + gain.
* ``s`` is a bilinear grid over the image with a membrane (first-difference) penalty and zero
  mean, so that where the board never was it is the bounded harmonic continuation of the
  observed border, never an extrapolated polynomial (``support == 0`` flags those nodes).
* ``g`` (optional) is a second membrane grid, the per-pixel change of the correction per metre
  of range (a deformation that grows with range, or a Z conversion made with other
  intrinsics); ``zeta(x) = (clip(x, lo, hi) - x_ref) / 1000`` is clamped to the training range.

:class:`ModelSpec` names one candidate of this family; :func:`fit_board_model` fits it;
:func:`to_depth_calibration` turns a fitted model into the calibration core's
``DepthCalibration`` (range curve + per-pixel surfaces interpolated in measured depth).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scipy import sparse
from scipy.linalg import cho_factor, cho_solve

from tofmetry.calibrate._model import DepthCalibration
from tofmetry.calibrate._support import CalibrationSupport
from tofmetry.sensor import CameraIntrinsics
from tofmetry.errors import EstimationError, InputError

RANGE_VARIABLES = ("radial", "z")


@dataclass(frozen=True)
class ModelSpec:
    """One candidate model of the family ``a(x) + s(u, v) + zeta(x) g(u, v)``.

    Attributes
    ----------
    name : label used in reports.
    range_variable : "radial" (path length ``Z rho``) or "z".
    knot_spacing_mm : spacing of the range knots [mm]; ``0`` = one knot (a constant),
        ``inf`` = two knots at the ends of the training range (constant + gain).
    surface_smooth : membrane weight of ``s`` (per sample-equivalent); None = no surface.
    gain_smooth : membrane weight of ``g``; None = no gain surface.
    grid : (Gu, Gv) surface nodes.
    range_smooth : second-difference weight of ``a``.
    complexity : rank in the ladder of candidates (simplest first), for the one-standard-error rule.
    identity : no correction at all (the candidate every other one must beat).
    """

    name: str
    range_variable: str = "radial"
    knot_spacing_mm: float = 200.0
    surface_smooth: float | None = None
    gain_smooth: float | None = None
    grid: tuple[int, int] = (17, 15)
    range_smooth: float = 1.0
    complexity: int = 0
    identity: bool = False

    def __post_init__(self) -> None:
        if self.range_variable not in RANGE_VARIABLES:
            raise InputError(f"ModelSpec.range_variable must be one of {RANGE_VARIABLES}, found {self.range_variable!r}")
        if not self.knot_spacing_mm >= 0:
            raise InputError(f"ModelSpec.knot_spacing_mm must be >= 0, found {self.knot_spacing_mm}")

    @property
    def has_surface(self) -> bool:
        return self.surface_smooth is not None

    def to_dict(self) -> dict:
        return {"name": self.name, "range_variable": self.range_variable,
                "knot_spacing_mm": None if not np.isfinite(self.knot_spacing_mm) else self.knot_spacing_mm,
                "surface_smooth": self.surface_smooth, "gain_smooth": self.gain_smooth, "grid": list(self.grid),
                "range_smooth": self.range_smooth, "complexity": self.complexity, "identity": self.identity}


def ray_length(intrinsics) -> np.ndarray:
    """(H, W) float64 ``rho = sqrt(x_n^2 + y_n^2 + 1)``: radial path length per unit of Z."""
    r = intrinsics.ray_table()
    return np.sqrt(r[..., 0] ** 2 + r[..., 1] ** 2 + 1.0)


@dataclass
class BoardDepthModel:
    """Fitted depth correction ``c(u, v, Z) = a(x) + s(u, v) + zeta(x) g(u, v)`` [mm] (module docstring).

    Attributes
    ----------
    range_variable : "radial" or "z".
    x_knots_mm : (K,) range knots [mm] (K = 1: constant); ``a`` is constant beyond the ends.
    range_mm : (K,) values of ``a`` at the knots [mm].
    grid_u, grid_v : (Gu,), (Gv,) pixel positions of the surface nodes (empty without a surface).
    surface_mm : (Gv, Gu) node values of ``s`` [mm] (zero mean), or (0, 0).
    gain_mm_per_m : (Gv, Gu) node values of ``g`` [mm per m of range], or (0, 0).
    x_ref_mm, x_lo_mm, x_hi_mm : reference and clamp range of ``zeta`` [mm] (training range of x).
    shape : (H, W) image size.
    support : (Gv, Gu) number of samples near each surface node (0 = never seen by the board).
    intrinsics : dict of the intrinsics (``rho`` of the radial variable), or None for "z".
    spec : dict of the :class:`ModelSpec` fitted.
    """

    range_variable: str
    x_knots_mm: np.ndarray
    range_mm: np.ndarray
    grid_u: np.ndarray
    grid_v: np.ndarray
    surface_mm: np.ndarray
    shape: tuple[int, int]
    gain_mm_per_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    x_ref_mm: float = 0.0
    x_lo_mm: float = 0.0
    x_hi_mm: float = 0.0
    support: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    intrinsics: dict | None = None
    spec: dict = field(default_factory=dict)

    # ----------------------------------------------------------- evaluation
    def _rho(self) -> np.ndarray | None:
        if self.range_variable != "radial":
            return None
        return ray_length(CameraIntrinsics.from_dict(self.intrinsics, source="board model intrinsics"))

    def range_value(self, u: np.ndarray, v: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
        """Range variable ``x`` [mm] at integer pixels (u, v) for measured Z [mm]."""
        z = np.asarray(z_mm, float)
        rho = self._rho()
        if rho is None:
            return z
        return z * rho[np.asarray(v, int), np.asarray(u, int)]

    def range_term(self, x_mm: np.ndarray) -> np.ndarray:
        """``a(x)`` [mm], constant beyond the knots."""
        x = np.asarray(x_mm, float)
        if len(self.x_knots_mm) == 1:
            return np.full(x.shape, float(self.range_mm[0]))
        return np.interp(x, self.x_knots_mm, self.range_mm)

    def correction(self, u: np.ndarray, v: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
        """Correction [mm] at integer pixels (u, v) for measured Z [mm] (same shapes)."""
        u = np.asarray(u)
        v = np.asarray(v)
        x = self.range_value(u, v, z_mm)
        c = self.range_term(x)
        if self.surface_mm.size:
            c = c + _bilinear_eval(self.grid_u, self.grid_v, self.surface_mm, u.astype(float), v.astype(float))
        if self.gain_mm_per_m.size:
            zeta = (np.clip(x, self.x_lo_mm, self.x_hi_mm) - self.x_ref_mm) / 1000.0
            c = c + zeta * _bilinear_eval(self.grid_u, self.grid_v, self.gain_mm_per_m, u.astype(float), v.astype(float))
        return c

    def surface_image(self) -> np.ndarray:
        """(H, W) float64 surface term ``s(u, v)`` [mm] (zeros without a surface)."""
        H, W = self.shape
        if not self.surface_mm.size:
            return np.zeros((H, W))
        vv, uu = np.mgrid[0:H, 0:W]
        return _bilinear_eval(self.grid_u, self.grid_v, self.surface_mm, uu.ravel().astype(float),
                              vv.ravel().astype(float)).reshape(H, W)

    def gain_image(self) -> np.ndarray:
        """(H, W) float64 gain term ``g(u, v)`` [mm per m] (zeros without one)."""
        H, W = self.shape
        if not self.gain_mm_per_m.size:
            return np.zeros((H, W))
        vv, uu = np.mgrid[0:H, 0:W]
        return _bilinear_eval(self.grid_u, self.grid_v, self.gain_mm_per_m, uu.ravel().astype(float),
                              vv.ravel().astype(float)).reshape(H, W)

    def correction_image(self, z_mm: float | np.ndarray) -> np.ndarray:
        """(H, W) correction [mm] for a measured Z (scalar or (H, W))."""
        H, W = self.shape
        vv, uu = np.mgrid[0:H, 0:W]
        z = np.broadcast_to(np.asarray(z_mm, float), (H, W))
        return self.correction(uu, vv, z)

    def apply(self, depth: np.ndarray) -> np.ndarray:
        """Corrected depth: (H, W) uint16 [mm] -> (H, W) uint16 [mm] (0 stays 0)."""
        d = np.asarray(depth)
        if d.shape != tuple(self.shape):
            raise InputError(f"BoardDepthModel.apply: depth {d.shape} does not match the model's {tuple(self.shape)}")
        z = d.astype(np.float64)
        out = np.clip(np.rint(z + self.correction_image(z)), 0, 65535).astype(np.uint16)
        out[d == 0] = 0
        return out

    @property
    def x_support_mm(self) -> tuple[float, float]:
        """Training range of the range variable [mm] (``a`` is clamped outside)."""
        return float(self.x_lo_mm), float(self.x_hi_mm)

    def describe(self) -> str:
        if self.spec.get("identity"):
            return "no correction"
        parts = [f"a({'radial range' if self.range_variable == 'radial' else 'Z'}): "
                 + ("constant" if len(self.x_knots_mm) == 1 else
                    "constant + gain" if len(self.x_knots_mm) == 2 else f"{len(self.x_knots_mm)} knots")]
        if self.surface_mm.size:
            parts.append(f"surface {self.surface_mm.shape[1]}x{self.surface_mm.shape[0]} nodes")
        if self.gain_mm_per_m.size:
            parts.append("gain surface")
        return ", ".join(parts)

    def to_dict(self) -> dict:
        return {"model": "board_range_surface", "range_variable": self.range_variable, "x_knots_mm": self.x_knots_mm,
                "range_mm": self.range_mm, "grid_u": self.grid_u, "grid_v": self.grid_v, "surface_mm": self.surface_mm,
                "gain_mm_per_m": self.gain_mm_per_m, "x_ref_mm": self.x_ref_mm, "x_lo_mm": self.x_lo_mm,
                "x_hi_mm": self.x_hi_mm, "shape": list(self.shape), "support": self.support,
                "intrinsics": self.intrinsics, "spec": self.spec}

    @classmethod
    def from_dict(cls, d: dict) -> "BoardDepthModel":
        try:
            return cls(str(d["range_variable"]), np.asarray(d["x_knots_mm"], float), np.asarray(d["range_mm"], float),
                       np.asarray(d["grid_u"], float), np.asarray(d["grid_v"], float),
                       np.asarray(d["surface_mm"], float).reshape(np.shape(d["surface_mm"])), tuple(d["shape"]),
                       np.asarray(d.get("gain_mm_per_m", np.zeros((0, 0))), float), float(d.get("x_ref_mm", 0.0)),
                       float(d.get("x_lo_mm", 0.0)), float(d.get("x_hi_mm", 0.0)),
                       np.asarray(d.get("support", np.zeros((0, 0))), float), d.get("intrinsics"), dict(d.get("spec", {})))
        except KeyError as exc:
            raise InputError(f"board depth model: missing key {exc}") from None


# ----------------------------------------------------------------------------- bilinear grid
def _bilinear_weights(gx: np.ndarray, gy: np.ndarray, u: np.ndarray, v: np.ndarray):
    """Indices (N, 4) into the flattened (Gv, Gu) grid and weights (N, 4)."""
    fu = np.clip(np.interp(u, gx, np.arange(len(gx))), 0, len(gx) - 1 - 1e-9)
    fv = np.clip(np.interp(v, gy, np.arange(len(gy))), 0, len(gy) - 1 - 1e-9)
    i0, j0 = np.floor(fu).astype(int), np.floor(fv).astype(int)
    a, b = fu - i0, fv - j0
    G = len(gx)
    idx = np.stack([j0 * G + i0, j0 * G + i0 + 1, (j0 + 1) * G + i0, (j0 + 1) * G + i0 + 1], 1)
    w = np.stack([(1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b], 1)
    return idx, w


def _bilinear_eval(gx, gy, grid, u, v) -> np.ndarray:
    idx, w = _bilinear_weights(gx, gy, np.ravel(u), np.ravel(v))
    return np.sum(grid.ravel()[idx] * w, axis=1).reshape(np.shape(u))


def _membrane(Gu: int, Gv: int, offset: int, n_cols: int):
    """First-difference operator over a (Gv, Gu) grid whose unknowns start at ``offset``."""
    node = np.arange(Gu * Gv).reshape(Gv, Gu)
    pairs = np.concatenate([np.stack([node[:, :-1].ravel(), node[:, 1:].ravel()], 1),
                            np.stack([node[:-1].ravel(), node[1:].ravel()], 1)])
    m = len(pairs)
    return sparse.csr_matrix((np.concatenate([np.ones(m), -np.ones(m)]),
                              (np.concatenate([np.arange(m)] * 2), offset + np.concatenate([pairs[:, 0], pairs[:, 1]]))),
                             shape=(m, n_cols))


def range_knots(x_mm: np.ndarray, spacing_mm: float) -> np.ndarray:
    """Knots over the 1st-99th percentile of ``x`` at about ``spacing_mm`` (one knot for 0,
    two for ``inf``), at least 0.5 mm apart."""
    lo, hi = np.percentile(np.asarray(x_mm, float), [1, 99])
    if spacing_mm == 0:
        return np.array([0.5 * (lo + hi)])
    if hi - lo < 1.0:
        return np.array([0.5 * (lo + hi)])
    if not np.isfinite(spacing_mm):
        return np.array([lo, hi])
    n = int(np.clip(round((hi - lo) / spacing_mm) + 1, 2, 16))
    return np.linspace(lo, hi, n)


def fit_board_model(u: np.ndarray, v: np.ndarray, measured_mm: np.ndarray, reference_mm: np.ndarray,
                    shape: tuple[int, int], spec: ModelSpec | None = None, *, intrinsics=None,
                    weights: np.ndarray | None = None) -> BoardDepthModel:
    """Penalised least-squares fit of ``reference - measured = c(u, v, Z_measured)``.

    Parameters
    ----------
    u, v : (N,) int pixel coordinates; measured_mm, reference_mm : (N,) [mm] (Z).
    shape : (H, W) image size.
    spec : the candidate model (default: radial range spline + surface, :class:`ModelSpec`).
    intrinsics : CameraIntrinsics of the reference (required for the radial range variable).
    weights : (N,) optional sample weights (e.g. one pose's weight spread over its pixels).

    Returns
    -------
    BoardDepthModel

    Notes
    -----
    Penalty weights are per sample-equivalent and scaled by ``sqrt(N / nodes)`` so that the
    balance does not depend on the number of samples. ``s`` has zero mean (hard penalty) so the
    constant lives in ``a``; ``g`` has zero mean at ``x_ref`` by construction of ``zeta`` and its
    mean is left to ``a`` through the same hard penalty.
    """
    spec = spec or ModelSpec("spline+surface", surface_smooth=3.0)
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    z = np.asarray(measured_mm, float)
    y = np.asarray(reference_mm, float) - z
    N = len(y)
    if N < 20:
        raise EstimationError(f"too few board samples to fit a depth model ({N})")
    H, W = shape
    rho = None
    if spec.range_variable == "radial":
        if intrinsics is None:
            raise InputError("fit_board_model: the radial range variable needs the intrinsics")
        rho = ray_length(intrinsics)
        x = z * rho[v.astype(int), u.astype(int)]
    else:
        x = z
    knots = range_knots(x, spec.knot_spacing_mm)
    if spec.identity:
        lo, hi = float(np.percentile(x, 1)), float(np.percentile(x, 99))
        return BoardDepthModel(spec.range_variable, np.array([0.5 * (lo + hi)]), np.zeros(1), np.zeros(0), np.zeros(0),
                               np.zeros((0, 0)), (H, W), x_ref_mm=float(np.median(x)), x_lo_mm=lo, x_hi_mm=hi,
                               intrinsics=intrinsics.to_dict() if rho is not None else None, spec=spec.to_dict())
    K = len(knots)
    rows = np.arange(N)
    if K == 1:
        A_range = sparse.csr_matrix((np.ones(N), (rows, np.zeros(N, int))), shape=(N, 1))
    else:
        fz = np.clip(np.interp(x, knots, np.arange(K)), 0, K - 1 - 1e-9)
        k0 = np.floor(fz).astype(int)
        a = fz - k0
        A_range = sparse.csr_matrix((np.concatenate([1 - a, a]), (np.concatenate([rows, rows]),
                                                                  np.concatenate([k0, k0 + 1]))), shape=(N, K))
    blocks = [A_range]
    Gu, Gv = spec.grid
    gx, gy = np.linspace(0, W - 1, Gu), np.linspace(0, H - 1, Gv)
    G = Gu * Gv
    idx = w = None
    if spec.has_surface or spec.gain_smooth is not None:
        idx, w = _bilinear_weights(gx, gy, u, v)
    x_lo, x_hi = (float(np.percentile(x, 1)), float(np.percentile(x, 99)))
    x_ref = float(np.median(x))
    if spec.has_surface:
        blocks.append(sparse.csr_matrix((w.ravel(), (np.repeat(rows, 4), idx.ravel())), shape=(N, G)))
    if spec.gain_smooth is not None:
        zeta = (np.clip(x, x_lo, x_hi) - x_ref) / 1000.0
        blocks.append(sparse.csr_matrix(((w * zeta[:, None]).ravel(), (np.repeat(rows, 4), idx.ravel())), shape=(N, G)))
    A = sparse.hstack(blocks).tocsr()
    P = A.shape[1]
    if weights is not None:
        sw = np.sqrt(np.asarray(weights, float))
        A = sparse.diags(sw) @ A
        y = y * sw
        n_eff = float(np.sum(weights))
    else:
        n_eff = float(N)
    pen = []
    off = K
    if spec.has_surface:
        pen.append(_membrane(Gu, Gv, off, P) * (spec.surface_smooth * np.sqrt(n_eff / G)))
        pen.append(sparse.csr_matrix((np.ones(G), (np.zeros(G, int), off + np.arange(G))), shape=(1, P))
                   * (10.0 * np.sqrt(n_eff)))
        off += G
    if spec.gain_smooth is not None:
        pen.append(_membrane(Gu, Gv, off, P) * (spec.gain_smooth * np.sqrt(n_eff / G)))
        pen.append(sparse.csr_matrix((np.ones(G), (np.zeros(G, int), off + np.arange(G))), shape=(1, P))
                   * (10.0 * np.sqrt(n_eff)))
    if K > 2 and spec.range_smooth > 0:
        mk = K - 2
        pen.append(sparse.csr_matrix((np.concatenate([np.ones(mk), -2 * np.ones(mk), np.ones(mk)]),
                                      (np.concatenate([np.arange(mk)] * 3),
                                       np.concatenate([np.arange(mk), np.arange(mk) + 1, np.arange(mk) + 2]))),
                                     shape=(mk, P)) * (spec.range_smooth * np.sqrt(n_eff / K)))
    M = sparse.vstack([A] + pen).tocsr() if pen else A
    rhs = np.concatenate([y, np.zeros(M.shape[0] - N)])
    # few unknowns (K + 2 G at most): dense normal equations are exact and fast
    MtM = (M.T @ M).toarray()
    scale = max(1.0, float(np.max(np.diag(MtM))))
    MtM[np.diag_indices(P)] += 1e-10 * scale
    try:   # symmetric positive definite: Cholesky
        sol = cho_solve(cho_factor(MtM, check_finite=False), M.T @ rhs, check_finite=False)
    except np.linalg.LinAlgError:
        sol = np.linalg.lstsq(MtM, M.T @ rhs, rcond=None)[0]
    surf = np.zeros((0, 0))
    gain = np.zeros((0, 0))
    support = np.zeros((0, 0))
    off = K
    if idx is not None:
        support = np.bincount(idx.ravel(), weights=(w.ravel() > 0.05).astype(float), minlength=G).reshape(Gv, Gu)
    if spec.has_surface:
        surf = sol[off:off + G].reshape(Gv, Gu)
        off += G
    if spec.gain_smooth is not None:
        gain = sol[off:off + G].reshape(Gv, Gu)
    has_grid = idx is not None
    return BoardDepthModel(
        range_variable=spec.range_variable, x_knots_mm=knots, range_mm=sol[:K],
        grid_u=gx if has_grid else np.zeros(0), grid_v=gy if has_grid else np.zeros(0), surface_mm=surf,
        shape=(H, W), gain_mm_per_m=gain, x_ref_mm=x_ref, x_lo_mm=x_lo, x_hi_mm=x_hi, support=support,
        intrinsics=intrinsics.to_dict() if (intrinsics is not None and spec.range_variable == "radial") else None,
        spec=spec.to_dict(),
    )


# ----------------------------------------------------------------------------- DepthCalibration
def to_depth_calibration(model: BoardDepthModel, intrinsics, sensor: str = "unknown",
                         provenance: dict | None = None, diagnostics: dict | None = None, support=None,
                         prediction: dict | None = None, n_gain_nodes: int = 5):
    """The board model as the calibration core's ``DepthCalibration`` (exact for the range and
    surface terms; the gain surface to within its reported node interpolation error).

    * The range term ``a(x)`` becomes the core's ray term ``W = -a`` (radial variable, applied in
      Z: ``gamma = 0``, degree 1 on the same knots, clamped beyond them as ``a`` is) or its range
      curve ``R = -a`` (Z variable).
    * The surface ``s`` is one surface; with a gain surface ``g``, ``s + zeta(x) g`` is tabulated at
      ``n_gain_nodes`` depths over the training range (linear in ``d`` between them, held beyond;
      the interpolation error, from the per-pixel clamps of ``x``, is reported as
      ``diagnostics["node_interpolation_max_mm"]``).
    * ``support`` (a :class:`~tofmetry.calibrate._support.CalibrationSupport`): outside it the
      correction is held at the nearest supported depth (``fallback = "hold"``); without one the
      whole depth range is corrected with the same hold.
    """
    if tuple(intrinsics.shape) != tuple(model.shape):
        raise InputError(f"to_depth_calibration: intrinsics {intrinsics.shape} do not match the model {tuple(model.shape)}")
    k = np.asarray(model.x_knots_mm, float)
    a = -np.asarray(model.range_mm, float)
    lo_x, hi_x = (float(model.x_lo_mm), float(model.x_hi_mm)) if model.x_hi_mm > model.x_lo_mm else (k[0], k[-1])
    if len(k) == 1:
        k = np.array([lo_x - 1.0, hi_x + 1.0])
        a = np.full(2, a[0])
    t = np.concatenate([[k[0]], k, [k[-1]]])
    ray = {}
    if model.range_variable == "radial":
        ray = {"ray_knots": t, "ray_coeffs": a, "ray_degree": 1, "ray_gamma": 0.0, "ray_data_mm": np.array([k[0], k[-1]])}
        r_t, r_c, r_data = np.array([lo_x, lo_x, hi_x, hi_x]), np.zeros(2), np.array([lo_x, hi_x])
    else:
        r_t, r_c, r_data = t, a, np.array([k[0], k[-1]])
    H, W = model.shape
    rho = model._rho()
    surf_img = model.surface_image()
    interp_err = 0.0
    if model.gain_mm_per_m.size:
        gain_img = model.gain_image()
        nodes = np.linspace(lo_x / (float(rho.max()) if rho is not None else 1.0), hi_x, max(2, n_gain_nodes))

        def s_at(d):
            x = d * rho if rho is not None else np.full((H, W), float(d))
            return -(surf_img + (np.clip(x, model.x_lo_mm, model.x_hi_mm) - model.x_ref_mm) / 1000.0 * gain_img)

        surfaces = np.stack([s_at(d) for d in nodes])
        for j in range(len(nodes) - 1):
            for f in (0.25, 0.5, 0.75):
                d = nodes[j] + f * (nodes[j + 1] - nodes[j])
                lin = (1 - f) * surfaces[j] + f * surfaces[j + 1]
                interp_err = max(interp_err, float(np.max(np.abs(lin - s_at(d)))))
    else:
        nodes = np.array([0.5 * (lo_x + hi_x)])
        surfaces = -surf_img[None]
    grid = np.linspace(lo_x, hi_x, 256)
    offset = float(np.mean(np.interp(grid, k, a)))
    diag = dict(diagnostics or {})
    diag["node_interpolation_max_mm"] = interp_err
    if support is None:
        support = CalibrationSupport.everywhere(model.shape, 1.0, 65534.0)
    return DepthCalibration(
        sensor=sensor, intrinsics=intrinsics, range_knots=r_t, range_coeffs=r_c, range_degree=1,
        range_data_mm=r_data, valid_range_mm=np.array([1.0, 65534.0]), node_mm=nodes,
        surfaces=surfaces.astype(np.float32), offset_mm=offset, surface_model=f"board: {model.describe()}",
        provenance={"method": "board", **(provenance or {})}, diagnostics=diag, support=support, fallback="hold",
        prediction=dict(prediction or {}), **ray,
    )
