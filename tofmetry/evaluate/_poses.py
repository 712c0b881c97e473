"""Pose errors in the object's frame and the scale of a model against a reference.

Pose errors (simulated data, where the true camera poses are known): a camera pose error
matters through where it puts the object's surface, not through where it puts the camera.
A rotation error of 0.1 deg moves a camera 1 m from the object by 1.7 mm at its centre but
moves the object's points only by the angle times their distance from the rotation's axis;
conversely a pose can sit right at the camera and still be wrong on the object. So the
estimated poses are first carried into the true world by the one rigid transform that best
maps every view's object points back where they belong (least squares over all views and all
object points: the model's own frame is arbitrary), and each view's error is then measured as

* ``object_mm``: the largest displacement of the object's points (the reference vertices)
  under that view's remaining error (what the view's data are off by on the object);
* ``object_rms_mm``: their RMS displacement;
* ``camera_mm``: the displacement of the camera centre;
* ``rot_deg``: the rotation angle of the remaining error.

Scale (:func:`scale_from_reference`): the model, already rigidly aligned to the reference, is
fitted once more with a uniform scale about its centroid and a uniform offset along the
reference normals (point-to-plane, 8 parameters, Huber weights, inliers within a few
millimetres, iterated on new closest points). The offset matters: a range read 0.5 mm short
moves every surface 0.5 mm toward the cameras that saw it, which shrinks an object seen from
all around by 0.5 mm on every side: 0.5 % of a 0.1 m radius if it were read as a scale. The
scale factor minus one is the model's scale error, the offset its surface offset; their
correlation comes from the normal equations (they are degenerate on a sphere), their standard
errors from the normal equations (noise) and from the estimate's spread over the model's regions
(a delete-one-region jackknife): a model's surface errors vary over the object (a rim read a few
tenths of a millimetre inward, a face bent by the range error), and on a shape that barely tells
scale from offset (a dome, correlation 0.95-0.98) they move the scale by tenths of a per cent
where the noise alone would say thousandths.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.cluster.vq import kmeans2, vq

from tofmetry._shared.geometry import (SCALE_OFFSET_MAX_CORRELATION, displacement_at, rotation_angle_deg,
                                       similarity_offset_jacobian)
from tofmetry.errors import InputError


@dataclass
class PoseErrors:
    """Per-view pose errors (see the module docstring).

    Attributes
    ----------
    rot_deg : (V,) rotation error [deg]
    object_mm : (V,) largest displacement of the object's points [mm]
    object_rms_mm : (V,) RMS displacement of the object's points [mm]
    camera_mm : (V,) displacement of the camera centre [mm]
    alignment : (4, 4) estimated world -> true world (the best rigid fit over all views)
    """

    rot_deg: np.ndarray
    object_mm: np.ndarray
    object_rms_mm: np.ndarray
    camera_mm: np.ndarray
    alignment: np.ndarray

    def to_dict(self) -> dict:
        return {"rot_deg": [round(float(x), 4) for x in self.rot_deg],
                "object_mm": [round(float(x), 3) for x in self.object_mm],
                "object_rms_mm": [round(float(x), 3) for x in self.object_rms_mm],
                "camera_mm": [round(float(x), 3) for x in self.camera_mm],
                "max": {"rot_deg": float(self.rot_deg.max()), "object_mm": float(self.object_mm.max()),
                        "camera_mm": float(self.camera_mm.max())}}


def _kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(4, 4) rigid transform minimising sum |T src - dst|^2."""
    cs, cd = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, cd - R @ cs
    return T


def pose_errors(poses, true_poses, object_points: np.ndarray, max_points: int = 2000) -> PoseErrors:
    """Errors of estimated camera poses in the object's frame (module docstring).

    Parameters
    ----------
    poses : (V, 4, 4) estimated camera-to-world [m] (any world frame)
    true_poses : (V, 4, 4) true camera-to-world [m]
    object_points : (N, 3) [m] points of the object in the true world (e.g. the reference vertices)
    max_points : at most this many object points are used (evenly subsampled)

    Returns
    -------
    PoseErrors
    """
    P = np.asarray(poses, np.float64)
    T = np.asarray(true_poses, np.float64)
    X = np.asarray(object_points, np.float64).reshape(-1, 3)
    if P.shape != T.shape or P.ndim != 3 or P.shape[1:] != (4, 4):
        raise InputError(f"pose_errors: poses {P.shape} and true poses {T.shape} must both be (V, 4, 4)")
    if len(X) == 0:
        raise InputError("pose_errors: no object points")
    X = X[np.linspace(0, len(X) - 1, min(len(X), max_points)).astype(np.int64)]
    A = [p @ np.linalg.inv(t) for p, t in zip(P, T)]  # true world -> estimated world, per view
    src = np.concatenate([X @ a[:3, :3].T + a[:3, 3] for a in A])
    G = _kabsch(src, np.tile(X, (len(A), 1)))
    rot, obj, obj_rms, cam = [], [], [], []
    for a, t in zip(A, T):
        E = G @ a
        d = np.linalg.norm(X @ E[:3, :3].T + E[:3, 3] - X, axis=1)
        rot.append(rotation_angle_deg(E))
        obj.append(float(d.max()) * 1e3)
        obj_rms.append(float(np.sqrt(np.mean(d ** 2))) * 1e3)
        cam.append(displacement_at(E, t[:3, 3]) * 1e3)
    return PoseErrors(np.array(rot), np.array(obj), np.array(obj_rms), np.array(cam), G)


#: the model's regions the scale's spread is taken over (:func:`_region_spread`)
SCALE_REGIONS = 16


def _region_spread(centred: np.ndarray, J: np.ndarray, w: np.ndarray, e: np.ndarray,
                   regions: int = SCALE_REGIONS) -> np.ndarray:
    """(P,) delete-one-region jackknife standard errors of the last step's parameters.

    Parameters
    ----------
    centred : (N, 3) [m] the inlier points about their centroid (what the regions are drawn on)
    J : (N, P) the step's Jacobian; w : (N,) its weights; e : (N,) its residuals [m]

    The points are split into ``regions`` compact regions (k-means on their positions, seeded); the
    step is solved again without each region, and the spread of those solutions, ``sqrt((B - 1) / B
    sum (x_b - mean)^2)``, is the standard error a spatially correlated surface error leaves (it
    includes the noise's). NaN where there are too few points for the regions.
    """
    n = len(centred)
    if n < 50 * regions:
        return np.full(J.shape[1], np.nan)
    sub = centred[:: max(1, n // 5000)]
    with warnings.catch_warnings():  # a region left empty is skipped below; kmeans2 would only warn of it
        warnings.simplefilter("ignore", UserWarning)
        codebook, _ = kmeans2(sub, regions, seed=0, minit="++", iter=20)
    label = vq(centred, codebook, check_finite=False)[0]
    Jw = J * w[:, None]
    H, g = Jw.T @ J, Jw.T @ e
    sols = []
    for b in range(regions):
        m = label == b
        if not m.any():
            continue
        Hb, gb = H - Jw[m].T @ J[m], g - Jw[m].T @ e[m]
        sols.append(-np.linalg.lstsq(Hb, gb, rcond=1e-12)[0])
    sols = np.array(sols)
    B = len(sols)
    if B < 4:
        return np.full(J.shape[1], np.nan)
    return np.sqrt((B - 1) / B * np.sum((sols - sols.mean(0)) ** 2, axis=0))


def scale_from_reference(points: np.ndarray, reference, inlier_mm: float = 3.0, iterations: int = 4,
                         max_points: int = 60_000, max_correlation: float = SCALE_OFFSET_MAX_CORRELATION,
                         offset: bool = True) -> dict:
    """Uniform scale of a model relative to a reference mesh (module docstring).

    Parameters
    ----------
    points : (N, 3) [m] model surface samples, already rigidly aligned to the reference
    reference : Geometry (mesh) in metres
    inlier_mm : correspondences farther than this from the reference are left out [mm]
    max_correlation : above this correlation of the scale and offset estimates the shape cannot
        separate them (a box: every face moves alike under both) and both are reported as NaN
    offset : fit the surface offset with the scale (default). False: the scale alone, the offset held
        at 0, so a uniform surface offset ``o`` reads as a scale ``o / R`` (``R`` the model's RMS
        radius about its centroid): the model's *size* error, defined on every shape, spheres and
        boxes included; ``offset_mm`` is then 0 and ``correlation`` NaN

    Returns
    -------
    dict: ``scale_error`` (the model's scale relative to the reference minus 1, dimensionless: +0.002
    = the model is 0.2 % too large), ``sigma`` (its standard error: ``sigma_noise``, from the normal
    equations with independent residuals, and ``sigma_regions``, the estimate's spread over the model's
    regions (:func:`_region_spread`: what surface errors that vary over the object leave in it), in
    quadrature; the offset's likewise), ``offset_mm`` (the model's surface
    offset along the reference's outward normals [mm]), ``offset_sigma_mm``, ``correlation`` (of the
    two estimates), ``n`` (inliers), ``rms_mm`` (point-to-plane RMS of the last iteration), and
    ``note`` when the two are not separable
    """
    from tofmetry.evaluate._distance import distances_to_mesh

    if not getattr(reference, "is_mesh", False):
        raise InputError("scale_from_reference: the reference must be a mesh")
    p = np.asarray(points, np.float64)
    if len(p) > max_points:
        p = p[np.random.default_rng(0).choice(len(p), max_points, replace=False)]
    L = float(np.sqrt(np.mean(np.sum((p - p.mean(0)) ** 2, 1))))
    q = p.copy()
    s_tot = 1.0
    sigma, n_in, rms = float("nan"), 0, float("nan")
    o = sigma_off = corr = float("nan")
    for _ in range(iterations):
        cp = distances_to_mesh(q, reference.points, reference.faces)
        n, r = cp.normal, cp.distance
        ok = np.abs(r) < inlier_mm * 1e-3
        if ok.sum() < 100:
            raise InputError(f"scale_from_reference: only {int(ok.sum())} model points within {inlier_mm} mm of the reference")
        m = q[ok].mean(0)
        qc = q[ok] - m
        # residual n . (q' - closest) with q' = m + dt + (1 + ds) dR (q - m), linearised; the Jacobian
        # is taken at the closest points, not at the model's points: their noise along n is the
        # residual itself, so it would sit in the scale's column too and bias the scale by sigma^2
        # (errors in variables; measured on a dome with 0.3 mm of noise: +0.38 %, 10 of its sigmas)
        J = similarity_offset_jacobian(cp.closest[ok] - m, n[ok], L)
        if not offset:
            J = J[:, :7]
        e = r[ok]
        # Huber weights on the residuals about the offset found so far: the offset is never moved
        # into the points (each step fits it whole), so weights about 0 would shrink it toward 0
        # (measured: 0.3 mm read 0.21 mm under 0.5 mm of noise)
        k = 0.5e-3
        a = np.abs(e - (o if offset and np.isfinite(o) else 0.0))
        w = np.where(a <= k, 1.0, k / np.maximum(a, 1e-12))
        H = (J * w[:, None]).T @ J
        n_in, rms = int(ok.sum()), float(np.sqrt(np.mean(e ** 2))) * 1e3
        Hi = np.linalg.pinv(H)
        if offset:
            corr = float(Hi[6, 7] / np.sqrt(max(Hi[6, 6] * Hi[7, 7], 1e-300)))
            if not np.isfinite(corr) or abs(corr) > max_correlation:
                break  # before the step: along that valley the solve runs away (module docstring)
        x = -np.linalg.lstsq(H, (J * w[:, None]).T @ e, rcond=1e-12)[0]
        w_rot, dt, ds = x[:3] / L, x[3:6], float(np.clip(x[6], -0.05, 0.05))
        o = -x[7] if offset else 0.0
        th = np.linalg.norm(w_rot)
        K = np.array([[0, -w_rot[2], w_rot[1]], [w_rot[2], 0, -w_rot[0]], [-w_rot[1], w_rot[0], 0]])
        dR = np.eye(3) + (np.sin(th) / th * K + (1 - np.cos(th)) / th ** 2 * K @ K if th > 1e-12 else K)
        q = m + dt + (1 + ds) * (q - m) @ dR.T
        s_tot *= 1 + ds
        fit = e + J @ x  # the residuals the step leaves
        s2 = float(np.sum(w * fit ** 2) / max(np.sum(w), 1e-12))
        sigma = float(np.sqrt(max(Hi[6, 6] * s2, 0.0)))
        if offset:
            sigma_off = float(np.sqrt(max(Hi[7, 7] * s2, 0.0)))
        last = (qc, J, w, e)
    # the noise-only sigmas above take the residuals as independent; a model's surface errors are not
    # (a rim read 0.3 mm inward, a face bent by the range error), and where the shape barely separates
    # scale from offset such an error moves the scale far more than noise does: the spread of the
    # estimate over the model's regions (block jackknife) says how far
    sigma_noise, sigma_regions = sigma, float("nan")
    if np.isfinite(sigma) and (not offset or (np.isfinite(corr) and abs(corr) <= max_correlation)):
        spread = _region_spread(*last)
        sigma_regions = float(spread[6])
        sigma = float(np.hypot(sigma, sigma_regions)) if np.isfinite(sigma_regions) else sigma
        if offset and np.isfinite(spread[7]):
            sigma_off = float(np.hypot(sigma_off, spread[7]))
    # s_tot maps the model onto the reference: the model's own scale is its inverse
    if not offset:
        ok_scale = np.isfinite(s_tot) and s_tot > 0
        return {"scale_error": 1.0 / s_tot - 1.0 if ok_scale else float("nan"), "sigma": sigma,
                "sigma_noise": sigma_noise, "sigma_regions": sigma_regions, "offset_mm": 0.0,
                "offset_sigma_mm": 0.0, "correlation": float("nan"), "n": n_in, "rms_mm": rms}
    if not np.isfinite(corr) or abs(corr) > max_correlation or not np.isfinite(s_tot) or s_tot <= 0:
        # a box-like shape: scaling about the centroid moves its faces as an offset does; the two
        # cannot be told apart, and the solve runs away along that valley (measured: a "scale" of 1e-7)
        return {"scale_error": float("nan"), "sigma": float("nan"), "sigma_noise": float("nan"),
                "sigma_regions": float("nan"), "offset_mm": float("nan"),
                "offset_sigma_mm": float("nan"), "correlation": corr, "n": n_in, "rms_mm": rms,
                "note": f"scale and surface offset not separable on this shape (correlation {corr:+.3f})"}
    return {"scale_error": 1.0 / s_tot - 1.0, "sigma": sigma, "sigma_noise": sigma_noise, "sigma_regions": sigma_regions,
            "offset_mm": float(o) * 1e3, "offset_sigma_mm": sigma_off * 1e3, "correlation": corr, "n": n_in, "rms_mm": rms}


def model_scale(points: np.ndarray, reference) -> dict:
    """The model's scale against a reference mesh, as ``tofmetry evaluate`` reports it.

    Parameters
    ----------
    points : (N, 3) [m] model surface samples, already rigidly aligned to the reference
    reference : Geometry (mesh) in metres

    Returns
    -------
    dict: ``scale_error_pct`` and ``sigma_pct`` (the scale with the surface offset fitted beside it,
    :func:`scale_from_reference`; None where the shape cannot tell them apart, with ``note``),
    ``offset_mm``, ``offset_sigma_mm``, ``correlation``, ``separable``; ``size_error_pct`` and
    ``size_sigma_pct`` (the scale with no offset, defined on every shape: a uniform surface offset
    ``o`` reads in it as ``o / R``, ``R`` the model's RMS radius); ``n`` and ``rms_mm`` of the fit.
    A fit that cannot be made (too few model points near the reference) gives ``error`` instead.
    """
    try:
        both = scale_from_reference(points, reference)
        size = scale_from_reference(points, reference, offset=False)
    except InputError as exc:
        return {"error": str(exc)}

    def pct(x):
        return None if not np.isfinite(x) else 100.0 * float(x)

    def mm(x):
        return None if not np.isfinite(x) else float(x)

    separable = bool(np.isfinite(both["scale_error"]))
    out = {"scale_error_pct": pct(both["scale_error"]), "sigma_pct": pct(both["sigma"]),
           "sigma_noise_pct": pct(both["sigma_noise"]), "sigma_regions_pct": pct(both["sigma_regions"]),
           "offset_mm": mm(both["offset_mm"]), "offset_sigma_mm": mm(both["offset_sigma_mm"]),
           "correlation": mm(both["correlation"]), "separable": separable,
           "size_error_pct": pct(size["scale_error"]), "size_sigma_pct": pct(size["sigma"]),
           "n": both["n"], "rms_mm": mm(both["rms_mm"]),
           "rule": "after the rigid alignment, a uniform scale about the model's centroid and a uniform offset "
                   "along the reference's normals (point-to-plane, Huber, inliers within 3 mm); the size is the "
                   "same fit without the offset. Positive: the model is larger than the reference"}
    if not separable:
        out["note"] = both.get("note")
    return out

