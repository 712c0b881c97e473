"""Checks of a scan against its plan (``plan.json``, :mod:`tofmetry.pipelines.plan`).

* ``tofmetry reconstruct --plan plan.json`` (:func:`plan_followed`, no reference needed): the views as
  registered beside the views the plan asked for, both predicted on the object's size;
* ``tofmetry evaluate --poses poses.json --plan plan.json`` (:func:`plan_check`, with a reference):
  the prediction for the views as taken beside the completeness achieved.
"""

from __future__ import annotations

import numpy as np

from tofmetry.errors import InputError
from tofmetry.plan import PlanObject, predict, proxy_from_size, surface_samples
from tofmetry.reconstruct import support_plane_frame, transform_plane
from tofmetry.sensor import CameraIntrinsics


def planned_views(doc: dict) -> dict | None:
    """The view set a ``plan.json`` asks to take (the completed views, else the views asked for,
    else the proposal) and its prediction; None when it holds none."""
    for key in ("completed", "asked", "proposal"):
        p = doc.get(key)
        if p:
            pr = p.get("prediction") or {}
            return {"which": key, "name": p.get("name"), "n_views": pr.get("n_views"),
                    "completeness": pr.get("completeness"), "completeness_range": pr.get("completeness_range")}
    return None


def view_layout(poses, centre: np.ndarray) -> dict:
    """Where a set of cameras stands around an object: how many, their elevation and slant
    distance ranges from ``centre`` and the largest gap between successive azimuths.

    Parameters
    ----------
    poses : (V, 4, 4) camera-to-world [m], world z up
    centre : (3,) the object's centre [m]

    Returns
    -------
    dict: ``n_views``, ``elevation_deg`` [min, max], ``distance_m`` [min, max], ``azimuth_gap_deg``
    (360 for a single view)
    """
    rel = np.array([np.asarray(P, np.float64)[:3, 3] - centre for P in poses])
    dist = np.linalg.norm(rel, axis=1)
    elev = np.degrees(np.arcsin(np.clip(rel[:, 2] / np.maximum(dist, 1e-12), -1, 1)))
    az = np.sort(np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360.0)
    gap = float(np.max(np.diff(np.r_[az, az[0] + 360.0]))) if len(az) > 1 else 360.0
    return {"n_views": len(rel), "elevation_deg": [round(float(elev.min()), 1), round(float(elev.max()), 1)],
            "distance_m": [round(float(dist.min()), 3), round(float(dist.max()), 3)],
            "azimuth_gap_deg": round(gap, 1)}


def _layout_text(lay: dict) -> str:
    e, d = lay["elevation_deg"], lay["distance_m"]
    return (f"{lay['n_views']} views at {e[0]:.0f}-{e[1]:.0f} deg elevation, {d[0]:.2f}-{d[1]:.2f} m, largest azimuth "
            f"gap {lay['azimuth_gap_deg']:.0f} deg")


def plan_followed(doc: dict, model_points: np.ndarray, poses, intrinsics: CameraIntrinsics,
                  min_mm: float = 500.0, max_mm: float = 2500.0) -> dict:
    """The views as registered beside the views a plan asked for, without a reference (issue 16:
    the reconstruction compares the plan's prediction with what the scan did).

    Both view sets are predicted on the same object: the rounded box of the plan's object size
    (:func:`tofmetry.plan.proxy_from_size` of ``object.extent_m``; for a plan made from a mesh, the
    box of its extent), so that the difference is the views' and not the object's. The model is
    in the reconstruction's ground frame (support plane z = 0, origin under the object); the box is
    turned about the vertical so that its longer horizontal side lies along the model's longer
    horizontal principal axis (a box is the same turned by 180 deg). What the scan achieved on the
    real object needs a reference: ``tofmetry evaluate --poses --plan`` (:func:`plan_check`).

    Parameters
    ----------
    doc : the content of a ``plan.json`` (:func:`read_plan`)
    model_points : (N, 3) [m] the model (vertices or cloud), ground frame
    poses : (V, 4, 4) the registered camera-to-world [m], ground frame
    intrinsics : the depth camera's; min_mm, max_mm : the depth range kept [mm]

    Returns
    -------
    dict: planned (:func:`planned_views`, with ``on_size``: its prediction on the box and
    ``layout``: :func:`view_layout`), taken (``layout``, ``on_size``, ``on_size_range``), short_pts
    (planned - taken on the box [points]), object (the box's size and the model's footprint), summary
    """
    ext = np.asarray((doc.get("object") or {}).get("extent_m") or [], np.float64)
    if ext.shape != (3,) or not (ext > 0).all():
        raise InputError(f"reconstruct --plan: the plan.json gives no object size (object.extent_m: {ext.tolist()})")
    planned = planned_views(doc)
    key = None if planned is None else planned["which"]
    planned_poses = [np.asarray(T, np.float64) for T in ((doc.get(key) or {}).get("camera_to_world") or [])]
    if not planned_poses:
        raise InputError("reconstruct --plan: the plan.json holds no views (no camera_to_world in its proposal, asked "
                         "or completed views)")
    m = np.asarray(model_points, np.float64)
    m = m[m[:, 2] > 0.005] if (m[:, 2] > 0.005).sum() >= 10 else m
    if len(m) < 10:
        raise InputError(f"reconstruct --plan: the model has {len(m)} points above its support plane; nothing to "
                         "compare the plan's object with")
    c = 0.5 * (m[:, :2].min(0) + m[:, :2].max(0))
    vec = np.linalg.eigh(np.cov((m[:, :2] - c).T))[1]
    major = vec[:, 1]  # the model's longer horizontal axis
    a = np.arctan2(major[1], major[0]) - (0.0 if ext[0] >= ext[1] else np.pi / 2)
    G = np.eye(4)  # ground frame -> the box's frame: centred on the z axis, its longer side along the major axis
    G[:2, :2] = [[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]
    G[:2, 3] = -G[:2, :2] @ c
    taken = [G @ np.asarray(P, np.float64) for P in poses]
    box = proxy_from_size(*ext)
    kw = {"min_mm": min_mm, "max_mm": max_mm}
    p_taken = predict(box, taken, intrinsics, **kw)
    p_plan = predict(box, planned_poses, intrinsics, **kw)
    foot = (m[:, :2] - c) @ vec
    size = [round(float(np.ptp(foot[:, 1])), 3), round(float(np.ptp(foot[:, 0])), 3)]  # along the major axis first
    lay_t, lay_p = view_layout(taken, box.centre_m), view_layout(planned_poses, box.centre_m)
    short = 100 * (p_plan.completeness - p_taken.completeness)
    lo, hi = p_taken.completeness_range
    text = (f"views taken: {_layout_text(lay_t)}; planned ({planned['name']}): {_layout_text(lay_p)}. On the plan's "
            f"object size ({ext[0]:.2f} x {ext[1]:.2f} x {ext[2]:.2f} m) the views taken are predicted to cover "
            f"{p_taken.completeness:.1%} ({lo:.0%}-{hi:.0%}), the planned ones {p_plan.completeness:.1%}: "
            + (f"{short:.1f} points short of the plan" if short > 0.5 else "as the plan or better"))
    if max(size) > 1.5 * max(ext[:2]) or max(size) < max(ext[:2]) / 1.5:
        text += (f" (the model's footprint, {size[0]:.2f} x {size[1]:.2f} m, differs from the plan's object: was it "
                 "planned for this object?)")
    turn = (doc.get("settings") or {}).get("turn_about_vertical") or {}
    if turn.get("free"):
        text += (". The plan warned that the object's geometry leaves the views' turn about the vertical free (stiffness "
                 f"ratio {turn.get('ratio', float('nan')):.2f}): the poses hold only where a pattern or a declared "
                 "turntable step fixed it (see the registration's verdict)")
    text += ". The completeness achieved needs a reference: tofmetry evaluate --poses poses.json --plan plan.json"
    return {"planned": {**planned, "layout": lay_p, "on_size": round(p_plan.completeness, 4)},
            "taken": {"layout": lay_t, "on_size": round(p_taken.completeness, 4),
                      "on_size_range": [round(lo, 4), round(hi, 4)]},
            "short_pts": round(short, 2),
            "object": {"plan_extent_m": [round(float(x), 4) for x in ext], "model_footprint_m": size,
                       "model_height_m": round(float(m[:, 2].max()), 3)},
            "turn_free_warned": bool(turn.get("free")),
            "summary": text}


def plan_check(doc: dict | None, reference: tuple[np.ndarray, np.ndarray], model_points: np.ndarray, cameras,
               world_from_model: np.ndarray, threshold_mm: float = 5.0) -> dict:
    """The plan's prediction beside what the scan achieved (issue 16: the plan within 5 points).

    The prediction is made again for the views as they were taken (the registered cameras) on the
    reference itself, so that it judges the predictor and not how closely the views followed the
    plan; the plan's own figure for the views it asked for is reported beside it. The achieved
    completeness is the share of the same surface samples (the reference less its base, as the
    plan counts it) within ``threshold_mm`` of the model.

    Parameters
    ----------
    doc : the content of a ``plan.json`` (:func:`read_plan`) or None
    reference : (vertices (V, 3) [m], faces (F, 3)) of the reference, in its frame
    model_points : (N, 3) [m] model samples, aligned to the reference
    cameras : :class:`~tofmetry.evaluate.CameraViews` of the reconstruction (model frame), with its
        support plane
    world_from_model : (4, 4) the model -> reference alignment

    Returns
    -------
    dict: planned (:func:`planned_views`), views_taken (number, elevation and distance ranges,
    predicted completeness and range), achieved, error_pts (predicted - achieved [points]), summary
    """
    from scipy.spatial import cKDTree

    if cameras.support_plane is None:
        raise InputError("evaluate --plan: the poses.json holds no support plane (the model is not in a ground "
                         "frame); the plan's completeness leaves the base out by it")
    T = np.asarray(world_from_model, np.float64)
    V, F = np.asarray(reference[0], np.float64), np.asarray(reference[1], np.int64)
    # the reference's ground frame: the support plane at z = 0, the origin under its centroid
    G = support_plane_frame(transform_plane(cameras.support_plane, T), V, T @ cameras.poses[0])
    obj = PlanObject(V @ G[:3, :3].T + G[:3, 3], F, "reference")
    poses = [G @ T @ P for P in cameras.poses]
    pred = predict(obj, poses, cameras.intrinsics, min_mm=cameras.min_mm, max_mm=cameras.max_mm)
    pts, _ = surface_samples(obj)
    m = np.asarray(model_points, np.float64) @ G[:3, :3].T + G[:3, 3]
    d, _ = cKDTree(m).query(pts, distance_upper_bound=threshold_mm * 1e-3, workers=-1)
    achieved = float(np.isfinite(d).mean())
    lay = view_layout(poses, obj.centre_m)
    lo, hi = pred.completeness_range
    taken = {**{k: lay[k] for k in ("n_views", "elevation_deg", "distance_m")},
             "predicted": round(pred.completeness, 4), "predicted_range": [round(lo, 4), round(hi, 4)]}
    err = 100 * (pred.completeness - achieved)
    planned = planned_views(doc) if doc else None
    (e0, e1), (d0, d1) = lay["elevation_deg"], lay["distance_m"]
    text = (f"predicted {pred.completeness:.1%} ({lo:.0%}-{hi:.0%}) for the {len(poses)} views as taken "
            f"(elevation {e0:.0f}-{e1:.0f} deg, {d0:.2f}-{d1:.2f} m), achieved "
            f"{achieved:.1%} within {threshold_mm:g} mm: {err:+.1f} points")
    if planned and planned.get("completeness") is not None:
        text += (f"; the plan asked for {planned['name']} ({planned['n_views']} views), predicted "
                 f"{planned['completeness']:.1%}")
    if not lo - 0.005 <= achieved <= hi + 0.005:
        text += (" (achieved outside the predicted range: views left out, registration off, or surface the chain "
                 "lost that the views saw)" if achieved < lo else " (achieved above the range)")
    return {"planned": planned, "views_taken": taken, "achieved": round(achieved, 4), "threshold_mm": threshold_mm,
            "error_pts": round(err, 2), "summary": text}
