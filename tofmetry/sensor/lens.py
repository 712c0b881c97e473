"""Lens distortion models on normalised coordinates (pure functions on arrays).

Three models, each with the coefficient order of OpenCV so that the arrays pass unchanged to
``cv2.projectPoints`` / ``cv2.undistortPoints`` (``brown``, ``rational``) or to ``cv2.fisheye``
(``fisheye``):

``brown`` ``(k1, k2, p1, p2, k3)``
    :math:`\\rho = 1 + k_1 r^2 + k_2 r^4 + k_3 r^6`, plus the tangential terms below.
``rational`` ``(k1, k2, p1, p2, k3, k4, k5, k6)``
    :math:`\\rho = (1 + k_1 r^2 + k_2 r^4 + k_3 r^6) / (1 + k_4 r^2 + k_5 r^4 + k_6 r^6)`
    (OpenCV ``CALIB_RATIONAL_MODEL``; the Azure Kinect factory model). Brown is the special case
    ``k4 = k5 = k6 = 0``.

    .. math::
       x_d = x\\rho + 2p_1xy + p_2(r^2+2x^2),\\quad y_d = y\\rho + p_1(r^2+2y^2) + 2p_2xy
``fisheye`` ``(k1, k2, k3, k4)`` (Kannala–Brandt, as ``cv2.fisheye``)
    :math:`\\theta = \\arctan r,\\ \\theta_d = \\theta(1 + k_1\\theta^2 + k_2\\theta^4 + k_3\\theta^6
    + k_4\\theta^8),\\ (x_d, y_d) = (\\theta_d / r)(x, y)`.

Here ``(x, y) = (X/Z, Y/Z)`` are undistorted normalised coordinates of a camera-frame point
(x right, y down, z forward) and ``r^2 = x^2 + y^2``; pixels are ``u = fx x_d + cx``,
``v = fy y_d + cy``. The inverses are Newton iterations to ~1e-15; where an inverse does not
converge (outside the region where the model is one-to-one) the result is NaN.
"""

from __future__ import annotations

import numpy as np

from tofmetry.errors import InputError

#: model name -> number of coefficients (OpenCV order)
MODELS: dict[str, int] = {"brown": 5, "rational": 8, "fisheye": 4}
LENS_MODELS = tuple(MODELS)
#: coefficient names per model, in array order
COEFFICIENT_NAMES: dict[str, tuple[str, ...]] = {
    "brown": ("k1", "k2", "p1", "p2", "k3"),
    "rational": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "fisheye": ("k1", "k2", "k3", "k4"),
}


def check_model(model: str, coeffs, source: str = "intrinsics") -> np.ndarray:
    """Validate a model name and its coefficients; returns them as a (n,) float64 array.

    A Brown model given 4 coefficients gets ``k3 = 0``; a rational model given the 5 Brown
    coefficients gets ``k4 = k5 = k6 = 0``.

    Raises
    ------
    InputError
        Unknown model, wrong number of coefficients or a non-finite one (names ``source``).
    """
    if model not in MODELS:
        raise InputError(f"{source}: unknown lens model {model!r}; expected one of {sorted(MODELS)}")
    d = np.asarray(coeffs, dtype=np.float64).ravel()
    if model == "brown" and d.size == 4:
        d = np.append(d, 0.0)
    if model == "rational" and d.size == 5:
        d = np.append(d, np.zeros(3))
    if d.size != MODELS[model]:
        raise InputError(f"{source}: distortion of the {model} lens model needs {MODELS[model]} coefficients "
                         f"[{', '.join(COEFFICIENT_NAMES[model])}], found {d.size}")
    if not np.all(np.isfinite(d)):
        raise InputError(f"{source}: distortion must be finite, found {d.tolist()}")
    return d


def _rational8(model: str, d: np.ndarray) -> tuple:
    if model == "brown":
        k1, k2, p1, p2, k3 = d
        return k1, k2, p1, p2, k3, 0.0, 0.0, 0.0
    return tuple(d)


def distort(xy: np.ndarray, model: str, d: np.ndarray) -> np.ndarray:
    """Undistorted -> distorted normalised coordinates.

    Parameters
    ----------
    xy : (N, 2) float64, undistorted normalised ``(X/Z, Y/Z)``
    model : ``"brown"``, ``"rational"`` or ``"fisheye"``
    d : (n,) coefficients in the model's order

    Returns
    -------
    (N, 2) float64 distorted normalised coordinates.
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    x, y = xy[:, 0], xy[:, 1]
    if model == "fisheye":
        r = np.hypot(x, y)
        th = np.arctan(r)
        th2 = th * th
        thd = th * (1 + th2 * (d[0] + th2 * (d[1] + th2 * (d[2] + th2 * d[3]))))
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.where(r > 1e-12, thd / r, 1.0)
        return np.column_stack([x * s, y * s])
    k1, k2, p1, p2, k3, k4, k5, k6 = _rational8(model, d)
    r2 = x * x + y * y
    rad = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([xd, yd])


def undistort(xy_d: np.ndarray, model: str, d: np.ndarray, iterations: int = 30) -> np.ndarray:
    """Distorted -> undistorted normalised coordinates (inverse of :func:`distort`).

    Parameters
    ----------
    xy_d : (N, 2) float64 distorted normalised coordinates
    model, d : as :func:`distort`
    iterations : Newton iterations at most

    Returns
    -------
    (N, 2) float64 undistorted normalised coordinates; NaN where the iteration did not converge
    to 1e-9 (a point outside the region where the model can be inverted).
    """
    xy_d = np.asarray(xy_d, dtype=np.float64).reshape(-1, 2)
    if model == "fisheye":
        out = _undistort_fisheye(xy_d, d, iterations)
    else:
        out = _undistort_rational(xy_d, _rational8(model, d), iterations)
    with np.errstate(invalid="ignore"):
        back = distort(out, model, d)
        bad = ~(np.abs(back - xy_d).max(axis=1) < 1e-9)
    out[bad] = np.nan
    return out


def _undistort_rational(xy_d: np.ndarray, d: tuple, iterations: int) -> np.ndarray:
    k1, k2, p1, p2, k3, k4, k5, k6 = d
    xd, yd = xy_d[:, 0], xy_d[:, 1]
    r2d = xd * xd + yd * yd
    rad0 = (1 + r2d * (k1 + r2d * (k2 + r2d * k3))) / (1 + r2d * (k4 + r2d * (k5 + r2d * k6)))
    rad0 = np.where(rad0 > 0.1, rad0, 1.0)
    x, y = xd / rad0, yd / rad0
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for _ in range(iterations):
            r2 = x * x + y * y
            num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
            rad = num / den
            dnum = k1 + r2 * (2 * k2 + 3 * k3 * r2)
            dden = k4 + r2 * (2 * k5 + 3 * k6 * r2)
            drad = (dnum * den - num * dden) / (den * den)  # d rad / d r2
            fx = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
            fy = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
            j11 = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
            j12 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            j22 = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
            det = j11 * j22 - j12 * j12
            dx = (j22 * fx - j12 * fy) / det
            dy = (-j12 * fx + j11 * fy) / det
            x = x - dx
            y = y - dy
            if not (np.nanmax(np.abs(dx) + np.abs(dy), initial=0.0) >= 1e-15):
                break
    return np.column_stack([x, y])


def _undistort_fisheye(xy_d: np.ndarray, d: np.ndarray, iterations: int) -> np.ndarray:
    k1, k2, k3, k4 = d
    thd = np.hypot(xy_d[:, 0], xy_d[:, 1])
    th = np.minimum(thd, np.pi / 2)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for _ in range(iterations):
            t2 = th * th
            f = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - thd
            df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            step = f / df
            th = th - step
            if not (np.nanmax(np.abs(step), initial=0.0) >= 1e-15):
                break
        th = np.where((th >= 0) & (th < np.pi / 2), th, np.nan)
        s = np.where(thd > 1e-12, np.tan(th) / thd, 1.0)
    return xy_d * s[:, None]
