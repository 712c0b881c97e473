"""Pipeline ``plan``: an object (rough size, mesh or first view) -> predicted completeness and accuracy
of a set of views, and the views proposed to reach a target (:mod:`tofmetry.plan`).

``plan.json`` holds the object's proxy description, the proposal (camera-to-world poses in the
object's z-up frame, ground z = 0) with its prediction, every candidate's prediction and, with
``--views``, the prediction of the views asked for. Two checks read it back:

* ``tofmetry reconstruct --plan plan.json`` (:func:`plan_followed`, no reference needed): the views as
  registered beside the views the plan asked for, both predicted on the object's size;
* ``tofmetry evaluate --poses poses.json --plan plan.json`` (:func:`plan_check`, with a reference):
  the prediction for the views as taken beside the completeness achieved.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.errors import InputError
from tofmetry.io import atomic_write_json, read_json
from tofmetry.pipelines.paths import refuse_existing
from tofmetry.plan import (PREDICTION_ERROR_PTS, PlanObject, Proposal, aim_for, complete, predict, propose,
                           proxy_from_mesh, proxy_from_points, proxy_from_size, ring, surface_samples, turn_about_vertical)
from tofmetry.reconstruct import support_plane_frame, transform_plane
from tofmetry.sensor import KINECT_V2, CameraIntrinsics


#: what the family measured of views added at other elevations (bench/robustness, draws 20-21, 2026-11-28)
ADDED_VIEWS_WARNING = ("the added views look from other elevations than the scan's: their registration is harder; on "
                       "the family's draws 20-21 it broke 3 of 18 completed scans (flagged unreliable, 0.64-172 deg "
                       "off) that were right without them; check the reconstruction's verdict")


@dataclass
class PlanRun:
    """Result of :func:`plan_acquisition` (all JSON-able through :meth:`to_dict`)."""

    object: PlanObject
    intrinsics: CameraIntrinsics
    proposal: object
    candidates: list
    asked: object = None
    settings: dict = field(default_factory=dict)
    completed: object = None

    def to_dict(self) -> dict:
        return {"object": {"source": self.object.source, "extent_m": [round(float(x), 4) for x in self.object.extent_m],
                           "frame": "z up, ground z = 0, object centred on the z axis, metres"},
                "intrinsics": self.intrinsics.to_dict(), "settings": self.settings,
                "proposal": None if self.proposal is None else self.proposal.to_dict(),
                "asked": None if self.asked is None else self.asked.to_dict(),
                "completed": None if self.completed is None else self.completed.to_dict(),
                "candidates": [{"name": c.name, **c.prediction.to_dict()} for c in self.candidates]}


def parse_views(spec: str, obj: PlanObject, distance_m: float) -> list:
    """Views from ``ring:N:ELEV[:M:ELEV2]`` (N views at ELEV deg, plus M zenithal views at ELEV2)."""
    parts = spec.split(":")
    if parts[0] != "ring" or len(parts) not in (3, 5):
        raise InputError(f"--views: expected ring:N:ELEVATION or ring:N:ELEVATION:M:ELEVATION2, found {spec!r}")
    try:
        n, el = int(parts[1]), float(parts[2])
        poses = ring(n, distance_m, el, obj.centre_m)
        if len(parts) == 5:
            m, el2 = int(parts[3]), float(parts[4])
            poses += ring(m, distance_m, el2, obj.centre_m, 180.0 / n) if m > 0 else []
    except ValueError:
        raise InputError(f"--views: numbers expected in {spec!r}") from None
    return poses


def object_from_first_view(capture: str | os.PathLike, calibration=None) -> tuple[PlanObject, float, CameraIntrinsics]:
    """The object as a first view shows it: segmented on its support plane, a prism over its footprint.

    Returns (proxy, median distance of the object from the camera [m], intrinsics)."""
    from tofmetry.io import Capture
    from tofmetry.reconstruct import extrapolated_points, prepare_view, segment_object

    cap = Capture(capture)
    intr = calibration.intrinsics if calibration is not None else cap.intrinsics()[0]
    v = prepare_view(cap.depth_stack(), intr, calibration, name=str(capture))
    seg = segment_object(v.points, height_tolerance_m=extrapolated_points(v.points, calibration)[1],
                         normals=v.normals, grid=(v.index, intr.shape))
    n = seg.plane[:3]
    obj = v.points[seg.object_mask]
    h = obj @ n + seg.plane[3]
    x = np.cross(n, [1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.cross(n, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    up = np.c_[obj @ x, obj @ y, h]
    dist = float(np.median(np.linalg.norm(obj, axis=1)))
    return proxy_from_points(up), dist, intr


def plan_acquisition(*, size: tuple[float, float, float] | None = None, mesh: str | os.PathLike | None = None,
                     mesh_scale: float = 1.0, mesh_up=(0.0, 0.0, 1.0), first_view: str | os.PathLike | None = None,
                     calibration=None, distance_m: float | None = None, target: float = 0.9, n_frames: int = 10,
                     views: str | None = None, complete_views: bool = False, output: str | os.PathLike | None = None,
                     force: bool = False) -> PlanRun:
    """Plan the acquisition of one object (exactly one of ``size``, ``mesh``, ``first_view``).

    Parameters
    ----------
    size : (width, depth, height) [m]
    mesh : PLY/OBJ/STL of the object (``mesh_scale`` converts its units to metres, ``mesh_up`` its up axis)
    first_view : a capture of the object on its support
    calibration : DepthCalibration or a calibration file (intrinsics and its predicted error) or None
    distance_m : slant distance of the views from the object centre [m]; default: the first view's,
        else 0.5 m + 1.5 x the largest side, within 0.7-1.5 m
    target : completeness to reach (0-1); the views proposed (and completed) must be predicted to
        reach :func:`tofmetry.plan.aim_for` of it, higher by the prediction's p95 over-estimate
    views : a set of views to predict as well (:func:`parse_views`)
    complete_views : also propose the views to add to ``views`` so that they reach ``target``
        (:func:`tofmetry.plan.complete`: next-best views, each placed in the loop where its azimuth falls)
    output : ``plan.json`` to write (atomic; refuses to overwrite without ``force``)
    """
    from tofmetry.pipelines.calibration_files import load_calibration

    if sum(x is not None for x in (size, mesh, first_view)) != 1:
        raise InputError("plan: give exactly one of --size, --mesh, --first-view")
    if not 0 < target <= 1:
        raise InputError(f"plan: --target must be in (0, 1], found {target}")
    cal = load_calibration(calibration) if calibration is not None and not hasattr(calibration, "intrinsics") \
        else calibration
    intr = cal.intrinsics if cal is not None else KINECT_V2.depth
    if size is not None:
        obj = proxy_from_size(*size)
    elif mesh is not None:
        from tofmetry.io.mesh import read_geometry

        g = read_geometry(mesh, "plan mesh")
        if not g.is_mesh:
            raise InputError(f"plan: {mesh} holds no triangles (a mesh is needed)")
        obj = proxy_from_mesh(g.points, g.faces, mesh_up, mesh_scale)
    else:
        obj, d0, intr = object_from_first_view(first_view, cal)
        distance_m = distance_m or d0
    if distance_m is None:
        distance_m = float(np.clip(0.5 + 1.5 * obj.extent_m.max(), 0.7, 1.5))
    cal_mm = 0.5
    if cal is not None:
        cal_mm = float(((cal.prediction or {}).get("interpolation") or {}).get("central_abs_mm", {}).get("predicted", 0.5))
    kw = {"n_frames": n_frames, "calibration_mm": cal_mm}
    aim = aim_for(target)  # the prediction over-estimates by up to 3.3 points (p95): aim that much higher
    best, ranked = propose(obj, intr, aim, distance_m, **kw)
    asked = None
    if views is not None:
        poses = parse_views(views, obj, distance_m)
        asked = Proposal(views, poses, predict(obj, poses, intr, **kw), {"spec": views})
    completed = None
    if complete_views:
        if asked is None:
            raise InputError("plan: --complete completes the views given with --views; give --views too")
        poses, added, pred = complete(obj, asked.poses, intr, aim, distance_m, **kw)
        completed = Proposal(f"{views} + {len(added)} planned", poses, pred, {"spec": views, "added_at": added})
    settings = {"target": target, "aimed_at": round(aim, 4), "distance_m": distance_m, "n_frames": n_frames,
                "calibration_mm": cal_mm,
                "aim_rule": f"the views must be predicted to reach the target plus {PREDICTION_ERROR_PTS[1]:g} points, the "
                            "prediction's p95 over-estimate on the family (bench/robustness), so that the scan "
                            "reaches the target on about 95 % of runs"}
    if obj.source == "size":  # the rounded box stands for any shape of that size: it tells nothing of symmetry
        turn = {"free": None, "note": "not judged: a size alone does not tell the object's shape (give --mesh or "
                                      "--first-view)"}
    else:
        turn = {**turn_about_vertical(*surface_samples(obj)),
                "rule": "free where the surface resists a turn about the vertical less than a fifth as much as a "
                        "shift (point-to-plane stiffness, tofmetry.plan._symmetry)"}
    settings["turn_about_vertical"] = turn
    warnings = [w for w in (calibrated_range_warning(obj, distance_m, cal),
                            None if completed is None or not completed.params["added_at"] else ADDED_VIEWS_WARNING,
                            yaw_free_warning(turn)) if w]
    if warnings:
        settings["warnings"] = warnings
    run = PlanRun(obj, intr, best, ranked, asked, settings, completed)
    if output is not None:
        refuse_existing(output, force)
        atomic_write_json(Path(output), run.to_dict())
    return run


def yaw_free_warning(turn: dict) -> str | None:
    """What a user is told when the object's geometry leaves the views' turn about the vertical free
    (:func:`tofmetry.plan.turn_about_vertical`); None otherwise."""
    if not turn.get("free"):
        return None
    return (f"the object is nearly a surface of revolution: its surface resists a turn about the vertical "
            f"{turn['ratio']:.2f} times as much as a shift (below {turn['free_below']:g}), so no set of views fixes "
            "their turn from the geometry; on the family's held-out draws 25-34, 2 of 26 such scans came out right and "
            "reliable. Give the surface a pattern (paint, texture or markers: the IR albedo then fixes the turn) or "
            "scan it on a turntable and declare its step (reconstruct --turntable-step)")


def calibrated_range_warning(obj: PlanObject, distance_m: float, calibration) -> str | None:
    """A warning when the views at ``distance_m`` [m] from the object centre see depths the depth
    calibration's stations do not span (its correction there is extrapolated); None otherwise.

    The depths seen are bounded by the distance minus / plus half the object's diagonal (a camera
    looks at the centre, so Z along its axis lies within that)."""
    if calibration is None or getattr(calibration, "support", None) is None:
        return None
    from tofmetry.reconstruct import extrapolation_error_mm

    lo, hi = calibration.support.range_mm
    half = 0.5 * float(np.linalg.norm(obj.extent_m))
    near, far = 1e3 * (distance_m - half), 1e3 * (distance_m + half)
    if near >= lo and far <= hi:
        return None
    return (f"views at {distance_m:.2f} m see the object at about {max(near, 0):.0f}-{far:.0f} mm, the calibration's "
            f"stations span {lo:.0f}-{hi:.0f} mm: outside, its correction is extrapolated, off by up to "
            f"{extrapolation_error_mm(calibration.prediction):.1f} mm by its own extrapolation folds; scan from "
            f"{(lo * 1e-3 + half):.2f} m or farther, or calibrate nearer")


def read_plan(path: str | os.PathLike) -> dict:
    """A ``plan.json`` written by :func:`plan_acquisition` (checked for its proposal or asked views)."""
    d = read_json(path, "plan")
    if not isinstance(d, dict) or ("proposal" not in d and "asked" not in d):
        raise InputError(f"{path}: not a plan.json (no 'proposal' / 'asked')")
    return d


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
    w, vec = np.linalg.eigh(np.cov((m[:, :2] - c).T))
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
    size = [round(float(np.ptp(foot[:, 1])), 3), round(float(np.ptp(foot[:, 0])), 3), round(float(m[:, 2].max()), 3)]
    lay_t, lay_p = view_layout(taken, box.centre_m), view_layout(planned_poses, box.centre_m)
    short = 100 * (p_plan.completeness - p_taken.completeness)
    lo, hi = p_taken.completeness_range
    text = (f"views taken: {_layout_text(lay_t)}; planned ({planned['name']}): {_layout_text(lay_p)}. On the plan's "
            f"object size ({ext[0]:.2f} x {ext[1]:.2f} x {ext[2]:.2f} m) the views taken are predicted to cover "
            f"{p_taken.completeness:.1%} ({lo:.0%}-{hi:.0%}), the planned ones {p_plan.completeness:.1%}: "
            + (f"{short:.1f} points short of the plan" if short > 0.5 else "as the plan or better"))
    if max(size[:2]) > 1.5 * max(ext[:2]) or max(size[:2]) < max(ext[:2]) / 1.5:
        text += (f" (the model's footprint, {size[0]:.2f} x {size[1]:.2f} m, differs from the plan's object: was it "
                 "planned for this object?)")
    text += ". The completeness achieved needs a reference: tofmetry evaluate --poses poses.json --plan plan.json"
    return {"planned": {**(planned or {}), "layout": lay_p, "on_size": round(p_plan.completeness, 4)},
            "taken": {"layout": lay_t, "on_size": round(p_taken.completeness, 4),
                      "on_size_range": [round(lo, 4), round(hi, 4)]},
            "short_pts": round(short, 2),
            "object": {"plan_extent_m": [round(float(x), 4) for x in ext], "model_footprint_m": size,
                       "model_height_m": size[2]},
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
