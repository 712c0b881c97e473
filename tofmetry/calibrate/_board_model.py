"""Board depth-correction model: ``c(u, v, Z) = a(Z) + s(u, v)`` (see :mod:`tofmetry.calibrate.board`).

``a`` is piecewise linear in measured Z; ``s`` a bilinear grid over the image with a membrane
(first-difference) penalty and zero mean, so that where the board never was ``s`` is the
smooth continuation of the observed border (flagged by ``support == 0``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tofmetry.errors import EstimationError, InputError


@dataclass
class BoardDepthModel:
    """Depth correction ``c(u, v, Z) = a(Z) + s(u, v)`` [mm], added to measured depth.

    Attributes
    ----------
    z_knots_mm : (K,) range knots [mm]; ``a`` is piecewise linear, constant beyond the ends.
    range_mm : (K,) values of ``a`` at the knots [mm].
    grid_u, grid_v : (Gu,), (Gv,) pixel positions of the surface nodes.
    surface_mm : (Gv, Gu) surface node values [mm] (zero mean), bilinear in between.
    shape : (H, W) image size the model applies to.
    support : (Gv, Gu) number of samples influencing each node (0 = never seen by the board).
    """

    z_knots_mm: np.ndarray
    range_mm: np.ndarray
    grid_u: np.ndarray
    grid_v: np.ndarray
    surface_mm: np.ndarray
    shape: tuple[int, int]
    support: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def correction(self, u: np.ndarray, v: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
        """Correction [mm] at pixels (u, v) (float or int) for measured Z [mm]."""
        a = np.interp(np.asarray(z_mm, float), self.z_knots_mm, self.range_mm)
        return a + _bilinear_eval(self.grid_u, self.grid_v, self.surface_mm, np.asarray(u, float), np.asarray(v, float))

    def surface_image(self) -> np.ndarray:
        """(H, W) float64 surface term s(u, v) [mm]."""
        H, W = self.shape
        vv, uu = np.mgrid[0:H, 0:W]
        return _bilinear_eval(self.grid_u, self.grid_v, self.surface_mm, uu.ravel().astype(float),
                              vv.ravel().astype(float)).reshape(H, W)

    def apply(self, depth: np.ndarray) -> np.ndarray:
        """Corrected depth: (H, W) uint16 [mm] -> (H, W) uint16 [mm] (0 stays 0)."""
        d = np.asarray(depth)
        if d.shape != tuple(self.shape):
            raise InputError(f"BoardDepthModel.apply: depth {d.shape} does not match the model's {tuple(self.shape)}")
        z = d.astype(np.float64)
        out = z + np.interp(z, self.z_knots_mm, self.range_mm) + self.surface_image()
        out = np.clip(np.rint(out), 0, 65535).astype(np.uint16)
        out[d == 0] = 0
        return out

    def to_dict(self) -> dict:
        return {"model": "board_range_surface", "z_knots_mm": self.z_knots_mm, "range_mm": self.range_mm,
                "grid_u": self.grid_u, "grid_v": self.grid_v, "surface_mm": self.surface_mm,
                "shape": list(self.shape), "support": self.support}

    @classmethod
    def from_dict(cls, d: dict) -> "BoardDepthModel":
        try:
            return cls(np.asarray(d["z_knots_mm"], float), np.asarray(d["range_mm"], float), np.asarray(d["grid_u"], float),
                       np.asarray(d["grid_v"], float), np.asarray(d["surface_mm"], float), tuple(d["shape"]),
                       np.asarray(d.get("support", np.zeros((0, 0))), float))
        except KeyError as exc:
            raise InputError(f"board depth model: missing key {exc}") from None


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
    idx, w = _bilinear_weights(gx, gy, u.ravel(), v.ravel())
    return np.sum(grid.ravel()[idx] * w, axis=1).reshape(np.shape(u))


def fit_board_model(u: np.ndarray, v: np.ndarray, measured_mm: np.ndarray, reference_mm: np.ndarray,
                    shape: tuple[int, int], n_knots: int = 6, grid: tuple[int, int] = (17, 15),
                    smooth_surface: float = 3.0, smooth_range: float = 1.0) -> BoardDepthModel:
    """Least-squares fit of ``reference - measured = a(Z_measured) + s(u, v)``.

    Parameters
    ----------
    u, v : (N,) pixel coordinates; measured_mm, reference_mm : (N,) [mm].
    shape : (H, W) image size.
    n_knots : range knots spread over the 1st-99th percentile of measured Z.
    grid : (Gu, Gv) surface nodes.
    smooth_surface, smooth_range : penalty weights [per sample-equivalent], scaled by sqrt(N / nodes)
        so the balance does not depend on the number of samples.

    Notes
    -----
    ``s`` has zero mean (hard penalty) so the constant lives in ``a``. Nodes the board never
    reached are fixed only by the membrane penalty: they take the smooth continuation of their
    neighbours (flat far from data), with ``support`` = 0 flagging them.
    """
    from scipy import sparse

    u = np.asarray(u, float)
    v = np.asarray(v, float)
    z = np.asarray(measured_mm, float)
    r = np.asarray(reference_mm, float) - z
    N = len(r)
    if N < 100:
        raise EstimationError(f"too few board samples to fit a depth model ({N})")
    H, W = shape
    Gu, Gv = grid
    gx = np.linspace(0, W - 1, Gu)
    gy = np.linspace(0, H - 1, Gv)
    zlo, zhi = np.percentile(z, [1, 99])
    knots = np.linspace(zlo, zhi, max(2, n_knots)) if zhi > zlo + 1 else np.array([zlo - 1, zlo + 1])
    K = len(knots)
    # range: hat functions
    fz = np.clip(np.interp(z, knots, np.arange(K)), 0, K - 1 - 1e-9)
    k0 = np.floor(fz).astype(int)
    a = fz - k0
    rows = np.arange(N)
    A_range = sparse.csr_matrix((np.concatenate([1 - a, a]), (np.concatenate([rows, rows]), np.concatenate([k0, k0 + 1]))),
                                shape=(N, K))
    idx, w = _bilinear_weights(gx, gy, u, v)
    A_surf = sparse.csr_matrix((w.ravel(), (np.repeat(rows, 4), idx.ravel())), shape=(N, Gu * Gv))
    A = sparse.hstack([A_range, A_surf]).tocsr()
    # penalties
    scale = np.sqrt(N / (Gu * Gv))
    pen = []
    node = np.arange(Gu * Gv).reshape(Gv, Gu)
    dx = [(node[:, i], node[:, i + 1]) for i in range(Gu - 1)]
    dy = [(node[j], node[j + 1]) for j in range(Gv - 1)]
    pairs = np.concatenate([np.stack([p, q], 1) for p, q in dx + dy])
    m = len(pairs)
    D = sparse.csr_matrix((np.concatenate([np.ones(m), -np.ones(m)]),
                           (np.concatenate([np.arange(m)] * 2), K + np.concatenate([pairs[:, 0], pairs[:, 1]]))),
                          shape=(m, K + Gu * Gv))
    pen.append(D * (smooth_surface * scale))
    if K > 2:
        mk = K - 2
        D2 = sparse.csr_matrix((np.concatenate([np.ones(mk), -2 * np.ones(mk), np.ones(mk)]),
                                (np.concatenate([np.arange(mk)] * 3), np.concatenate([np.arange(mk), np.arange(mk) + 1, np.arange(mk) + 2]))),
                               shape=(mk, K + Gu * Gv))
        pen.append(D2 * (smooth_range * np.sqrt(N / K)))
    zero_mean = sparse.csr_matrix((np.ones(Gu * Gv), (np.zeros(Gu * Gv, int), K + np.arange(Gu * Gv))), shape=(1, K + Gu * Gv))
    pen.append(zero_mean * (10.0 * np.sqrt(N)))
    M = sparse.vstack([A] + pen).tocsr()
    rhs = np.concatenate([r, np.zeros(M.shape[0] - N)])
    # few unknowns (K + Gu*Gv): dense normal equations are exact and fast
    MtM = (M.T @ M).toarray()
    sol = np.linalg.solve(MtM + 1e-9 * np.eye(len(MtM)), M.T @ rhs)
    support = np.bincount(idx.ravel(), weights=(w.ravel() > 0.05).astype(float), minlength=Gu * Gv).reshape(Gv, Gu)
    return BoardDepthModel(knots, sol[:K], gx, gy, sol[K:].reshape(Gv, Gu), (H, W), support)




def to_depth_calibration(model: BoardDepthModel, intrinsics, sensor: str = "unknown", margin_mm: float = 50.0,
                         provenance: dict | None = None, diagnostics: dict | None = None):
    """The board model as the calibration core's ``DepthCalibration`` (exact, no refit).

    ``corrected = d - R(d) - S(p)`` with ``R = -a`` (degree-1 B-spline on the same knots,
    clamped outside them, as ``a`` is) and one surface ``S = -s``. Depths outside the knots
    +- ``margin_mm`` are left unchanged (the core's ``valid_range_mm`` convention): the board
    gives no evidence there.
    """
    from tofmetry.calibrate._model import DepthCalibration

    if tuple(intrinsics.shape) != tuple(model.shape):
        raise InputError(f"to_depth_calibration: intrinsics {intrinsics.shape} do not match the model {tuple(model.shape)}")
    k = np.asarray(model.z_knots_mm, float)
    t = np.concatenate([[k[0]], k, [k[-1]]])
    coeffs = -np.asarray(model.range_mm, float)
    grid = np.linspace(k[0], k[-1], 512)
    offset = float(np.mean(np.interp(grid, k, coeffs)))
    vr = (max(1.0, k[0] - margin_mm), min(65535.0, k[-1] + margin_mm))
    return DepthCalibration(
        sensor=sensor, intrinsics=intrinsics, range_knots=t, range_coeffs=coeffs, range_degree=1,
        range_data_mm=np.array([k[0], k[-1]]), valid_range_mm=np.array(vr), node_mm=np.array([float(np.mean(k))]),
        surfaces=(-model.surface_image())[None].astype(np.float32), offset_mm=offset, surface_model="board-grid",
        provenance={"method": "board", **(provenance or {})}, diagnostics=dict(diagnostics or {}),
    )
