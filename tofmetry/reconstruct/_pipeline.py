"""The reconstruction pipeline: views -> segmentation -> registration -> pose graph -> TSDF -> mesh.

:class:`ReconstructionPipeline` owns the looping, progress and outputs; the algorithms are
the small classes/functions of the sibling modules (kiss-icp style).
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from tofmetry._shared.geometry import transform_points
from tofmetry.errors import EstimationError, InputError, SensorMismatchError
from tofmetry.reconstruct._adjust_circle import off_axis_reason
from tofmetry.reconstruct._adjust_result import AdjustResult
from tofmetry.reconstruct._adjust_stage import joint_adjustment, scale_budget_of
from tofmetry.reconstruct._calibration_support import (calibration_central_mm, depth_field_prior, extrapolated_points,
                                                     extrapolation_scale_sigma, extrapolation_warning,
                                                     local_prediction)
from tofmetry.reconstruct._colour import colour_model
from tofmetry.reconstruct._config import ReconstructionConfig
from tofmetry.reconstruct._model_build import (
    crop_model,
    fuse_views,
    median_object_depth_m,
    object_depth_span_mm,
    world_plane,
)
from tofmetry.reconstruct._mat_stage import (calibration_beyond_gate, departures, judge_placements, pattern_scale,
                                             pattern_scale_warning, place_views)
from tofmetry.reconstruct._mat_scale import budget_held, held_poses, placed_scale
from tofmetry.reconstruct._mat_tilt import MatDepthTilt, take_off_depth_tilt
from tofmetry.reconstruct._preprocess import ViewData, prepare_view
from tofmetry.reconstruct._support_curve import correct_by_support
from tofmetry.reconstruct._register_stage import register_views
from tofmetry.reconstruct._regview import RegView, leaves_yaw_free, make_reg_view
from tofmetry.reconstruct._scale_report import scale_report
from tofmetry.reconstruct._segment import Segmentation, segment_object
from tofmetry.reconstruct._thin_slab import slab_reason, thin_slab_check
from tofmetry.reconstruct._turntable import turntable_poses
from tofmetry.reconstruct._turntable_bridge import UNCONFIRMED_REASON
from tofmetry.reconstruct._verdict import assess
from tofmetry.reconstruct._world import support_plane_frame, transform_plane

@contextmanager
def _no_progress(description: str, total: int | None):
    yield lambda n=1: None


@dataclass
class ReconstructionResult:
    """Outputs of a reconstruction (metres; world frame: the support plane z = 0 by default, see
    ``diagnostics["world"]``; the first camera's frame without a support plane).

    Attributes
    ----------
    names : view names in processing order
    poses : (V, 4, 4) camera-to-world
    edges : per-pair registration diagnostics (fitness, inlier RMSE, kept, residuals)
    mesh_vertices, mesh_triangles, mesh_normals : cropped TSDF mesh
    points, normals : cropped fused cloud
    poisson : (vertices, triangles) or None
    support_plane : (4,) world-frame plane (unit normal up, offset) or None
    diagnostics : per-view stats, fusion parameters, timings [s], "reliable" (bool), "reliability"
        (:func:`~tofmetry.reconstruct.assess`: reasons, warnings, per-view verdicts; edges carry theirs),
        "consistency" (the pose-graph consistency gate), "scale" (predicted scale uncertainty),
        "world" (the output frame and its transform from the first camera's frame), "left_out",
        "color" (share coloured per output and per view; None without colour frames)
    colours : output name ("points", "mesh", "poisson") -> :class:`~tofmetry.reconstruct.ModelColours`,
        or None (no colour frames, or ``config.color`` off)
    """

    names: list
    poses: np.ndarray
    edges: list
    mesh_vertices: np.ndarray
    mesh_triangles: np.ndarray
    mesh_normals: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    poisson: tuple | None
    support_plane: np.ndarray | None
    diagnostics: dict = field(default_factory=dict)
    colours: dict | None = None


class ReconstructionPipeline:
    """Run the whole chain on a scan dataset.

    Parameters
    ----------
    dataset : tofmetry.io.ScanDataset (``len`` / ``[i]`` -> Capture, ``names``)
    calibration : tofmetry.calibrate.DepthCalibration or None (raw data)
    config : ReconstructionConfig
    progress : callable(description, total) -> context manager yielding ``advance(n=1)``
    white_map : (H, W) white amplitude reference at 1 m (:func:`white_amplitude_map`; enables the amplitude-bias correction)
    """

    def __init__(self, dataset, calibration=None, config: ReconstructionConfig | None = None, progress=None,
                 white_map: np.ndarray | None = None):
        if len(dataset) < 2:
            raise InputError(f"{getattr(dataset, 'path', 'scan')}: {len(dataset)} view(s); at least 2 are needed")
        self.ds = dataset
        self.cal = calibration
        #: the calibration's prediction with its error between stations taken where the object lies
        #: (set by run(): local_prediction); it judges the run, the global one bounds the gain
        self.prediction_at_object = None if calibration is None else (calibration.prediction or {})
        self.cfg = config or ReconstructionConfig()
        self.progress = progress or _no_progress
        self.white_map = white_map
        self.timings: dict[str, float] = {}
        self.adjust_failure: str | None = None
        self.kept: list[int] = list(range(len(dataset)))
        self.left_out: dict[str, str] = {}
        self.other_edges: list[dict] = []
        self.turntable: dict | None = None  # the declared turntable's axis fit and bridges (turntable_bridges)
        self.pattern: dict | None = None  # the edges searched again by the IR pattern (search_by_pattern)
        self.tied_starts: list[np.ndarray] = []  # pose-graph poses of the choices tied with the chosen one
        self.mat = None  # the views' placements on a dot mat (place_views), when registration.mat is set
        self.mat_tilt = None  # the depth's tilt the mat's dots measured and took off (MatDepthTilt)

    # -- stages -----------------------------------------------------------------------------
    def _intrinsics(self, cap):
        if self.cal is not None:
            self.cal.check_compatible(sensor=cap.sensor, shape=cap.shape)
            return self.cal.intrinsics
        return cap.intrinsics()[0]

    def prepare_segmented(self, cap, intr, cal, name: str, ir: np.ndarray | None,
                          white_map: np.ndarray | None = None) -> tuple[ViewData, Segmentation]:
        """One capture's view (:func:`prepare_view`) and its object segmentation; a failed
        segmentation names the view."""
        v = prepare_view(cap.depth_stack(), intr, cal, self.cfg.preprocess, name=name, ir=ir, white_map=white_map)
        outside, tol = extrapolated_points(v.points, cal)
        try:
            s = segment_object(v.points, self.cfg.segment, seed=self.cfg.registration.seed, height_tolerance_m=tol,
                               normals=v.normals, grid=(v.index, intr.shape))
        except EstimationError as exc:
            raise EstimationError(f"view {name}: {exc}") from None
        v.stats["object_points"] = int(s.object_mask.sum())
        if outside is not None:
            v.stats["object_points_extrapolated"] = int((outside & s.object_mask).sum())
        return v, s

    def load_views(self) -> tuple[list[ViewData], list[Segmentation], list[RegView], object]:
        views, segs, regs = [], [], []
        intr0 = None
        with self.progress("preparing views", len(self.ds)) as adv:
            for i in range(len(self.ds)):
                cap = self.ds[i]
                name = self.ds.names[i]
                try:
                    intr = self._intrinsics(cap)
                except SensorMismatchError as exc:
                    raise SensorMismatchError(f"view {name} ({cap.path}): {exc}") from None
                if intr0 is None:
                    intr0 = intr
                elif intr.shape != intr0.shape:
                    raise SensorMismatchError(f"view {name}: depth {intr.shape} differs from the first view's {intr0.shape}")
                ir = cap.ir_mean() if cap.has_ir else None
                if self.white_map is not None and ir is None:
                    raise InputError(f"view {name}: the amplitude correction needs IR frames, {cap.path} has none")
                if self.white_map is not None and self.white_map.shape != intr.shape:
                    raise SensorMismatchError(f"amplitude reference is {self.white_map.shape}, view {name} is {intr.shape}")
                v, s = self.prepare_segmented(cap, intr, self.cal, name, ir, self.white_map)
                views.append(v)
                segs.append(s)
                regs.append(make_reg_view(v, s, self.cfg.registration, intr, self.white_map))
                adv()
        return views, segs, regs, intr0

    def register(self, regs: list[RegView]):
        """The views registered into an optimised pose graph (:func:`register_views`); sets :attr:`kept`,
        :attr:`left_out`, :attr:`other_edges`, :attr:`tied_starts`, :attr:`pattern` and :attr:`turntable`,
        and returns the graph."""
        r = register_views(regs, list(self.ds.names), self.cfg.registration, self.progress)
        self.kept, self.left_out, self.other_edges = r.kept, r.left_out, r.other_edges
        self.tied_starts, self.pattern, self.turntable = r.tied_starts, r.pattern, r.turntable
        return r.graph

    def adjust(self, views: list[ViewData], segs: list[Segmentation], regs: list[RegView],
               poses: np.ndarray, loops: list[dict] | None = None, edges=(), edge_ir=(),
               yaw_free: bool = False, tied=(),
               placed: tuple[np.ndarray, np.ndarray] | None = None) -> AdjustResult | None:
        """The joint fit of the poses (:func:`joint_adjustment`; its failure in :attr:`adjust_failure`)."""
        res, self.adjust_failure = joint_adjustment(views, segs, regs, poses, self.cfg, self.cal, self.white_map,
                                                    self.progress, turntable=bool(self.turntable), loops=loops,
                                                    edges=edges, edge_ir=edge_ir, yaw_free=yaw_free, tied=tied,
                                                    placed=placed,
                                                    tilt_measured_mm=None if self.mat_tilt is None else
                                                    self.mat_tilt.sigma_mm)
        return res

    def correct_by_support(self, views, segs, intr, anchors: list | None = None, level: bool = True) -> dict:
        """The range error the flat support shows, subtracted from every view before the fusion
        (:func:`~tofmetry.reconstruct._support_curve.correct_by_support`, ``anchors`` the dot mat's
        planes); its report."""
        pc = self.cfg.preprocess
        if not pc.support_curve:
            return {"applied": False, "why": "off (preprocess.support_curve)"}
        with self.progress("range curve from the support", 1) as adv:
            report = correct_by_support(views, segs, intr, pc.support_curve_band_mm * 1e-3, pc.support_curve_clear_px,
                                        self.cfg.segment.plane_threshold_mm * 1e-3, pc.support_curve_step_mm,
                                        pc.support_curve_smooth_mm, anchors, level,
                                        self.calibration_stations_mm() if pc.support_curve_stations else None,
                                        pc.support_curve_columns, tuple(pc.support_curve_lateral),
                                        self.support_curve_bound_mm(), pc.support_curve_variable)
            adv()
        return report

    def support_curve_bound_mm(self) -> float | None:
        """The most range error a support curve may read at the object's depths [mm]
        (``preprocess.support_curve_max_mm`` plus ``support_curve_max_sigmas`` times the calibration's
        predicted error there); None without a bound or a calibration."""
        pc = self.cfg.preprocess
        predicted = calibration_central_mm(self.prediction_at_object) if self.cal is not None else None
        if pc.support_curve_max_mm is None or predicted is None:
            return None
        return pc.support_curve_max_mm + pc.support_curve_max_sigmas * predicted

    def calibration_stations_mm(self) -> list[float] | None:
        """The depths of the depth calibration's stations [mm] (its fit's samples), None without them."""
        rows = ((self.cal.diagnostics or {}).get("samples") or []) if self.cal is not None else []
        z = [float(r["center_mm"]) for r in rows if isinstance(r, dict) and np.isfinite(r.get("center_mm", np.nan))]
        return z or None

    def level_from_support(self) -> bool:
        """Whether the support curve's level at the object's depths is taken off the object
        (``preprocess.support_curve_level``; 'auto': where the calibration predicts more than
        ``registration.max_calibration_mm`` of its own error there, the warning's condition)."""
        mode = self.cfg.preprocess.support_curve_level
        if mode != "auto":
            return mode == "support"
        if self.mat is not None and self.cfg.registration.mat_plane_at_object:  # placed at the object's depths
            return False
        pc = calibration_central_mm(self.prediction_at_object) if self.cal is not None else None
        return pc is not None and pc > self.cfg.registration.max_calibration_mm

    def anchored_support(self, views, segs, regs, intr, rc) -> dict | None:
        """On a dot mat whose dots gave at least three views their plane (:attr:`mat`'s ``dot_planes``),
        the support curve with those planes as anchors, subtracted now, whole, and the views placed
        again on the corrected depth (their registration clouds rebuilt, ``regs`` in place); its report,
        or None (the curve then comes after the poses, levelled)."""
        if not (self.cfg.preprocess.support_curve and self.cfg.preprocess.support_anchor == "whole"):
            return None
        anchors = self.mat_anchors(self.ds.names)
        if anchors is None:
            return None
        report = self.correct_by_support(views, segs, intr, anchors, level=False)
        if report.get("applied"):
            regs[:] = [make_reg_view(v, s, rc, intr, self.white_map) for v, s in zip(views, segs)]
            self.place_on_mat(views, segs, regs, intr, "placing the views on the mat again")
        return report

    def mat_field(self, views, segs, intr):
        """The depth calibration's residual field where the object lies
        (:func:`~tofmetry.reconstruct._calibration_support.depth_field_prior`, its tilt
        ``registration.uncalibrated_tilt_mm`` where it left that uncalibrated, or what the mat's dots
        left of it, :attr:`mat_tilt`), which the mat's placements weigh their support plane's tilt by;
        None without a calibration."""
        if self.cal is None:
            return None
        return depth_field_prior(self.cal.prediction or {}, object_depth_span_mm(views, segs), intr,
                                 tilt_sigma_mm=self.cfg.registration.uncalibrated_tilt_mm,
                                 tilt_measured_mm=None if self.mat_tilt is None else self.mat_tilt.sigma_mm)

    def tilt_from_mat(self, views, segs, regs, intr, rc) -> MatDepthTilt | None:
        """The depth's tilt across the image, measured by the mat's dots against each view's support
        (:func:`~tofmetry.reconstruct._mat_tilt.depth_tilt_from_dots`, weighed against what the
        calibration may have left), taken off every view's depth; the support planes refitted, the
        registration clouds rebuilt (``regs`` in place) and the views placed again. Sets and returns
        :attr:`mat_tilt`; None (nothing changed) without a calibration or with fewer than three views
        whose dots gave their plane."""
        field = self.mat_field(views, segs, intr)
        if field is None or self.mat is None or not rc.mat_depth_tilt:
            return None
        thr = self.cfg.segment.plane_threshold_mm * 1e-3
        mt = take_off_depth_tilt(views, segs, intr, [self.mat.dot_planes.get(n) for n in self.ds.names],
                                 field.tilt_sigma_m * 1e3, thr, field)
        if mt is None:
            return None
        self.mat_tilt = mt
        regs[:] = [make_reg_view(v, s, rc, intr, self.white_map) for v, s in zip(views, segs)]
        self.place_on_mat(views, segs, regs, intr, "placing the views on the mat again (depth tilt taken off)")
        return mt

    def mat_scale_inputs(self, views, segs, names: list[str]) -> tuple:
        """What the mat's scale terms take of the views ``names``: the object's points [m] and normals per
        view (camera frame), each view's :class:`~tofmetry.reconstruct._mat_locate.MatFix` (None: not
        placed by dots), and the placements' tilt [deg] and height [m] fallback sigmas (the height's the
        calibration's predicted central error, the configured prior without one)."""
        rc = self.cfg.registration
        height_mm = calibration_central_mm(None if self.cal is None else self.cal.prediction) or rc.mat_prior_mm
        return ([v.points[s.object_mask] for v, s in zip(views, segs)],
                [v.normals[s.object_mask] for v, s in zip(views, segs)],
                [self.mat.fixes.get(n) for n in names], rc.mat_prior_deg, height_mm * 1e-3)

    def hold_mat_scale(self, views, segs, start, poses, intr, adj: AdjustResult, names: list[str]):
        """The joint fit's ``poses`` with their scale weighed against the mat's placements ``start``
        (:func:`~tofmetry.reconstruct._mat_scale.held_poses`): (poses, ScaleHold)."""
        fit = scale_budget_of(views, segs, poses, intr, median_object_depth_m(views, segs), None, 0.0, adj)(0.0, 0.0)
        P, N, fixes, tilt_deg, height_m = self.mat_scale_inputs(views, segs, names)
        return held_poses(P, N, start, poses, fixes, (fit.get("poses") or {}).get("sigma", np.nan),
                          adj.pose_covariance, tilt_deg, height_m)

    def placements_scale(self, views, segs, placed, names: list[str]):
        """The model's scale 1-sigma the mat's placements ``placed`` (V, 4, 4) leave where they stand
        unrefined (:func:`~tofmetry.reconstruct._mat_scale.placed_scale`): a ScaleHold."""
        P, N, fixes, tilt_deg, height_m = self.mat_scale_inputs(views, segs, names)
        return placed_scale(P, N, placed, fixes, tilt_deg, height_m)

    def place_on_mat(self, views, segs, regs, intr, what: str) -> None:
        """Every view placed on the dot mat (:func:`place_views`, into :attr:`mat`), its tilt weighed
        by the calibration's residual field (:meth:`mat_field`)."""
        with self.progress(what, 1) as adv:
            self.mat = place_views(views, segs, regs, intr, self.white_map, self.cfg.registration, list(self.ds.names),
                                   self.cfg.segment.plane_threshold_mm * 1e-3,
                                   self.cfg.preprocess.support_anchor != "none", self.mat_field(views, segs, intr))
            adv()

    def mat_anchors(self, names: list[str]) -> list | None:
        """Per view of ``names``, ``(a, b, c)`` and their covariance of the plane the mat's dots alone gave
        it (None for a view without), or None when fewer than three views have one (or no mat)."""
        dp = {} if self.mat is None else self.mat.dot_planes
        if len(dp) < 3:
            return None
        return [(dp[n].inverse_depth, dp[n].inverse_depth_cov) if n in dp else None for n in names]

    def fuse(self, views, segs, poses, intr):
        """TSDF fusion of the views at ``poses`` (:func:`fuse_views`)."""
        return fuse_views(views, segs, poses, intr, self.cfg, self.progress)

    def crop_model(self, V, F, N, P, PN, world_obj: np.ndarray, plane_w: np.ndarray | None,
                   margin_mm: float | None = None) -> tuple:
        """The fused model cropped to the object (:func:`~tofmetry.reconstruct._model_build.crop_model`)."""
        return crop_model(V, F, N, P, PN, world_obj, plane_w, self.cfg, margin_mm)

    def working_range_mm(self) -> list[float]:
        """Depth range [mm] kept by the preprocessing (working range within the calibrated span)."""
        lo, hi = self.cfg.preprocess.min_mm, self.cfg.preprocess.max_mm
        if self.cal is not None:
            lo, hi = max(lo, float(self.cal.valid_range_mm[0])), min(hi, float(self.cal.valid_range_mm[1]))
        return [float(lo), float(hi)]

    # -- driver -------------------------------------------------------------------------------
    def run(self) -> ReconstructionResult:
        t0 = time.perf_counter()
        views, segs, regs, intr = self.load_views()
        if self.cal is not None:  # the calibration's predicted error where this object lies
            self.prediction_at_object = local_prediction(self.cal.prediction or {}, object_depth_span_mm(views, segs))
        t1 = time.perf_counter()
        rc = self.cfg.registration
        if rc.mat is not None:  # each view placed on the dot mat on its own
            self.place_on_mat(views, segs, regs, intr, "placing the views on the mat")
            self.tilt_from_mat(views, segs, regs, intr, rc)
            support = self.anchored_support(views, segs, regs, intr, rc)
            if len(self.mat.kept) < 2:
                raise EstimationError("fewer than two views were placed on the dot mat: " + "; ".join(
                    f"{n}: {f.reason}" for n, f in self.mat.fixes.items() if not f.located))
            self.kept, self.left_out, graph = self.mat.kept, dict(self.mat.left_out), self.mat.graph
        else:
            graph, support = self.register(regs), None
        if len(self.kept) < len(views):  # views no registration links to the others are left out
            views, segs, regs = ([x[k] for k in self.kept] for x in (views, segs, regs))
        names = [self.ds.names[k] for k in self.kept]
        t2a = time.perf_counter()
        idx = {n: k for k, n in enumerate(names)}
        kept_edges = [e for e in graph.edges if e.get("kept") and e["source"] in idx and e["target"] in idx]
        start = graph.poses
        if self.turntable:  # the declared turntable places the views; the joint fit refines them within its accuracy
            start, self.turntable["poses"] = turntable_poses(graph.poses, self.kept,
                                                             self.cfg.registration.turntable_step_deg,
                                                             np.array(self.turntable["axis"]),
                                                             self.cfg.registration.turntable_tol_deg)
        # on a mat the placements may overrule the fit, which corrects the views' depth: what it found is kept
        before_fit = [(v.points, v.depth_mm, sg.plane) for v, sg in zip(views, segs)] if self.mat is not None else []
        adj = self.adjust(views, segs, regs, start, (graph.consistency or {}).get("loops"),
                          [(idx[e["source"]], idx[e["target"]]) for e in kept_edges],
                          [e.get("ir_corr") for e in kept_edges],
                          self.mat is None and any(leaves_yaw_free(e.get("conditioning"), rc.yaw_free_ratio)
                                                   for e in kept_edges),
                          self.tied_starts, None if self.mat is None else self.mat.prior(rc.mat_prior_deg, rc.mat_prior_mm))
        t2 = time.perf_counter()
        mat_kept, mat_unsure = None, None
        if self.mat is not None and adj is not None:  # the placements stand unless the fit is surely better
            mat_unsure = calibration_beyond_gate(adj.calibration_pose, rc.pose_gate_deg, rc.pose_gate_mm)
            centre = np.concatenate([v.points[s.object_mask] @ T[:3, :3].T + T[:3, 3]
                                     for v, s, T in zip(views, segs, start)]).mean(0)
            mat_kept = None if mat_unsure else departures(start, adj.poses, centre, rc.pose_gate_deg, rc.pose_gate_mm,
                                                          names, self.mat.allowed_moves(centre))
            if mat_kept or mat_unsure:  # a fit not kept leaves the views' depth as it found it
                adj = None
                for v, sg, (pts, depth, plane) in zip(views, segs, before_fit):
                    v.points, v.depth_mm, sg.plane = pts, depth, plane
        poses, hold, placed = start if adj is None else adj.poses, None, None
        if self.mat is not None and adj is not None and rc.mat_holds_scale:  # the fit may not bend the mat's scale
            poses, hold = self.hold_mat_scale(views, segs, start, poses, intr, adj, names)
        elif self.mat is not None and adj is None:  # the placements are the poses: their own scale uncertainty
            placed = self.placements_scale(views, segs, start, names)
        if support is None:  # the curve after the poses, levelled on the object unless the calibration warns there
            # (level_from_support); on a mat, its gain anchored
            gain = self.cfg.preprocess.support_anchor == "gain"
            support = self.correct_by_support(views, segs, intr, self.mat_anchors(names) if gain else None,
                                              level=gain or not self.level_from_support())
        t2b = time.perf_counter()
        V, F, N, P, PN, fusion_info = self.fuse(views, segs, poses, intr)
        t3 = time.perf_counter()
        world_obj = np.concatenate([
            v.points[s.object_mask] @ T[:3, :3].T + T[:3, 3] for v, s, T in zip(views, segs, poses)])
        plane_w = world_plane(segs[0].plane, poses[0])
        V, F, N, P, PN, poisson = self.crop_model(V, F, N, P, PN, world_obj, plane_w, fusion_info["crop_margin_mm"])
        W, poses_fit = np.eye(4), poses  # poses_fit: in the frame of the joint fit's increments
        if self.cfg.world_frame == "support" and plane_w is not None and self.mat is None:
            W = support_plane_frame(plane_w, world_obj, poses[0])
            poses = np.einsum("ij,vjk->vik", W, poses)
            V, P = transform_points(V, W), transform_points(P, W)
            N, PN = N @ W[:3, :3].T, PN @ W[:3, :3].T
            if poisson is not None:
                poisson = (transform_points(poisson[0], W), poisson[1])
            plane_w = transform_plane(plane_w, W)
        slab = thin_slab_check(P, regs, poses, rc.icp_radii_mm[-1] * 1e-3, rc.slab_max_thickness_share)
        t4 = time.perf_counter()
        colours, colour_diag = None, None
        if self.cfg.color:
            sets = {"points": (P, PN), "mesh": (V, N), **({"poisson": (poisson[0], None)} if poisson is not None else {})}
            colours, colour_diag = colour_model(self.ds, self.kept, views, poses, sets, [intr] * len(views),
                                                self.progress)
        t5 = time.perf_counter()
        self.timings = {"views_s": t1 - t0, "registration_s": t2a - t1, "adjustment_s": t2 - t2a,
                        "support_curve_s": t2b - t2, "fusion_s": t3 - t2b,
                        "meshing_s": t4 - t3, "color_s": t5 - t4, "total_s": t5 - t0}
        adj_d = ({"failed": self.adjust_failure} if self.adjust_failure else None) if adj is None else adj.to_dict(names)
        if adj is not None:  # the coefficient the model was corrected with: the preprocessing's plus dk
            amp = adj_d["amplitude_bias"]
            amp["k_mm_per_ln"] = (None if self.white_map is None else
                                  round(self.cfg.preprocess.amplitude_k_mm_per_ln + (amp["dk_mm_per_ln"] or 0.0), 4))
        edges = graph.edges + self.other_edges
        pred = None if self.cal is None else (self.cal.prediction or {})
        z_obj = median_object_depth_m(views, segs)
        verdict = assess(names, edges, graph.consistency, self.left_out, adj_d, self.prediction_at_object,
                         rc.max_calibration_mm,
                         rc.pose_gate_deg, rc.pose_gate_mm, rc.yaw_free_ratio, rc.max_left_out,
                         turntable_accuracy_deg=rc.turntable_accuracy_deg,
                         turntable_placed=bool(self.turntable), restart_share=rc.restart_share,
                         placed=None if self.mat is None else {"by": "the dot mat", "views": self.mat.view_verdicts()})
        if self.mat is not None:
            judge_placements(verdict, self.mat, mat_unsure, mat_kept, rc.pose_gate_deg, rc.pose_gate_mm)
        mat_scale = None if self.mat is None else pattern_scale(self.mat.fixes, calibration_central_mm(pred), rc.mat_scale_floor_pct)
        if pattern_scale_warning(mat_scale):
            verdict["warnings"].append(pattern_scale_warning(mat_scale))
        verdict["warnings"] += (support or {}).get("refused", [])  # curves beyond what the calibration can have left
        if slab is not None and slab["slab"] and self.mat is None:  # the mat places both faces
            verdict["reasons"].append(slab_reason(slab, names))
            verdict["reliable"] = False
        off_axis = off_axis_reason(adj_d, names, rc.turn_axis_max_sigmas)
        if off_axis:
            verdict["reasons"].append(off_axis)
            verdict["reliable"] = False
        if self.turntable and self.turntable.get("axis_from", "").startswith("rejected"):
            verdict["reasons"].append(UNCONFIRMED_REASON)
            verdict["reliable"] = False
        if self.cal is not None and self.cal.support is not None:
            w = extrapolation_warning({v.name: v.stats for v in views}, pred, self.cal.support.range_mm)
            if w:
                verdict["warnings"].append(w)
        world = ({"frame": "the dot mat's: z up from the sheet, origin at its centre, x along its width",
                  "from_first_camera": poses[0].tolist()} if self.mat is not None else
                 {"frame": "support plane z = 0 (normal up), origin under the object's footprint centre, x along the "
                           "first view's viewing direction projected on the plane", "from_first_camera": W.tolist()}
                 if not np.allclose(W, np.eye(4)) else {"frame": "camera frame of the first view (x right, y down, z "
                                                                 "forward)", "from_first_camera": W.tolist()})
        diag = {"consistency": graph.consistency, "reliable": bool(verdict["reliable"]), "reliability": verdict,
                "scale": scale_report(adj_d, pred, z_obj * 1e3,
                                      budget_held(scale_budget_of(views, segs, poses_fit, intr, z_obj, self.white_map,
                                                                  rc.amplitude_k_sigma_mm, adj), hold),
                                      rc.amplitude_k_sigma_mm if self.white_map is not None else None,
                                      rc.scale_floor_pct, support, object_depth_span_mm(views, segs),
                                      None if self.cal is None or self.cal.support is None else
                                      extrapolation_scale_sigma({v.name: v.stats for v in views}, pred),
                                      None if placed is None else 100 * placed.mat_sigma)
                | ({"mat_pattern": mat_scale} if self.mat is not None else {}),
                "world": world, "slab": slab, "support_curve": support,
                "views": {v.name: v.stats for v in views}, "fusion": fusion_info, "timings_s": self.timings,
                "adjustment": adj_d, "mat_scale_hold": None if hold is None else hold.to_dict(),
                "left_out": self.left_out, "color": colour_diag, "turntable": self.turntable,
                "pattern": self.pattern, "mat": None if self.mat is None else self.mat.to_dict(),
                "mat_depth_tilt": None if self.mat_tilt is None else self.mat_tilt.to_dict(),
                "mat_range_offset": None if self.mat is None else self.mat.range_offset,
                "calibrated": self.cal is not None, "amplitude_corrected": self.white_map is not None, "intrinsics": intr.to_dict(),
                "calibration_local": (self.prediction_at_object or {}).get("local"),
                "working_range_mm": self.working_range_mm(), "config": self.cfg.model_dump()}
        return ReconstructionResult(names, poses, edges, V, F, N, P, PN, poisson, plane_w, diag, colours)
