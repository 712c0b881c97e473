"""How far the depth calibration's per-pixel residual can move the poses of the global adjustment.

A depth calibration leaves a residual that depends on the position in the image: its deformation
surfaces are fitted between wall stations and miss what changes between them. Every view of a scan
carries the same residual field ``delta(x, y)`` (views at one range see the same one), so its
effect on the joint fit does not average out over the views: started at the true poses, the fit
ends where that field puts it. Measured with ``bench/robustness/drift.py`` (2026-11-27): noise and
the per-pixel residual alone move a box 0.47 deg and a rocker arm 0.36 deg off, where noise alone
moves them 0.12 and 0.16 deg; the scan does not determine such a field (an image-position term
fitted from the views came out at +-0.6-2.1 mm against a 0.32 mm prior).

The scan cannot remove it, so its effect is predicted from outside: the field is unknown, but its
size is the calibration's own prediction (its blocked folds: central error, per-pixel systematic
RMS). It is modelled as a sum of 2-D Legendre polynomials in the normalised image coordinates
(``x / z``, ``y / z`` over the half field of view), degree <= ``degree``, with independent
zero-mean coefficients: the constant one with the central error as standard deviation, the
others sharing the per-pixel RMS equally. The joint fit is linear in the field to first order:
a field with coefficients ``c`` moves its unknowns by ``dx = -H^-1 F c`` (``H``: the normal matrix
it solved, priors included; ``F = J^T W B``: the correspondences' response to each basis field,
:func:`tofmetry.reconstruct._adjust_terms._normal_equations`). :func:`pose_spread` draws ``c`` and
judges each draw's poses as the family judges a run: the whole set aligned on the object (the
small-motion mean removed), rotation and largest displacement of the object's points per view,
the worst view per draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import legendre


@dataclass(frozen=True)
class DepthFieldPrior:
    """Size of the per-pixel depth residual a calibration leaves (module docstring).

    Attributes
    ----------
    half_extent : (ax, ay) half the field of view in normalised image coordinates (``x / z``,
        ``y / z`` at the image border), dimensionless
    offset_sigma_m : standard deviation of the field's mean (the calibration's central error) [m]
    shape_rms_m : RMS over the image of the rest (the calibration's per-pixel systematic RMS) [m]
    degree : highest total degree of the Legendre products
    tilt_sigma_m : standard deviation of a term linear in the image position the calibration did
        not calibrate, ``a x + b y`` [m per unit of ``x / z``] (walls of unknown orientation cannot
        show it, and the RMS of its folds leaves it out); 0 when it was calibrated
    gain_sigma : standard deviation of the depth gain the calibration can leave between its
        stations, ``dz = g (Z - z_ref)`` (dimensionless; its central error over half the station
        spacing, as the scale budget takes it); 0: no range term. A residual that changes with the
        range is the same in every view but not a function of the image position: over an object's
        depth span its linear part stretches each view along its own line of sight, which the views
        of a turntable take up as one tilt of every camera about its own x axis (measured: noise and
        the calibration's residual range error alone put a 16-view pebble 0.75 deg off, every view
        -0.70 to -0.73 deg about its x axis, where the image-position field predicted 0.27 deg at p90)
    z_ref_m : depth where that term is zero [m] (the adjustment's ``z_ref``)
    """

    half_extent: tuple[float, float]
    offset_sigma_m: float
    shape_rms_m: float
    degree: int = 3
    tilt_sigma_m: float = 0.0
    gain_sigma: float = 0.0
    z_ref_m: float = 0.0

    def terms(self) -> list[tuple[int, int]]:
        return [(i, k - i) for k in range(self.degree + 1) for i in range(k + 1)]

    def coefficient_sigmas(self) -> np.ndarray:
        """(T,) standard deviation of each term's coefficient [m; the gain's, last when
        ``gain_sigma`` > 0, dimensionless]: the constant term's is the
        offset's; the others share ``shape_rms_m`` so that the field's expected mean square over
        the image is ``offset^2 + shape_rms^2`` (``<L_i^2 L_k^2> = 1 / ((2i + 1) (2k + 1))``), and
        the two linear terms carry ``tilt_sigma_m`` as well."""
        t = self.terms()
        n_shape = max(len(t) - 1, 1)
        s = np.array([self.offset_sigma_m if (i, k) == (0, 0) else
                      self.shape_rms_m * np.sqrt((2 * i + 1) * (2 * k + 1) / n_shape) for i, k in t])
        for j, (i, k) in enumerate(t):  # a x = (a ax) L1(x / ax): the tilt's coefficient at the image edge
            if (i, k) in ((1, 0), (0, 1)):
                s[j] = np.hypot(s[j], self.tilt_sigma_m * self.half_extent[0 if i else 1])
        return np.r_[s, self.gain_sigma] if self.gain_sigma > 0 else s

    def basis(self, points_cam: np.ndarray) -> np.ndarray:
        """(M, T) value of each term at camera-frame points (M, 3) [m] (dimensionless; the gain's,
        last when ``gain_sigma`` > 0, is ``Z - z_ref`` [m])."""
        p = np.asarray(points_cam, np.float64)
        u = np.clip(p[:, 0] / p[:, 2] / self.half_extent[0], -1.0, 1.0)
        v = np.clip(p[:, 1] / p[:, 2] / self.half_extent[1], -1.0, 1.0)
        eye = np.eye(self.degree + 1)
        Lu = np.stack([legendre.legval(u, eye[i]) for i in range(self.degree + 1)], 1)
        Lv = np.stack([legendre.legval(v, eye[i]) for i in range(self.degree + 1)], 1)
        B = np.stack([Lu[:, i] * Lv[:, k] for i, k in self.terms()], 1)
        return np.c_[B, p[:, 2] - self.z_ref_m] if self.gain_sigma > 0 else B


def pose_spread(response: np.ndarray, coef_sigma: np.ndarray, V: int, object_points_w: np.ndarray,
                n_draws: int = 400, seed: int = 0, noise_cov: np.ndarray | None = None) -> dict:
    """Spread of the poses under random fields of the prior (module docstring).

    Parameters
    ----------
    response : (6 (V - 1), T) move of the poses' left increments (rotation vector [rad],
        translation [m], view 0 fixed) per unit coefficient of each term [1 / m]
    coef_sigma : (T,) standard deviation of each coefficient [m]
    V : number of views
    object_points_w : (N, 3) object points, world frame [m] (at most a few hundred are used)
    n_draws : fields drawn (seeded)
    noise_cov : (6 (V - 1), 6 (V - 1)) covariance of the same increments from the data's noise
        [rad^2, m^2], or None. The field and the noise are independent: a run's pose error is their
        sum, and the field alone under-reads it where the calibration is good (the family's draw
        29, 2026-11-29: the field's p90 covered 3 of 8 reliable runs, its worst view 0.04-0.15 deg
        against 0.04-0.23 deg measured)

    Returns
    -------
    dict: ``rot_deg`` and ``object_mm``, each with ``p50`` and ``p90`` of the worst view per draw
    (the whole set aligned on the object), and ``per_view_sigma_deg`` / ``per_view_sigma_mm`` (RMS
    over the draws, per view, in the same alignment), all of the field alone; ``with_noise``: the
    same ``rot_deg`` and ``object_mm`` of the field plus a draw of the noise (when ``noise_cov``)
    """
    X = np.asarray(object_points_w, np.float64)
    X = X[np.linspace(0, len(X) - 1, min(len(X), 300)).astype(np.int64)]
    rng = np.random.default_rng(seed)
    c = rng.standard_normal((n_draws, len(coef_sigma))) * coef_sigma
    inc = c @ response.T  # (D, 6 (V - 1))
    out = _judge(inc, V, X)
    if noise_cov is not None and noise_cov.shape == (6 * (V - 1),) * 2 and np.all(np.isfinite(noise_cov)):
        w, U = np.linalg.eigh(0.5 * (noise_cov + noise_cov.T))
        noise = (rng.standard_normal((n_draws, len(w))) * np.sqrt(np.clip(w, 0, None))) @ U.T
        both = _judge(inc + noise, V, X)
        out["with_noise"] = {"rot_deg": both["rot_deg"], "object_mm": both["object_mm"]}
    return out


def _judge(inc: np.ndarray, V: int, X: np.ndarray) -> dict:
    """The worst view's rotation [deg] and object displacement [mm] per draw of the increments
    ``inc`` (D, 6 (V - 1)), the whole set aligned on the object: p50 / p90, and per-view RMS."""
    n_draws = len(inc)
    dx = np.zeros((n_draws, V, 6))
    dx[:, 1:] = inc.reshape(n_draws, V - 1, 6)
    dx -= dx.mean(1, keepdims=True)  # small-motion alignment of the whole set on the object
    w, t = dx[..., :3], dx[..., 3:]
    rot = np.degrees(np.linalg.norm(w, axis=2))  # (D, V)
    # displacement of each object point: w x X + t, its largest norm per view
    disp = np.cross(w[:, :, None, :], X[None, None]) + t[:, :, None, :]
    obj = np.linalg.norm(disp, axis=3).max(2) * 1e3  # (D, V)
    worst_r, worst_o = rot.max(1), obj.max(1)
    q = lambda a: {"p50": round(float(np.percentile(a, 50)), 4), "p90": round(float(np.percentile(a, 90)), 4)}
    return {"rot_deg": q(worst_r), "object_mm": q(worst_o),
            "per_view_sigma_deg": np.sqrt(np.mean(rot ** 2, 0)).round(4).tolist(),
            "per_view_sigma_mm": np.sqrt(np.mean(obj ** 2, 0)).round(3).tolist(), "n_draws": int(n_draws)}
