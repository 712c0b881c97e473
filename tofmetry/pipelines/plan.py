"""Pipeline ``plan``: an object (rough size, mesh or first view) -> predicted completeness and accuracy
of a set of views, and the views proposed to reach a target (:mod:`tofmetry.plan`).

``plan.json`` holds the object's proxy description, the proposal (camera-to-world poses in the
object's z-up frame, ground z = 0) with its prediction, every candidate's prediction and, with
``--views``, the prediction of the views asked for. :mod:`tofmetry.pipelines.plan_check` reads it
back after a scan (``reconstruct --plan``, ``evaluate --plan``).
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
        else 0.5 m + 1.5 x the largest side, within 0.7-1.5 m, and no nearer than
        :func:`calibrated_distance_m` (the object's near side at the calibration's nearest station)
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
    distance_note = None
    if distance_m is None:
        distance_m = float(np.clip(0.5 + 1.5 * obj.extent_m.max(), 0.7, 1.5))
        near = calibrated_distance_m(obj, cal)
        if near is not None and near > distance_m:  # nearer, the calibration extrapolates on the object's near side
            distance_note = (f"{distance_m:.2f} m raised to {near:.2f} m: the object's near side at the calibration's "
                             "nearest station")
            distance_m = near
    cal_mm = 0.5
    if cal is not None:
        cal_mm = float(((cal.prediction or {}).get("interpolation") or {}).get("central_abs_mm", {}).get("predicted", 0.5))
    kw = {"n_frames": n_frames, "calibration_mm": cal_mm}
    aim = aim_for(target)  # the prediction over-estimates by up to 2.8 points (p95, PREDICTION_ERROR_PTS): aim that much higher
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
                **({"distance_note": distance_note} if distance_note else {}),
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
                            yaw_free_warning(turn), short_overlap_warning(best, ranked, aim)) if w]
    if warnings:
        settings["warnings"] = warnings
    run = PlanRun(obj, intr, best, ranked, asked, settings, completed)
    if output is not None:
        refuse_existing(output, force)
        atomic_write_json(Path(output), run.to_dict())
    return run


def short_overlap_warning(best: Proposal | None, ranked: list[Proposal], aim: float,
                          min_overlap: float = 0.5) -> str | None:
    """What a user is told when no set of views reaches the completeness aimed at with successive
    views sharing ``min_overlap`` of the surface, but the first listed reaches it with less (a low
    ring and zenithal views, :func:`tofmetry.plan.propose`); None otherwise."""
    if best is not None or not ranked or ranked[0].prediction.completeness < aim:
        return None
    p = ranked[0].prediction
    return (f"{ranked[0].name} is predicted to reach {p.completeness:.1%}, but successive views share as little as "
            f"{p.min_overlap:.2f} of the surface (below {min_overlap:g}), too little for the views to register on "
            "each other alone: stand the object on a printed dot mat (tofmetry mat; reconstruct --mat places every "
            "view on it) or scan it on a turntable and declare its step (reconstruct --turntable-step)")


def yaw_free_warning(turn: dict) -> str | None:
    """What a user is told when the object's geometry leaves the views' turn about the vertical free
    (:func:`tofmetry.plan.turn_about_vertical`); None otherwise."""
    if not turn.get("free"):
        return None
    return (f"the object is nearly a surface of revolution: its surface resists a turn about the vertical "
            f"{turn['ratio']:.2f} times as much as a shift (below {turn['free_below']:g}), so no set of views fixes "
            "their turn from the geometry; on the family's held-out draws 25-34, 2 of 26 such scans came out right and "
            "reliable. Stand it on a printed dot mat (tofmetry mat; reconstruct --mat places every view on it), give the "
            "surface a pattern (paint, texture or markers: the IR albedo then fixes the turn) or scan it on a turntable "
            "and declare its step (reconstruct --turntable-step)")


def calibrated_distance_m(obj: PlanObject, calibration) -> float | None:
    """The nearest distance [m] of the views from the object centre at which the object's near side
    (half its diagonal toward the camera, as :func:`calibrated_range_warning` bounds it) lies no nearer
    than the calibration's nearest station: nearer, the correction there is extrapolated (on the
    family's held-out draw 103 an igea of 0.2 m scanned from 0.67 m, 45 % of its points below the
    nearest station, came out 2.6 % large). None without a calibration with a support map."""
    if calibration is None or getattr(calibration, "support", None) is None:
        return None
    lo = float(calibration.support.range_mm[0])
    return float(np.ceil((lo * 1e-3 + 0.5 * float(np.linalg.norm(obj.extent_m))) * 100.0) / 100.0)  # to the cm above


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
    # the advice names the side the views leave: too near, the distance calibrated_distance_m gives (to the cm
    # above, so that scanning from it raises no warning); too far, the farthest within the stations (to the cm below)
    farthest = float(np.floor((hi * 1e-3 - half) * 100.0) / 100.0)
    advice = (f"scan from {calibrated_distance_m(obj, calibration):.2f} m or farther, or calibrate nearer" if near < lo
              else f"scan from {farthest:.2f} m or nearer, or calibrate farther" if farthest > 0
              else "calibrate over the depths the object spans")
    return (f"views at {distance_m:.2f} m see the object at about {max(near, 0):.0f}-{far:.0f} mm, the calibration's "
            f"stations span {lo:.0f}-{hi:.0f} mm: outside, its correction is extrapolated, off by up to "
            f"{extrapolation_error_mm(calibration.prediction):.1f} mm by its own extrapolation folds; {advice}")


def read_plan(path: str | os.PathLike) -> dict:
    """A ``plan.json`` written by :func:`plan_acquisition` (checked for its proposal or asked views)."""
    d = read_json(path, "plan")
    if not isinstance(d, dict) or ("proposal" not in d and "asked" not in d):
        raise InputError(f"{path}: not a plan.json (no 'proposal' / 'asked')")
    return d
