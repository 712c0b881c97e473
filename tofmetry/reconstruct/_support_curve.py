"""The views' depth corrected by the range error their flat support shows (:func:`~tofmetry.calibrate.flat_support_curve`).

Where it runs: after the poses are final, before the fusion. The poses are judged on the depth
the calibration gave (the verdicts, the joint fit and the mat's placements stay as they were
measured); the model is built from the corrected depth, so its size no longer carries the range
error the calibration left between its stations.

Measured on family draw 74 and two draw-73 sensors whose calibrations had warned
(docs/history/object-models.md, session 34): a baluster's model -1.61 -> -0.02 % (mean distance 1.39 ->
0.33 mm), a rocker arm's -0.85 -> -0.16 %, a fandisk's -0.22 -> -0.03 %; over the 20 runs the scale's
p90 0.20 -> 0.14 %, the surfaces within 0.02 mm of before, the poses unchanged. Applied before the
registration instead (a probe), the placements came out closer (0.75 -> 0.68 mm at the object on a vase)
but the joint fit then moved the vase's views 2.0 -> 5.5 mm and ended further off (0.44 -> 0.95 mm): not
done there.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from tofmetry.calibrate import flat_support_curve
from tofmetry.errors import EstimationError
from tofmetry.reconstruct._preprocess import ViewData, correct_views
from tofmetry.reconstruct._segment import Segmentation
from tofmetry.sensor import CameraIntrinsics


def support_samples(views: list[ViewData], segs: list[Segmentation], intr: CameraIntrinsics,
                    band_m: float, clear_px: float,
                    columns: float | None = None) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each view's points on its support plane, away from the object: measured Z [mm] and normalised
    rays (x, y).

    Parameters
    ----------
    views, segs : the prepared views (camera frame, x right, y down, z forward) and their segmentations
    intr : the depth intrinsics (the rays of the points' pixels)
    band_m : a point lies on the support within this of its fitted plane [m] (wider than the range
        error to be measured: the plane is fitted through it)
    clear_px : points within this many pixels of the object's are left out: its foot (below the
        segmentation's height), its flying pixels and its shadow lie at the object's own depths, where
        a millimetre of them reads as the range error there
    columns : None: the whole support. Otherwise only its points in the object's own image columns (the 5-95 %
        span of the object's normalised x in that view) widened by this on each side: the calibration's residual
        between its stations changes over the image, and the support in the object's own columns shows the part
        the object has (``preprocess.support_curve_columns``)

    Returns
    -------
    z_mm : per view (N_j,) [mm]; xy : per view (N_j, 2); empty arrays for a view without a plane
    """
    rays = intr.ray_table(True).reshape(-1, 2)
    H, W = intr.shape
    z_mm, xy = [], []
    for v, s in zip(views, segs):
        if s.plane is None:
            z_mm.append(np.zeros(0))
            xy.append(np.zeros((0, 2)))
            continue
        obj = np.zeros(H * W, bool)
        obj[v.index[s.object_mask]] = True
        clear = ndimage.distance_transform_edt(~obj.reshape(H, W)).ravel() > clear_px
        on = (np.abs(v.points @ np.asarray(s.plane[:3]) + float(s.plane[3])) < band_m) & ~s.object_mask & clear[v.index]
        if columns is not None and s.object_mask.any():
            x = rays[v.index, 0]
            lo, hi = np.percentile(x[s.object_mask], [5, 95])
            on &= (x > lo - columns) & (x < hi + columns)
        z_mm.append(v.points[on, 2] * 1e3)
        xy.append(rays[v.index[on]])
    return z_mm, xy


def correct_by_support(views: list[ViewData], segs: list[Segmentation], intr: CameraIntrinsics,
                       band_m: float, clear_px: float, plane_threshold_m: float, step_mm: float,
                       smooth_mm: float, anchors: list | None = None, level: bool = True,
                       stations_mm: list[float] | None = None, columns: float | None = None,
                       lateral: tuple = (), max_error_mm: float | None = None, variable: str = "z") -> dict:
    """Fit the support's range curve, levelled on the object's depths, and subtract it from every
    view's depth, in place.

    Each point moves along its ray (``Z -> Z - e(Z)``), the depth maps with them; each support plane
    is refitted on the points that lay on it (within ``plane_threshold_m``) before.

    ``anchors``: per view None or ``(p, cov)``, its support plane known without the depth (the dot
    mat's, :class:`~tofmetry.reconstruct._mat_plane.DotPlane`); with enough of them the curve is whole
    (:func:`~tofmetry.calibrate.flat_support_curve`), its gain and curvature included. ``level``: the
    curve levelled on the object's depths; a curve not levelled moves the object by its level there
    (``object_offset_mm``): an anchored one by the whole range error the dots' planes show there, one
    from the support alone by its part orthogonal to ``1``, ``Z`` and ``Z^2`` (what the views'
    placements, which took their height from the measured support, leave the object off by).
    ``stations_mm``: the depth calibration's stations (:func:`~tofmetry.calibrate.flat_support_curve`):
    the curve's ``1``, ``Z`` and ``Z^2`` tied to nought there, which changes its gain over the object; its
    level at the object's depths stays the untied curve's (the placements hold the rest). ``columns``: the
    support's points in the object's image columns only (:func:`support_samples`). ``lateral``: image terms
    the curve changes by across the image (:func:`~tofmetry.calibrate.flat_support_curve`); each point is then
    corrected by the curve at its own ray, and the object's gain and level are read at its own pixels.
    ``max_error_mm``: the most range error a curve may read at the object's depths (:func:`curve_beyond`);
    a curve from the object's columns that reads more gives way to the whole support's, and one from the
    whole support that reads more is not applied (``applied`` False, ``why``). None: no bound. ``variable``:
    the curve a function of the measured depth (``"z"``) or of the measured ray length (``"radial"``,
    :func:`~tofmetry.calibrate.flat_support_curve`).

    Returns
    -------
    The report (``diagnostics.support_curve``): ``applied`` False with ``why`` when the support does not
    show the curve; otherwise the curve's :meth:`~tofmetry.calibrate.FlatSupportCurve.to_dict`, the gain it
    changed over the object's measured depths (``object_gain_pct``, its jackknife ``object_gain_sigma_pct``)
    and those depths' 5-95 % span (``object_depth_mm``)
    """
    rays = intr.ray_table(True).reshape(-1, 2)
    z_obj = np.concatenate([v.points[s.object_mask, 2] for v, s in zip(views, segs)]) * 1e3
    xy_obj = np.concatenate([rays[v.index[s.object_mask]] for v, s in zip(views, segs)])
    refused = []  # curves beyond the bound: from the object's columns, then from the whole support
    for cols in ((columns, None) if columns is not None else (None,)):
        z_mm, xy = support_samples(views, segs, intr, band_m, clear_px, cols)
        try:
            curve = flat_support_curve(z_mm, xy, step_mm=step_mm, smooth_mm=smooth_mm, anchors=anchors,
                                       stations_mm=stations_mm, lateral=lateral, variable=variable)
        except EstimationError as exc:
            return {"applied": False, "why": str(exc)} | ({"refused": refused} if refused else {})
        curve.level_mm = curve.tie_mean_mm(z_obj, xy_obj)  # the tie changes the curve's slope at the object, not its level
        beyond = curve_beyond(curve, z_obj, xy_obj, max_error_mm)
        if beyond is None:
            break
        refused.append(f"the support curve from the object's image columns {beyond}; the whole support's is tried"
                       if cols is not None else f"the support curve {beyond}; not applied")
    else:
        return {"applied": False, "why": refused[-1], "refused": refused}
    # levelled, the object's own mean depth stays as the calibration left it (session 34, on a bar of draw 74:
    # unlevelled, its mean distance went 0.22 -> 0.39 mm). Not levelled (by default where the calibration warns: the
    # views were placed by their measured support planes, which hold the curve's 1, Z and Z^2 parts; the object
    # is off those placements by the rest, its level here (99 runs of draws 80-84: the model's mean signed
    # deviation followed it, correlation -0.87; the ten largest levels unlevelled: mean |d| 1.45 -> 0.29 mm
    # at best, two worse, bench/robustness/README.md)
    lv, slv = curve.mean_error(z_obj, xy_obj)
    if level:
        curve = curve.levelled(z_obj, xy_obj)

    def along_rays(v: ViewData) -> tuple[np.ndarray, np.ndarray]:  # Z -> Z - e(Z) (at the point's ray)
        d = v.depth_mm
        valid = d > 0
        new = d.copy()
        new[valid] = d[valid] - curve.error_mm(d[valid], rays[np.flatnonzero(valid)])
        z0 = v.points[:, 2]
        return v.points * (1.0 - 1e-3 * curve.error_mm(z0 * 1e3, rays[v.index]) / z0)[:, None], new

    correct_views(views, segs, plane_threshold_m, along_rays)
    g, sg = curve.mean_gain(z_obj, xy_obj)
    out = {"applied": True, "object_gain_pct": round(100 * g, 4), "object_gain_sigma_pct": round(100 * sg, 4),
           "object_depth_mm": [round(float(np.percentile(z_obj, q)), 1) for q in (5, 95)]}
    # the level at the object's depths: taken off (levelled), or what moved the object
    out |= {"levelled": level, "object_offset_mm": 0.0 if level else round(lv, 3),
            "object_level_mm": round(lv, 3), "object_offset_sigma_mm": round(slv, 3)}
    if curve.anchored:
        out["anchored_level_mm"] = round(lv, 3)
    if refused:  # the object's columns gave way to the whole support
        out["refused"] = refused
    return out | curve.to_dict()


def curve_beyond(curve, z_obj_mm: np.ndarray, xy_obj: np.ndarray, max_error_mm: float | None) -> str | None:
    """Why the support curve ``curve`` (:class:`~tofmetry.calibrate.FlatSupportCurve`) cannot be the range
    error the calibration left, as a predicate ("reads ... mm ..."), or None: it reads more than
    ``max_error_mm`` [mm] of it at the object's points (``z_obj_mm`` (N,) measured depths [mm], ``xy_obj``
    (N, 2) their normalised rays; the 1-99 % of the curve there as it stands, its station tie included and
    its ``level_mm`` taken off). None too without a bound or object points.

    Such a curve did not find the range error: its fit lost its footing (draw 118's pebble, read in its own
    image columns, where ``x`` hardly varies: -65 mm of level and -11 % of gain at the object, 2.1 mm at most
    from the whole support) or the support is not flat. Over the family's 1856 stored runs the curves read at
    most 3.8 mm of level there."""
    if max_error_mm is None or np.size(z_obj_mm) == 0:
        return None
    e = curve.error_mm(z_obj_mm, xy_obj)
    peak = float(np.max(np.abs(np.percentile(e, [1, 99]))))
    if peak <= max_error_mm:
        return None
    return (f"reads {peak:.1f} mm of range error at the object's depths, more than the depth calibration can have "
            f"left there ({max_error_mm:.1f} mm): its fit lost its footing or the support is not flat")
