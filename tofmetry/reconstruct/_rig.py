"""Models fused in the frame of a calibrated rig: one capture per sensor, placed by the rig's extrinsics.

A rig (``tofmetry calibrate rig``) knows where every sensor is: sensor ``i``'s camera-to-rig pose is
the inverse of its ``rig_to_sensor`` extrinsics, to 0.1-0.5 mm and 0.01 deg on the virtual rigs of
the tests -- better than a registration of views that overlap only partly could do, and without
the need for overlap. :class:`RigReconstruction` therefore registers nothing: each view is
prepared with its own sensor's intrinsics (and depth calibration, when given), segmented, and
fused at the rig's pose into one TSDF volume (each depth map with its own intrinsics); the model
is cropped, meshed and coloured as in :class:`~tofmetry.reconstruct.ReconstructionPipeline`, and
stays in the rig frame (sensor 0's camera frame: x right, y down, z forward, metres).

The rig's calibration is checked against the data: where two views see the same surface, robust
ICP of one view's object points onto the other's (:func:`rig_correction`) measures how far the
data would move the sensor. On the virtual rig of the tests a calibrated rig gives 0.3-0.4 mm at
the object (0.1 deg); a sensor knocked by 0.3 deg about its vertical axis, 7-8 mm; by 1 deg, 24 mm.
A pair whose correction moves the object by more than the pose gate (``registration.pose_gate_mm``,
3 mm) makes the run unreliable. The point-to-plane residual at the rig's poses
(:func:`overlap_residuals`) is reported beside it; it alone misses a shift along the surface
(a 1 deg knock raised its median from 0.7 to only 1.1 mm).
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial import cKDTree

from tofmetry.errors import InputError, SensorMismatchError
from tofmetry.reconstruct._colour import colour_model
from tofmetry.reconstruct._config import TRUNCATION_RULE
from tofmetry.reconstruct._model_build import fusion_depth, fusion_volume, fusion_weight, median_object_depth_m
from tofmetry.reconstruct._pipeline import ReconstructionPipeline, ReconstructionResult
from tofmetry.reconstruct._world import transform_plane


def overlap_residuals(points_a: np.ndarray, points_b: np.ndarray, normals_b: np.ndarray, radius_m: float = 0.01,
                      max_points: int = 20000, seed: int = 0) -> dict:
    """Point-to-plane distances of one view's points to another view's surface, where they overlap.

    Parameters
    ----------
    points_a : (N, 3) [m] world frame; points_b, normals_b : (M, 3) [m] and unit normals, world frame
    radius_m : a point of ``a`` overlaps ``b`` when ``b`` has a point within this distance [m]
    max_points : ``a`` is subsampled to at most this many points (seeded)

    Returns
    -------
    dict: overlap_points, overlap_share (of ``a``'s sampled points), median_abs_mm, p90_abs_mm,
    mean_mm (signed along ``b``'s normals); the figures are None without overlap
    """
    a = np.asarray(points_a, np.float64).reshape(-1, 3)
    if len(a) > max_points:
        a = a[np.random.default_rng(seed).choice(len(a), max_points, replace=False)]
    if len(a) == 0 or len(points_b) == 0:
        return {"overlap_points": 0, "overlap_share": 0.0, "median_abs_mm": None, "p90_abs_mm": None, "mean_mm": None}
    d, k = cKDTree(points_b).query(a, distance_upper_bound=radius_m, workers=-1)
    ok = np.isfinite(d)
    r = np.einsum("ij,ij->i", a[ok] - points_b[k[ok]], normals_b[k[ok]]) * 1e3
    n = int(ok.sum())
    return {"overlap_points": n, "overlap_share": float(ok.mean()),
            "median_abs_mm": float(np.median(np.abs(r))) if n else None,
            "p90_abs_mm": float(np.percentile(np.abs(r), 90)) if n else None,
            "mean_mm": float(r.mean()) if n else None}


def rig_correction(points_src: np.ndarray, normals_src: np.ndarray, points_dst: np.ndarray, normals_dst: np.ndarray,
                   voxel_m: float = 0.004, radii_m: tuple = (0.04, 0.015, 0.006)) -> dict:
    """The rigid correction that robust point-to-plane ICP applies to one view's points to fit another's.

    Both views are already in the rig frame: for a rig that holds its calibration the correction is
    at the noise level (tenths of a millimetre); a sensor knocked by 0.3 deg moves the object by
    millimetres. A pure overlap residual misses such a knock where the shift runs along the surface.

    Parameters
    ----------
    points_src, normals_src : (N, 3) [m] and normals of the view checked, rig frame
    points_dst, normals_dst : (M, 3) [m] and normals of the reference view, rig frame
    voxel_m : downsampling voxel [m]; radii_m : successive ICP correspondence radii [m] (the first
        bounds the displacement that can be measured)

    Returns
    -------
    dict: transform (4x4, list), rotation_deg, displacement_mm (largest displacement of a source
    point), fitness (matched share at the last radius), inlier_rmse_mm
    """
    from tofmetry.reconstruct._o3d import icp, voxel_down

    if len(points_src) < 10 or len(points_dst) < 10:
        return {"transform": np.eye(4).tolist(), "rotation_deg": 0.0, "displacement_mm": 0.0, "fitness": 0.0,
                "inlier_rmse_mm": float("nan")}
    src, _ = voxel_down(points_src, normals_src, voxel_m)
    dst, dn = voxel_down(points_dst, normals_dst, voxel_m)
    D = np.eye(4)
    for r in radii_m:
        m = icp(src, dst, dn, D, r)
        D = m.transform
    disp = np.linalg.norm(src @ D[:3, :3].T + D[:3, 3] - src, axis=1)
    ang = float(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1.0, 1.0))))
    return {"transform": D.tolist(), "rotation_deg": ang, "displacement_mm": float(disp.max() * 1e3),
            "fitness": float(m.fitness), "inlier_rmse_mm": float(m.inlier_rmse_m * 1e3)}


class RigReconstruction(ReconstructionPipeline):
    """Fuse one capture per sensor of a calibrated rig in the rig frame (no registration).

    Parameters
    ----------
    dataset : scan dataset whose views are named after the rig's sensors (``views/<sensor>/``)
    sensors : the rig's sensors (:func:`tofmetry.io.rig_json.read_rig`: ``name``, ``intrinsics``,
        ``rig_to_sensor``, ``rotation_std_deg``, ``translation_std_mm``); sensor 0 is the rig frame
    calibrations : sensor name -> DepthCalibration applied to that sensor's depth (others raw)
    config, progress : as :class:`~tofmetry.reconstruct.ReconstructionPipeline`
    """

    def __init__(self, dataset, sensors: list, calibrations: dict | None = None, config=None, progress=None):
        super().__init__(dataset, None, config, progress)
        by_name = {s.name: s for s in sensors}
        unknown = [n for n in dataset.names if n not in by_name]
        if unknown:
            raise InputError(f"{getattr(dataset, 'path', 'scan')}: view(s) {', '.join(unknown)} are not sensors of the "
                             f"rig ({', '.join(by_name)}); name each view folder after its sensor")
        bad = [n for n in (calibrations or {}) if n not in by_name]
        if bad:
            raise InputError(f"calibrations: {', '.join(bad)} are not sensors of the rig ({', '.join(by_name)})")
        rank = {s.name: k for k, s in enumerate(sensors)}
        self.kept = sorted(range(len(dataset)), key=lambda i: rank[dataset.names[i]])
        self.sensors = [by_name[dataset.names[i]] for i in self.kept]
        self.rig_frame = sensors[0].name
        self.calibrations = dict(calibrations or {})

    def load_rig_views(self) -> tuple[list, list]:
        """Prepared and segmented views, in rig order, each with its sensor's intrinsics."""
        views, segs = [], []
        with self.progress("preparing views", len(self.kept)) as adv:
            for i, s in zip(self.kept, self.sensors):
                cap = self.ds[i]
                if cap.shape != s.intrinsics.shape:
                    raise SensorMismatchError(f"view {s.name} ({cap.path}): depth {cap.shape} but the rig's intrinsics of "
                                              f"{s.name} are {s.intrinsics.shape}")
                cal = self.calibrations.get(s.name)
                if cal is not None:
                    try:
                        cal.check_compatible(sensor=cap.sensor, shape=cap.shape)
                    except SensorMismatchError as exc:
                        raise SensorMismatchError(f"view {s.name} ({cap.path}): {exc}") from None
                v, seg = self.prepare_segmented(cap, s.intrinsics, cal, s.name, cap.ir_mean() if cap.has_ir else None)
                views.append(v)
                segs.append(seg)
                adv()
        return views, segs

    def fuse_rig(self, views, segs, poses) -> tuple:
        """TSDF fusion of every view with its own intrinsics; voxel and truncation from the median object
        depth and the sensors' mean focal length (:meth:`ReconstructionPipeline.fuse`'s rule)."""
        fc = self.cfg.fusion
        z_med = median_object_depth_m(views, segs) * 1e3
        f = float(np.mean([s.intrinsics.fx for s in self.sensors]))
        voxel = fc.voxel_for(z_med, f)
        trunc = fc.trunc_for(z_med, voxel)
        tsdf = fusion_volume(self.sensors[0].intrinsics, voxel, trunc, self.cfg)
        with self.progress("TSDF fusion", len(views)) as adv:
            for v, seg, T, s in zip(views, segs, poses, self.sensors):
                tsdf.integrate(fusion_depth(v, seg, self.cfg), T, s.intrinsics, weight=fusion_weight(v, self.cfg))
                adv()
        return (*tsdf.extract(1.0), {"voxel_mm": voxel, "trunc_mm": trunc, "median_object_depth_mm": z_med,
                                     "min_views": 1, "crop_margin_mm": fc.crop_margin_for(z_med, f),
                                     "rule": "voxel = 0.6 * z / f (mean f of the sensors); " + TRUNCATION_RULE})

    def rig_check(self, views, segs, poses) -> tuple[list, list, list]:
        """Check the rig against the data, pair by pair: the ICP correction of one view's object points
        onto the other's (:func:`rig_correction`) and the overlap residual at the rig's poses.

        Returns
        -------
        edges (dicts, one per pair), reasons (pairs whose correction moves the object more than
        ``registration.pose_gate_mm``: the run is unreliable), warnings (views no pair checks)
        """
        gate = self.cfg.registration.pose_gate_mm
        obj = [(v.points[s.object_mask] @ T[:3, :3].T + T[:3, 3], v.normals[s.object_mask] @ T[:3, :3].T)
               for v, s, T in zip(views, segs, poses)]
        edges, reasons, checked = [], [], set()
        for i in range(len(views)):
            for j in range(i + 1, len(views)):
                a, b = views[i].name, views[j].name
                res = overlap_residuals(obj[j][0], *obj[i])
                corr = rig_correction(obj[j][0], obj[j][1], obj[i][0], obj[i][1])
                e = {"source": a, "target": b, "method": "rig", "accepted": True, "kept": True,
                     "fitness": corr["fitness"], "inlier_rmse_mm": corr["inlier_rmse_mm"],
                     "correction_deg": corr["rotation_deg"], "correction_mm": corr["displacement_mm"],
                     "overlap": res}
                if corr["fitness"] < 0.2 or res["overlap_points"] < 200:
                    e["verdict"], e["reason"] = "not checked", "too little overlap to check the rig"
                elif corr["displacement_mm"] > gate:
                    e["verdict"] = "inconsistent"
                    e["reason"] = (f"the data move {b} by {corr['displacement_mm']:.1f} mm / {corr['rotation_deg']:.2f} deg "
                                   f"against {a} (> {gate:g} mm): the rig's calibration does not hold for these "
                                   "captures (a sensor moved?)")
                    reasons.append(f"{a}-{b}: {e['reason']}")
                else:
                    checked |= {a, b}
                    e["verdict"] = "consistent"
                    e["reason"] = f"the data move {b} by {corr['displacement_mm']:.2f} mm (<= {gate:g} mm) against {a}"
                edges.append(e)
        warnings = [f"view {v.name}: no overlapping view checks its rig pose" for v in views
                    if v.name not in checked and not any(v.name in r for r in reasons)] if len(views) > 1 else []
        return edges, reasons, warnings

    def run(self) -> ReconstructionResult:
        t0 = time.perf_counter()
        views, segs = self.load_rig_views()
        poses = np.stack([s.rig_to_sensor.inverse().matrix for s in self.sensors])  # camera -> rig
        t1 = time.perf_counter()
        edges, reasons, warnings = self.rig_check(views, segs, poses)
        t2 = time.perf_counter()
        V, F, N, P, PN, fusion_info = self.fuse_rig(views, segs, poses)
        t3 = time.perf_counter()
        world_obj = np.concatenate([v.points[s.object_mask] @ T[:3, :3].T + T[:3, 3]
                                    for v, s, T in zip(views, segs, poses)])
        k = next((k for k, s in enumerate(segs) if s.plane is not None), None)
        plane_w = None if k is None else transform_plane(segs[k].plane, poses[k])
        V, F, N, P, PN, poisson = self.crop_model(V, F, N, P, PN, world_obj, plane_w, fusion_info["crop_margin_mm"])
        t4 = time.perf_counter()
        colours, colour_diag = None, None
        if self.cfg.color:
            sets = {"points": (P, PN), "mesh": (V, N), **({"poisson": (poisson[0], None)} if poisson is not None else {})}
            colours, colour_diag = colour_model(self.ds, self.kept, views, poses, sets,
                                                [s.intrinsics for s in self.sensors], self.progress)
        t5 = time.perf_counter()
        self.timings = {"views_s": t1 - t0, "registration_s": 0.0, "rig_check_s": t2 - t1, "adjustment_s": 0.0,
                        "fusion_s": t3 - t2, "meshing_s": t4 - t3, "color_s": t5 - t4, "total_s": t5 - t0}
        names = [v.name for v in views]
        z_med = fusion_info["median_object_depth_mm"]
        rig = {"rig_frame": self.rig_frame, "sensors": [
            {"name": s.name, "rotation_std_deg": list(s.rotation_std_deg), "translation_std_mm": list(s.translation_std_mm),
             "calibrated": s.name in self.calibrations,
             # 1-sigma displacement at the object: translation std + rotation std times the object's range
             "predicted_displacement_mm": float(np.linalg.norm(s.translation_std_mm)
                                                + np.radians(np.linalg.norm(s.rotation_std_deg)) * z_med)}
            for s in self.sensors], "pose_gate_mm": self.cfg.registration.pose_gate_mm}
        world = {"frame": f"rig frame: the camera frame of sensor {self.rig_frame} (x right, y down, z forward)",
                 "from_first_camera": poses[0].tolist()}
        verdict = {"reliable": not reasons, "reasons": reasons, "warnings": warnings,
                   "views": {n: {"verdict": "placed by the rig", "reason": "rig extrinsics"} for n in names}}
        diag = {"consistency": {"method": "rig", "reasons": reasons}, "reliable": not reasons, "reliability": verdict,
                "rig": rig, "world": world, "views": {v.name: v.stats for v in views}, "fusion": fusion_info,
                "timings_s": self.timings, "adjustment": None, "left_out": {}, "color": colour_diag,
                "calibrated": bool(self.calibrations), "amplitude_corrected": False,
                "intrinsics": {s.name: s.intrinsics.to_dict() for s in self.sensors},
                "working_range_mm": self.working_range_mm(), "config": self.cfg.model_dump()}
        return ReconstructionResult(names, poses, edges, V, F, N, P, PN, poisson, plane_w, diag, colours)
