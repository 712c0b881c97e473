"""Typed configuration of every reconstruction stage (pydantic, documented fields)."""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, Field

from tofmetry._shared.study_constants import AMPLITUDE_BIAS_MM_PER_LN


class PreprocessConfig(BaseModel):
    """Per-view depth preparation (study §3.2, §5.2.1)."""

    robust_k: float = Field(3.0, gt=0, description="temporal outlier rejection: median +- k robust sigmas")
    min_valid_share: float = Field(0.5, ge=0, le=1, description="a pixel needs valid samples in this share of the frames")
    min_mm: float = Field(500.0, description="working range: nearest depth kept [mm] (Kinect v2 spec: 500)")
    max_mm: float = Field(2500.0, description="working range: farthest depth kept [mm]; small-object scans are at ~1 m")
    remove_flying: bool = Field(True, description="remove flying (mixed) pixels with tofmetry.assess.remove_flying_pixels")
    flying_max_support_between: int = Field(2, ge=0, le=8, description="a pixel between a nearer and a farther "
                                            "neighbour is flying when at most this many neighbours support it "
                                            "(tofmetry.assess.FlyingPixelParams.max_support_between). 8 also takes "
                                            "the steep surfaces (beyond the filter's 60 deg): tried on draw 73 "
                                            "(bench/robustness/README.md, session 33), mixed, not the default")
    support_curve: bool = Field(True, description="read the range error the calibration left from the flat support "
                                "(tofmetry.calibrate.flat_support_curve: the support seen over 0.5-1.5 m is not flat "
                                "by as much) and subtract it from every view before the fusion, the poses already "
                                "fixed. Needs a support plane in 3 views spanning 3 knot steps of depth")
    support_curve_level: Literal["auto", "support", "calibration"] = Field(
        "auto", description="the support curve's value at the object's depths: 'support' takes it off the object too "
        "(the views' placements took their height from the measured support, which holds the curve's 1, Z and Z^2 "
        "parts; the object is off them by the rest); 'calibration' levels the curve there, the object's mean depth "
        "staying as the calibration left it; 'auto': 'support' where the calibration predicts more than "
        "registration.max_calibration_mm of its own error between stations at the object's depths (it warns), "
        "'calibration' otherwise. Measured on the family's draws 80-84 (99 runs): where it warned (20), the model's "
        "mean signed deviation followed the level, correlation -0.96; elsewhere -0.35, levels 0.21 mm RMS, and "
        "taking them off made 6 of 10 held-out runs worse (draw 85)")
    support_curve_stations: bool = Field(False, description="the support curve's 1, Z and Z^2 (which a flat "
                                         "support cannot show) tied to nought at the depth calibration's stations, "
                                         "where it was fitted (tofmetry.calibrate.flat_support_curve): its gain over "
                                         "the object is then the whole range error's, its level there unchanged. Off: "
                                         "on 9 development runs of draws 113-117 (session 59, the family's stations "
                                         "100-250 mm apart) the depth's share of the scale came closer on 7 (|.| mean "
                                         "0.285 -> 0.247 %) but the models' scale no better (5 -> 5 of 8 beyond 0.2 %): "
                                         "the support shows the range error on other pixels than the object's")
    support_curve_columns: float | None = Field(0.05, gt=0, description="the support curve from the support's points "
                                                "in the object's own image columns (their 5-95 % span of normalised x "
                                                "in each view) widened by this on each side: the calibration's "
                                                "residual between stations changes over the image, and a curve from "
                                                "the whole support averages the image's sides into the object's "
                                                "centre. None: the whole support. A curve from the columns that reads "
                                                "beyond support_curve_max_mm gives way to the whole support's (in a "
                                                "strip x hardly varies and the fit can lose its footing: draw 118's "
                                                "pebble, 390 mm, mean |d| 0.88 mm; with the whole support's 0.15 mm). "
                                                "On 12 development runs of draws 113-117 (session 59, bench.robustness."
                                                "depth_scale) 0.05 left the object 0.23 -> 0.14 % of scale on average "
                                                "(the depth alone, at the true poses; better on 9 of 12), the runs' "
                                                "|scale| mean 0.238 -> 0.215 % (7 -> 6 of 11 beyond 0.2 %); held-out "
                                                "draw 118 (11 runs) |scale| p90 0.138 %")
    support_curve_lateral: list[Literal["x2", "y2", "r2"]] = Field(
        default_factory=list, description="image terms the support curve changes by across the image (tofmetry."
        "calibrate.flat_support_curve's lateral: e(Z) + x^2 h(Z) with ['x2']): the calibration's per-pixel "
        "deformation, interpolated between its stations, leaves a residual that differs between the image's centre "
        "(the object) and its sides (where the support is seen at the object's depths). Empty (the default): one "
        "curve for every pixel. Off: on 12 development runs of draws 113-117 (session 60, bench.robustness.depth_scale) "
        "['x2'] left the object 0.231 -> 0.176 % of scale on average (the depth alone, at the true poses), but the "
        "runs' scale no better (|.| mean 0.238 -> 0.248 % over 11): the poses' share, which the depth's had offset, "
        "remained. It held where the object's columns broke (draw 118's pebble: mean |d| 0.15 mm, completeness 0.998); "
        "['x2', 'y2'] broke on 2 of 3 (on a support, Z follows the image row)")
    support_curve_variable: Literal["z", "radial"] = Field(
        "z", description="what the support curve is a function of: the measured depth Z' ('z') or the measured ray "
        "length Z' sqrt(1 + x^2 + y^2) ('radial', the path whose phase a continuous-wave ToF camera measures): a "
        "range error wiggling in the ray length reads, at one depth, differently on the support's rows below the "
        "object than at the object (tofmetry.calibrate.flat_support_curve). 'z' (the default): on noise-free walls "
        "(bench.robustness.wall_transfer) the ray length carried the calibration's residual slope from the rows "
        "below to the image's centre far better on sensors whose error is in the ray length (9 of 11: median 0.13 -> "
        "0.03 % RMS), worse on those in Z; but on 20 development runs (session 62, rows "
        "object_family_dev_radial_ab_*) the models' |scale| mean went only 0.272 -> 0.267 % (18 separable, 13 -> 13 "
        "beyond 0.2 %) and mean |d| median 0.300 -> 0.314 mm (a baluster 0.40 -> 0.58 mm): the transfer is not "
        "what limits the scale")
    support_curve_max_mm: float | None = Field(5.0, gt=0, description="a support curve reading more range error at "
                                               "the object's depths than this [mm] plus support_curve_max_sigmas "
                                               "times the depth calibration's predicted error there is refused (its "
                                               "fit lost its footing, or the support is not flat): one from the "
                                               "object's columns gives way to the whole support's, one from the "
                                               "whole support is not applied and the run warns. None: no bound; "
                                               "none either without a calibration. Over the family's 1856 stored "
                                               "runs the curves' level there reached 3.8 mm (predicted 3.3 mm); "
                                               "draw 118's pebble, read in its columns, -65 mm")
    support_curve_max_sigmas: float = Field(3.0, ge=0, description="see support_curve_max_mm")
    support_curve_step_mm: float = Field(60.0, gt=0, description="the support curve's knot spacing [mm]: it follows "
                                         "range wiggles down to about twice this period")
    support_curve_smooth_mm: float = Field(5.0, gt=0, description="prior 1-sigma of the support curve's second "
                                           "differences [mm] (holds it where few points fall)")
    support_curve_band_mm: float = Field(15.0, gt=0, description="a point is on the support within this of the "
                                         "view's support plane [mm] (wider than the range error to be read)")
    support_curve_clear_px: float = Field(12.0, ge=0, description="support points within this many pixels of the "
                                          "object's are left out of the support curve (its foot, flying pixels "
                                          "and shadow lie at the object's own depths)")
    support_anchor: Literal["none", "gain", "whole"] = Field(
        "none", description="on a dot mat, the planes its dots give each view without the depth (tofmetry.reconstruct."
        "_mat_plane) measure the support curve's gain and curvature too: 'gain' levels that curve on the object's "
        "depths and subtracts it after the poses (the offset stays the calibration's); 'whole' subtracts it unlevelled "
        "before the views are placed, and places them again; 'none': the support alone (its part orthogonal to 1, Z "
        "and Z^2)")
    amplitude_k_mm_per_ln: float = Field(AMPLITUDE_BIAS_MM_PER_LN, description="amplitude bias k ln(A_white / A) [mm]; "
                                         "12 mm for 1/6 of the white amplitude (study §3.3.1) -> 12 / ln 6 = 6.70; used "
                                         "with an amplitude reference")
    amplitude_max_mm: float | None = Field(None, gt=0, description="clip of the amplitude correction [mm]; None: "
                                           "amplitude_max_ln times k (20 mm at the study's k = 6.7). A fixed 20 mm "
                                           "left the dark oblique parts of a painted bar up to ~14 mm long on a sensor "
                                           "with k = 11.4 (measured on boards): model mean |d| 3.6 mm, max 64 mm, "
                                           "completeness 0.81; clipped at 40 mm: 0.29 mm, 2.6 mm, 1.00")
    amplitude_max_ln: float = Field(2.985, gt=0, description="with amplitude_max_mm None, the correction is clipped "
                                    "at this many ln units of A_white / A (1/20 of the white amplitude), times k")
    max_incidence_deg: float = Field(80.0, gt=0, le=90, description="drop grazing points (incidence angle above this) [deg]")
    denoise: bool = Field(True, description="smooth each view's depth by an edge-preserving (bilateral) filter, "
                          "its range sigma from the view's own measured noise (the frames' spread), before "
                          "everything else: registration, the joint fit and fusion work on it (a projective TSDF "
                          "otherwise pulls noisy surfaces into the object: _preprocess.denoise_depth). Measured (docs/history/object-models.md, session 30) on the 20 scans of draw 68 on the mat: model mean "
                          "|d| median 0.33 -> 0.28 mm, p90 0.72 -> 0.47 mm, the same verdicts; through the chain on "
                          "draw 67: 5 -> 2 runs truly wrong, 1 -> 0 missed, 2 -> 5 false alarms")
    denoise_window_px: int = Field(3, ge=3, description="window diameter of that filter [px] (odd; 3: the pixel and its 4 neighbours)")
    denoise_range_sigmas: float = Field(3.0, gt=0, description="its range sigma, in the view's median standard "
                                        "error of a pixel's mean")
    normal_patch_mm: float = Field(12.0, ge=0, description="surface span of the window each normal is fitted over "
                                   "[mm] (3 to 9 px; 0: central differences over 2 px); near the minimum range a ToF "
                                   "camera's noise is as large as its pixel spacing and 2-px differences tilt the "
                                   "normals by ~30 degrees")


class SegmentConfig(BaseModel):
    """Object segmentation: support plane (RANSAC) + what stands on it + near-axis cluster."""

    keep_all: bool = Field(False, description="skip segmentation: keep the whole working range")
    plane_threshold_mm: float = Field(6.0, gt=0, description="RANSAC inlier distance to the support plane [mm]")
    min_height_mm: float = Field(5.0, ge=0, description="object points lie at least this high above the plane [mm]")
    max_height_mm: float = Field(600.0, gt=0, description="...and at most this high [mm] (drops walls/background)")
    cluster_eps_mm: float = Field(12.0, gt=0, description="DBSCAN neighbour distance for the object cluster [mm]")
    merge_gap_mm: float = Field(120.0, ge=0, description="clusters closer than this to the object are part of it [mm]")
    ring_mm: float = Field(60.0, ge=0, description="support-plane ring kept around the object footprint for registration [mm]")
    max_footprint_mm: float = Field(600.0, gt=0, description="object points farther than this (in the plane) from the "
                                    "cluster nearest the optical axis are background [mm]")
    support_band_mm: float = Field(30.0, ge=0, description="pixels lower than this [mm], level (normal within "
                                   "support_tilt_deg of the plane's) and joined smoothly on the image to the plane's "
                                   "inliers are support, not object: a table whose depth bends out of the plane's "
                                   "tolerance (near the end of the calibrated range) otherwise joins the object. 0: off")
    support_tilt_deg: float = Field(20.0, gt=0, le=90, description="... level within this angle [deg]")


class RegistrationConfig(BaseModel):
    """Automatic registration: FPFH + RANSAC coarse, robust point-to-plane ICP fine, pose graph."""

    feature_voxel_mm: float = Field(5.0, gt=0, description="voxel for FPFH features / RANSAC [mm]")
    coarse_voxel_mm: float = Field(8.0, gt=0, description="voxel of the clouds for the quick ICP of coarse hypotheses [mm]")
    refine_candidates: int = Field(3, ge=1, description="distinct coarse hypotheses refined by the full ICP")
    icp_voxel_mm: float = Field(2.5, gt=0, description="voxel of the ICP clouds [mm]")
    icp_radii_mm: tuple[float, ...] = Field((15.0, 6.0, 3.0), description="ICP correspondence radii, coarse to fine [mm]; "
                                            "all stages but the last run on the mid-voxel clouds")
    mid_voxel_mm: float = Field(5.0, gt=0, description="voxel of the clouds of the wide ICP stages and of hypothesis "
                                "ranking [mm] (4x fewer points than the ICP voxel; the last stage fixes the pose)")
    icp_max_iter: int = Field(50, ge=1, description="ICP iterations per wide stage (mid-voxel clouds); measured: 20 "
                              "leaves the pose sliding along the prism-like middle of the object (10 mm errors)")
    fine_max_iter: int = Field(20, ge=1, description="ICP iterations of the last stage (full ICP clouds; starts within ~1 mm: "
                               "20 gives the same poses as 50 on the simulated 8-view scans)")
    yaw_hops_deg: tuple[float, ...] = Field((-8.0, -4.0, 4.0, 8.0), description="after a pair's ICP, the last ICP "
                                            "stage is run again from the pose turned by these angles about the support "
                                            "plane's normal through the object [deg], and the pose whose object points "
                                            "match best is kept (repeated from it, at most yaw_hop_rounds times, never "
                                            "farther than the largest hop from the start; the chosen hypothesis only). The "
                                            "wide ICP stages are biased where the views overlap in part and leave the "
                                            "last one in a local minimum a few degrees off about the vertical (measured "
                                            "on a flat rocker arm: 3.4 deg off, matching 82.5 %; the hop's pose 1.0 deg, "
                                            "84.5 %; ICP from the truth 0.6 deg, 85.4 %). Empty: off")
    yaw_hop_min_gain: float = Field(0.005, ge=0, description="a hop is taken only where it raises the share of "
                                    "object points matched by more than this (its noise, as elsewhere)")
    yaw_hop_rounds: int = Field(3, ge=1, description="at most this many hops in a row")
    yaw_hop_reach_deg: float | None = Field(None, gt=0, description="the hops never take the pose farther than this "
                                            "from where they started [deg]; None: the largest hop. 15 (half the yaw "
                                            "seeds' spacing) was tried on smooth pebbles (2026-11-30): a painted one's "
                                            "pairs 7.4 -> 1.9 and 2.8 -> 0.1 deg, its run 10.0 -> 1.45 deg off, but "
                                            "another's 1.38 -> 3.25 deg (all flagged), and 16 held-out runs unchanged; "
                                            "not the default")
    slab_max_thickness_share: float = Field(0.3, gt=0, le=1, description="an object whose extent along its "
                                            "thinnest principal axis is at most this share of the next, with views "
                                            "of both its faces, is a slab whose thickness its rim alone ties: the run "
                                            "is unreliable (simulated plaques 0.12-0.19 and 1.4-2.9 mm too thin; "
                                            "the next thinnest objects of draws 39-40: domes 0.34-0.44, seen from "
                                            "one side of that axis, flat rocker arms 0.60)")
    icp_seen_only: bool = Field(False, description="each ICP stage of a pair matches only the source points the "
                                "target camera observed at the current pose (facing it within 65 deg, inside its "
                                "image, within icp_seen_tol_mm of its depth there); the others have no partner and "
                                "pull the pose toward what the target saw nearby. Measured (2026-11-30): from the true "
                                "pose, a plaque's edge-on pairs slid +8.2 and +5.6 deg in yaw with every point, -0.9 "
                                "and -0.5 deg with the seen ones; over 13 flagged runs of draws 39-40 no verdict "
                                "changed but a plaque's (flagged since as a slab) and a wrong plaque's 180 -> 1.7 deg "
                                "(the pairs' yaw hops and the global search still pick the biased poses); not the default")
    icp_seen_tol_mm: float = Field(10.0, gt=0, description="a source point counts as observed by the target camera "
                                   "within this distance of the nearest depth it saw around the pixel [mm] (at least "
                                   "the stage's correspondence radius)")
    icp_seen_every: int = Field(10, ge=1, description="the observed points are re-selected every this many ICP "
                                "iterations")
    kernel: str = Field("huber", description="robust kernel: huber | tukey | none (k = radius / 3); measured: Tukey "
                        "with k = 1 mm on ~1 mm noise biases the pose by ~0.1 deg / 2 mm, Huber does not")
    max_incidence_deg: float = Field(70.0, gt=0, le=90, description="registration uses points seen at incidence below this [deg] "
                                     "(§6.3 reliability: grazing points are noisy and biased)")
    fine_max_incidence_deg: float = Field(90.0, gt=0, le=90, description="the fine ICP clouds keep points seen "
                                          "at incidence below this [deg] (stricter reliability weighting)")
    use_ground: bool = Field(True, description="fine ICP on object + a ring of the support plane (ground constrains tilt/height)")
    see_through_tol_mm: float = Field(15.0, gt=0, description="free-space test: a point mapped into the other camera "
                                      "counts as seen through when it lies this far in front of everything that camera "
                                      "observed around the pixel [mm] (several depth-noise sigmas + calibration residual "
                                      "+ coarse ICP error)")
    max_see_through: float = Field(0.20, ge=0, le=1, description="a pairwise hypothesis whose object points are seen "
                                   "through by the other camera for more than this share is rejected; measured on the "
                                   "simulated robustness matrix: correct poses 0.01-0.03 (balustrade, box) and up to 0.10 "
                                   "(rounded lumpy object: limb points at the silhouette; 0.13-0.17 on a vase at 0.7 m "
                                   "until the points the other camera sees beyond 65 degrees of incidence were left out "
                                   "of the test: 0.01-0.04 since), turned-over false matches of "
                                   "nearly symmetric objects 0.25-0.76; a pose slid along a prism-like object reads "
                                   "0.06-0.09 and is NOT caught by this test")
    min_fitness: float = Field(0.35, ge=0, le=1, description="an edge needs this share of object points matched")
    max_rmse_mm: float = Field(3.0, gt=0, description="...and an inlier RMSE below this [mm]")
    all_pairs: bool = Field(False, description="also register every non-successive pair (ICP loop closures seeded by "
                            "the chain) for the pose graph; off by default: the global adjustment matches all overlapping "
                            "views jointly, and loop-closure ICP between views 90 deg apart was measured to slide by "
                            "~15 mm on a prism-like object (2-3x slower, and worse)")
    edge_prune: float = Field(0.25, ge=0, le=1, description="pose-graph line-process edge pruning threshold")
    yaw_step_deg: float = Field(30.0, gt=0, description="support-plane yaw hypotheses step [deg] (coarse search "
                                "when FPFH is ambiguous on a nearly symmetric object)")
    turntable_step_deg: float | None = Field(None, gt=0, lt=360, description="the views were taken on a turntable "
                                             "turning by this step [deg] between successive views (capture order, either "
                                             "sense): the pairwise yaw seeds are the declared turns and a hypothesis off "
                                             "them by more than turntable_tol_deg is not accepted (tofmetry.reconstruct."
                                             "_turntable: a thin slab matches its own back turned over); None: not declared")
    turntable_tol_deg: float = Field(5.0, gt=0, le=90, description="... a pairwise registration may turn this far from "
                                     "the declared turn [deg] (a manual turntable's marks, the object's slip)")
    turntable_accuracy_deg: float = Field(1.0, gt=0, le=90, description="how accurately the declared turntable "
                                          "turns by its step [deg] (a manual turntable's marks ~1, a stepper motor "
                                          "~0.1): where no registration links two successive views, the declared turn "
                                          "does, and their poses are then this accurate; beyond pose_gate_deg the run "
                                          "is flagged unreliable")
    turntable_axis_mm: float = Field(1.0, gt=0, description="how well the turntable's axis is known from the "
                                     "registrations [mm]: with a declared turntable the global adjustment starts from "
                                     "the turntable's poses and holds each view within turntable_accuracy_deg of its "
                                     "turn and this of its object centre's place (the adjustment's pose prior)")
    mat: dict | None = Field(None, description="the printed dot mat the object stands on (tofmetry._shared.dot_mat."
                             "DotMat.to_dict: seed, size_m, dot_radius_m, cover; its yaw is unknown and unused): each "
                             "view is placed on it alone (tofmetry.reconstruct._mat_locate) and the joint fit refines "
                             "the placements; the model comes out in the mat's frame. None: no mat")
    mat_min_dots: int = Field(6, ge=3, description="a view is placed on the mat when at least this many dots it sees "
                              "match the printed layout; the others are left out of the model")
    mat_prior_deg: float = Field(0.5, gt=0, description="the joint fit holds each mat-placed view within about this of "
                                 "its placement [deg] (the placement's tilt comes from the support plane, which the "
                                 "depth calibration's residual tilts by ~0.1-0.2 deg)")
    mat_prior_mm: float = Field(3.0, gt=0, description="... and within about this at the object [mm]")
    mat_pattern_sigma_deg: float = Field(0.2, gt=0, description="1-sigma of the turn of a view the mat's whole pattern "
                                         "placed with too few dots seen whole to refine it [deg] "
                                         "(tofmetry.reconstruct._mat_dense.locate_by_pattern): measured on the "
                                         "family's held-out draws 89-109, 43 such views in 19 runs, RMS 0.186 deg, p90 0.29, "
                                         "at most 0.57 deg")
    mat_pattern_sigma_mm: float = Field(1.5, gt=0, description="... and of its shift along the sheet [mm] (the same "
                                        "views: the object's largest displacement p50 1.5, p90 2.35, at most 3.4 mm)")
    mat_depth_tilt: bool = Field(True, description="on a dot mat with a depth calibration, measure the depth's tilt "
                                 "across the image from the dots' planes, weigh it against what the calibration may "
                                 "have left, and take it off every view (tofmetry.reconstruct._mat_tilt)")
    mat_range_from_dots: bool = Field(False, description="on a dot mat, the mat's own range error read from its dots' "
                                      "size against the printed layout (one value for all views; always measured and "
                                      "reported) is taken out of the placements where beyond 3 of its sigmas, each "
                                      "moved back along its line of sight (tofmetry.reconstruct._mat_range). Off: on "
                                      "the family's held-out draw 109 the eight runs it would correct came out worse "
                                      "placed (1.33 -> 1.71 mm at the object, mean of the eight): every negative "
                                      "value made its placements worse, every positive one better")
    mat_scale_floor_pct: float = Field(0.1, ge=0, description="the dots' own systematic scale error [%] (1 sigma) in "
                                       "the mat's check of the depth scale (_mat_stage.pattern_scale): on exact depth "
                                       "they came out 0.09 +- 0.02 % small over 8 views of a vase")
    mat_plane_at_object: bool = Field(False, description="with a mat, each view's support plane takes its offset "
                                      "from the support at the object's depths before the view is placed "
                                      "(tofmetry.reconstruct._mat_level): the placements then share the object's "
                                      "range error, and the support curve is levelled on the object. Off: on 26 "
                                      "development runs of draws 113-115 (session 58) the models of the 15 whose "
                                      "placements stood unrefined came out less inflated (mean signed deviation "
                                      "+0.17 -> +0.07 mm, mean |d| p90 0.36 -> 0.30 mm) but their scale no better "
                                      "(|scale| p90 0.44 -> 0.46 %) and their poses farther from the truth at the object "
                                      "(up to 2.65 from 0.97 mm): the placements then carry the object's own range error")
    mat_plane_band_mm: float = Field(100.0, gt=0, description="with mat_plane_at_object, the support's points within "
                                     "this of the object's median depth give the plane's offset [mm]")
    mat_holds_scale: bool = Field(True, description="with a mat, the joint fit's change of the model's scale from the "
                                  "placements is weighed against the placements' own scale uncertainty and the rest "
                                  "taken off (tofmetry.reconstruct._mat_scale)")
    mat_range_curve: bool = Field(False, description="with a mat, the joint fit also estimates the range curve "
                                  "(range_curve_degree). Off: measured on 4 development scans (a baluster, a plaque, a "
                                  "vase, a dome), its 5 free coefficients let the views slide off the mat's placements "
                                  "(the baluster 1.2 -> 3.8 mm at the object, 2.7 mm without the curve)")
    max_loop_jump_deg: float = Field(5.0, gt=0, description="a loop-closure ICP may move at most this far from the "
                                      "chained initial pose [deg]")
    max_loop_jump_mm: float = Field(30.0, gt=0, description="... and this far [mm]")
    ir_yaw: bool = Field(True, description="where the overlap of two views leaves the rotation about the vertical free "
                         "(a surface of revolution), choose it by the IR amplitude: the relative albedo of the matched "
                         "points must agree (a painted pattern); see tofmetry.reconstruct._photometric")
    ir_icp: bool = Field(True, description="refine each accepted pairwise registration once more with the IR albedo as a "
                         "photometric term (coloured ICP), kept where the albedo pattern lines up clearly better "
                         "(ir_icp_min_corr, ir_icp_min_gain) and the geometry matches as well: a painted pattern fixes "
                         "the slide the geometry leaves free (measured on a bent bar: edges 1.2-2.8 deg off came to "
                         "0.2-0.5 deg); needs IR frames")
    ir_icp_lambda: float = Field(0.968, gt=0, le=1, description="weight of the geometric term in the photometric ICP "
                                 "(Open3D's default; 1 = geometry only)")
    ir_icp_min_corr: float = Field(0.3, ge=-1, le=1, description="the photometric result is kept only where the matched "
                                   "points' albedos correlate at least this much (a pattern both views see; measured: "
                                   "0.80-0.86 on a painted bar at the true poses, below 0.06 on a plain object)")
    ir_icp_min_gain: float = Field(0.03, ge=0, description="... and where that correlation rose by at least this "
                                   "(measured: +0.06 to +0.33 on edges that had slid, at most +0.03 on correct ones)")
    ir_local_yaw: bool = Field(True, description="where the matched points' IR albedos correlate (a painted pattern), "
                               "sweep the turn about the support normal near each accepted pairwise pose (the shift "
                               "along the support fitted at each yaw) and keep the yaw whose pattern lines up best among "
                               "those that fit as well: a smooth object's geometry leaves several degrees of yaw to its "
                               "pattern (see tofmetry.reconstruct._ir_yaw_local); needs IR frames")
    ir_local_yaw_deg: float = Field(15.0, gt=0, le=90, description="half-width of that sweep about the pose's yaw [deg] "
                                    "(measured: the geometric poses kept on a painted pebble were 3-9 deg off)")
    ir_local_yaw_step_deg: float = Field(1.0, gt=0, description="yaw step of that sweep [deg] (the albedo correlation's "
                                         "peak is about 5 deg wide on a pebble's 30-40 mm paint blobs at 0.7-1 m)")
    ir_local_gate_deg: float = Field(3.0, gt=0, description="the sweep runs only where the yaw turned by this either "
                                     "way (the shift refitted) fits within ir_local_fit_tol of the pose: elsewhere the "
                                     "geometry pins the yaw [deg]")
    ir_local_fit_tol: float = Field(0.02, ge=0, le=1, description="yaws whose fitness lies within this of the best one "
                                    "count as fitting alike (measured on a painted pebble: 0.01-0.02 over 10 deg)")
    ir_local_min_gain: float = Field(0.05, ge=0, le=2, description="the pattern's yaw replaces the geometric one only "
                                     "where its albedo correlation is higher by at least this")
    yaw_free_ratio: float = Field(0.15, gt=0, description="an edge whose yaw stiffness is below this share of its tilt "
                                  "stiffness is yaw free (registration_conditioning: 0.01-0.06 measured on a vase, "
                                  "0.9-2.7 on a bunny and a head)")
    ransac_seeds: int = Field(2, ge=1, description="RANSAC restarts per successive pair (best after ICP kept)")
    gate_max_deg: float = Field(2.0, gt=0, description="consistency gate: a kept pose-graph edge residual or the "
                                "per-edge closure of the view circle above this flags the run unreliable [deg]")
    gate_max_mm: float = Field(10.0, gt=0, description="... or above this [mm]")
    spread_max_deg: float = Field(6.0, gt=0, description="when the loops close within the gate only by dropping an "
                                  "edge, the hypotheses are chosen again with loops closing within this per edge [deg] "
                                  "and the loop error is spread over the edges (a turned-over match is off by tens of "
                                  "degrees; a loop of views with millimetres of depth-calibration residual by a few)")
    spread_max_mm: float = Field(40.0, gt=0, description="... and this [mm] per edge")
    ambiguity_margin: float = Field(0.05, ge=0, description="two choices of the pairwise hypotheses that both close every "
                                    "loop are indistinguishable when their summed fitness (share of object points "
                                    "matched) differs by less than this: the run is flagged 'registration ambiguous'")
    path_max_step_ratio: float | None = Field(3.0, gt=1, description="the cameras of a scan walk around the object in "
                                              "scan order (tofmetry.reconstruct._camera_path): a choice of the pairwise "
                                              "hypotheses whose cameras step back by more than half the median step, or "
                                              "leap by more than this many median steps, yields to a closing choice that "
                                              "walks them; where none does, the run is unreliable. Measured on 12 family "
                                              "runs 25-180 deg off: their paths stepped back 49-163 deg against steps of "
                                              "22-64 deg; true paths 0.6-1.7 x their median step. None: off")
    path_fitness_margin: float = Field(0.3, ge=0, description="... yielding gives up at most this much summed "
                                       "fitness (share of object points matched, summed over the edges)")
    loop_implied_min_gain: float | None = Field(0.02, ge=0, description="when the loops close only by dropping an "
                                                "edge, each pair on the loop it would close is registered again from "
                                                "the pose the rest of the loop implies; that pose becomes a hypothesis "
                                                "of the pair where the pair's own points fit it better by at least this "
                                                "share (the global search had missed it: an igea's 49.5 deg wrong pair "
                                                "matched 68 %, the implied pose 99 %; a smooth pebble's 24.6 deg wrong "
                                                "pair 94.7 %, the implied pose 98.0 %). Four times the fitness noise a "
                                                "yaw hop stands on (0.005); it was 0.05 until 2026-11-30. None: off")
    pattern_search: bool = Field(True, description="where the scan shows a pattern in the IR amplitude (an accepted "
                                 "edge lines it up, pattern_seen_corr), search each edge none of whose hypotheses comes "
                                 "within pattern_search_drop of the best edge's agreement again: the yaw about the "
                                 "support normal swept over the whole turn, scored by the pattern; the pose found "
                                 "becomes the edge's first hypothesis (tofmetry.reconstruct._pattern_search: a painted "
                                 "box turned by its symmetry lined the pattern up at -0.07-0.15, its right edges at "
                                 "0.75-0.86); not with a declared turntable; needs IR frames")
    pattern_seen_corr: float = Field(0.6, ge=-1, le=1, description="an accepted edge whose matched points' albedos "
                                     "correlate this much shows the scan carries a pattern (noise: below 0.1 at 200 "
                                     "matches)")
    pattern_search_drop: float = Field(0.3, ge=0, le=2, description="an edge is searched again where its best "
                                       "hypothesis lines the pattern up worse than the scan's best edge by this (a "
                                       "painted dome's half-turned pairs: 0.36-0.52 against 0.94)")
    pattern_min_corr: float = Field(0.5, ge=-1, le=1, description="the pattern's pose must line it up at least this much")
    pattern_gain: float = Field(0.2, ge=0, le=2, description="... and line it up better than the edge's own best "
                                "hypothesis by this (the selection's IR veto margin): otherwise the geometry's poses "
                                "stand (the sweep holds the tilt to the support planes and finds the yaw to about a "
                                "degree; a right geometric pose is finer)")
    pattern_min_fitness: float = Field(0.15, ge=0, le=1, description="... and match this share of the object points "
                                       "(below min_fitness: two views far apart on a box share one face, 0.15-0.25 of "
                                       "the points, where the pose turned by the symmetry matches all)")
    pattern_search_step_deg: float = Field(5.0, gt=0, le=90, description="yaw step of that search [deg] (the "
                                           "pattern's peak is about 5 deg wide on 30-40 mm blobs at 0.7-1 m)")
    global_adjust: bool = Field(True, description="after the pose graph, refine all poses jointly: every view's points "
                                "against every other view's surface (multi-view point-to-plane, Huber), view 0 fixed")
    adjust_radii_mm: tuple[float, ...] = Field((6.0, 3.0), description="correspondence radii of the global adjustment [mm]")
    adjust_iters: tuple[int, ...] = Field((2, 6), description="at most this many outer iterations (new correspondences) "
                                          "at each radius; stops earlier when converged (measured on the 8-view scans: "
                                          "converged after 2 + 6-7)")
    adjust_extrapolate: float = Field(8.0, ge=0, description="at the last radius, a joint-fit step that points the "
                                      "way the previous one did and is shorter is taken up to 1 + this many times, as "
                                      "far as the two steps' ratio says the fit still creeps (Besl-McKay accelerated "
                                      "ICP; tofmetry.reconstruct._adjust.creep_factor); 0: off. Measured on held-out "
                                      "draw 66 run both ways (bench/robustness/README.md, session 28): the same "
                                      "verdicts; a turntable box's model 1.09 -> 0.81 mm mean |d|, signed -0.92 -> "
                                      "-0.65 mm; the other right runs within 0.03 mm")
    adjust_albedo_weak_ratio: float | None = Field(None, gt=0, description="experimental: the joint fit "
                                                   "matches the IR albedo along the directions of each view's pose where "
                                                   "its information is at least this many times the geometry's, on any "
                                                   "object whose kept registrations line a pattern up; None (the "
                                                   "default): about the vertical only, where the geometry leaves it "
                                                   "free. Measured (bench/robustness/README.md, session 26): with 1 "
                                                   "vases and bars came closer, a fandisk and an igea farther; with 4 "
                                                   "a held-out vase and pebble farther")
    adjust_albedo_min_corr: float | None = Field(0.5, ge=-1, le=1, description="where a kept pairwise registration "
                                                 "leaves the rotation about the vertical free (yaw_free_ratio: a surface "
                                                 "of revolution), the global adjustment also matches the views' IR albedo "
                                                 "about the vertical (tofmetry.reconstruct._adjust_albedo), when the kept "
                                                 "registrations line a pattern up: the median albedo correlation of their "
                                                 "matched points reaches this (0.80-0.96 measured on painted objects, below "
                                                 "0.06 on plain ones). Measured on 4 painted vases of held-out draws: "
                                                 "0.79-1.40 deg off without, 0.46-0.86 with. None: geometry only; needs "
                                                 "IR frames")
    adjust_prior_deg: float | None = Field(None, gt=0, description="prior standard deviation [deg] holding each view "
                                           "near its pose-graph pose in the global adjustment, where the points leave "
                                           "a direction free (the axis of a surface of revolution: noise alone walked "
                                           "a painted vase 1.75 deg from its true poses, while the pose graph, whose "
                                           "yaw the IR pattern decided, was 0.27 deg off); widened to half the worst "
                                           "loop closure of the pose graph. None (default): no prior. Opt-in because "
                                           "the joint fit's move away from the pose graph is also the verdict's "
                                           "detector of a wrong pose graph: with 0.5 deg / 5 mm, two runs of a "
                                           "held-out draw 0.6 and 0.9 deg off were reported reliable (flagged without)")
    adjust_prior_mm: float | None = Field(None, gt=0, description="... and of the object centre's displacement [mm] "
                                          "(both must be set; 5 mm with 0.5 deg above)")
    estimate_depth_gain: bool = Field(False, description="the global adjustment also estimates a depth gain "
                                      "dz = g (z - z_ref) (residual of a depth calibration from few wall stations, zero "
                                      "at the median object depth z_ref; corrected in the fused model too). Off by "
                                      "default: the views hardly determine it and depth noise alone biases it (an "
                                      "igea whose true gain is 0 asked -1.2 % against a stated +-0.05 %; how the "
                                      "regressor is formed decides its sign)")
    depth_gain_prior: float = Field(0.02, gt=0, description="prior standard deviation of the depth gain (keeps it at 0 "
                                    "when the views do not observe it)")
    gain_max_sigma: float = Field(0.002, gt=0, description="the depth gain is estimated only when the views determine "
                                  "it to within this standard error (poses marginalised, no prior, times "
                                  "sigma_inflation); otherwise it stays 0 and the report says why")
    scale_floor_pct: float = Field(0.15, ge=0, description="the modelling chain's own scale uncertainty [%] "
                                   "(registration, fusion, meshing, the evaluation's sampling), added in quadrature "
                                   "to the predicted scale sigma. 0.15 % is its maximum-likelihood value over the 27 "
                                   "reliable runs with a measurable scale of four held-out family draws (13-16, "
                                   "2026-11-25): with 0.05 % (perfect depth at the true poses of a bunny) 67 % of the "
                                   "measured errors lay within 1 sigma and 78 % within 2; with 0.15 %, 78 % and 89 % "
                                   "(the worst: boxes, -0.40 % at 0.10 % predicted, +1.06 % at 0.37 %)")
    gain_systematic_mm: float | None = Field(0.0, ge=0, description="depth error common to whole views [mm] that "
                                             "enters the gain's standard error besides the noise (a gain is then "
                                             "estimated only when it moves the residuals by more than this error); "
                                             "None: the depth calibration's predicted central error (0 without one). "
                                             "Default 0 (noise only): with None, 2 refused-gain false alarms of the "
                                             "family go, but a pebble whose wrong poses only the refused gain "
                                             "revealed is then reported reliable (a miss)")
    gain_max_calibration_sigmas: float = Field(3.0, gt=0, description="an estimated depth gain larger than this many "
                                               "times the gain the depth calibration can leave between its stations "
                                               "(its predicted central error over half the station spacing) is refused "
                                               "and makes the run unreliable (the views disagree with the calibration)")
    range_curve_degree: int = Field(3, ge=0, description="0: off. Otherwise the global adjustment also estimates "
                                    "a range-error curve shared by all views, Legendre terms 2 .. this degree over the "
                                    "scan's depth span (zero at z_ref, no linear part: that is the gain's): the "
                                    "residual wiggling the depth calibration leaves between its stations, which each view "
                                    "sees over a different depth range; estimated only when the views determine it "
                                    "better than its prior. Measured on 6 fresh family draws: the pose error drops "
                                    "or stays on every run whose registration is right (0.34 -> 0.17 deg, 1.13 -> "
                                    "0.28 deg); no verdict changed (docs/history/object-models.md)")
    range_curve_degree_varied: int = Field(5, ge=0, description="the range curve's degree when the views' distances "
                                           "to the object vary by at least range_varied_min (a hand-held loop: they "
                                           "see the same surfaces at different ranges); measured from the true "
                                           "poses on 16 hand-held family scans, degree 5 left 3 beyond the pose gate "
                                           "instead of 7 (on 9 turntables it made 4 worse, so they keep "
                                           "range_curve_degree)")
    range_varied_min: float = Field(0.04, ge=0, description="relative spread (std / median) of the views' distances "
                                    "to the object from which range_curve_degree_varied applies (a turntable: 0; "
                                    "a hand-held loop at +-12 % jitter: about 7 %)")
    range_curve_prior_mm: float | None = Field(None, gt=0, description="prior standard deviation of each range-curve "
                                               "coefficient [mm]; None: the depth calibration's predicted central "
                                               "error between its stations (1 mm without one)")
    amplitude_k_prior_mm: float | None = Field(3.0, gt=0, description="with an amplitude reference, the global "
                                               "adjustment also corrects the amplitude-bias coefficient k of the "
                                               "preprocessing by dk (Z -> Z - dk ln(A_white / A)): one point seen at "
                                               "different incidences by two views disagrees unless k is the sensor's. "
                                               "Prior standard deviation of dk [mm per ln unit]; estimated only when "
                                               "the views determine it better. None: off")
    image_tilt_prior_mm: float | None = Field(None, gt=0, description="opt-in. When the depth calibration did not "
                                              "calibrate a depth error linear in the image position (walls of unknown "
                                              "orientation cannot show it; or no calibration), the global adjustment "
                                              "estimates it, Z -> Z + a x + b y (x = X / Z, y = Y / Z). Such a term rotates "
                                              "every view's points by ~a / Z rad in its own frame, which the views "
                                              "only show through its shear: left in, it puts the poses up to 0.5 deg "
                                              "off (family draws 414861560, 1723591326). Prior standard deviation "
                                              "of a and b [mm per unit of x / z; 10 mm ~ 0.6 deg at 1 m]; estimated only "
                                              "when the views determine both better. Off by default: the noise of the "
                                              "nearest-neighbour pairs biases b (measured -12 mm per unit on a family "
                                              "bunny whose sensor had none, 0.32 -> 0.62 deg). None: off")
    adjust_target_smooth_k: int = Field(12, ge=0, description="the global adjustment matches each view's points "
                                        "to the other views' clouds projected on their local planes (k nearest "
                                        "neighbours; tofmetry.pointcloud.project_to_local_planes): nearest points in "
                                        "two noisy clouds pull the surfaces together (a plaque started at its true "
                                        "poses, noise only: 3.1 -> 1.1 mm at the object). 0: raw targets")
    adjust_target_smooth_deg: float | None = Field(30.0, gt=0, le=90, description="with "
                                                    "adjust_target_smooth_k, only the neighbours whose normal lies "
                                                    "within this angle [deg] of a point's own enter its plane (a point "
                                                    "near an edge is projected on its own face); None: all k. 30 since "
                                                    "session 34: a thin plaque's rim planes spanned both faces and "
                                                    "read +0.24-0.44 % of scale (draws 73-74; "
                                                    "docs/history/object-models.md)")
    adjust_symmetric_normals: bool = Field(True, description="the global adjustment's residual along the sum of "
                                           "both points' normals (symmetric point-to-plane) instead of the target's "
                                           "normal (False). From the true poses, every error term, 12 family scans: "
                                           "beyond the pose gate 8 with it, 5 without; but in the whole chain, on the "
                                           "20 held-out scans of draw 38, the target's normal turned 7 rotations worse "
                                           "by 0.03-0.22 deg and 2 better, and a bar's scale -1.06 % (+0.01 % with it): "
                                           "kept (reconstruct._adjust.global_adjust)")
    support_plane_deg: float | None = Field(0.1, gt=0, description="the global adjustment holds the views' support "
                                            "planes, placed by their poses, to one plane, each within this tilt [deg] "
                                            "and support_plane_mm in height (the depth calibration's residual over the "
                                            "table, a table not flat, a turntable's wobble; reconstruct._adjust_support). "
                                            "At the true poses of 6 family scans the planes lay within 0.02-0.08 deg / "
                                            "0.3-1.1 mm of their mean. From the true poses (bench/robustness/drift.py) "
                                            "it took the tilt a rocker arm's views had drifted from 0.6-0.86 deg to "
                                            "0.03-0.13 deg (worst view 1.37 -> 1.03 deg: the turn about the vertical "
                                            "stays); on family draw 48 one run changed verdict, a pebble 0.55 -> 0.49 deg. "
                                            "None: the object's points alone place the views")
    support_plane_mm: float = Field(0.5, gt=0, description="height allowance of support_plane_deg's term [mm]")
    turn_axis_mm: float | None = Field(0.3, gt=0, description="where the pose graph's poses were taken on a turntable "
                                       "(every view's motion from the first a turn about one vertical axis, within "
                                       "turn_axis_detect_mm), the global adjustment holds them to that axis with this "
                                       "standard deviation [mm] (a turntable's wobble, the object's slip; "
                                       "tofmetry.reconstruct._adjust_circle): a smooth object that matches itself turned "
                                       "about another axis (a bar bent in an arc) no longer slides there. Not with a "
                                       "declared turntable (turntable_step_deg holds the views). Measured on the 32 "
                                       "turntable runs of family draws 50-52: truly wrong 9 -> 7 (1 mm: 8), misses 3 -> "
                                       "1, |scale error| p90 1.02 -> 0.47 %. None: off")
    turn_axis_detect_mm: float = Field(10.0, gt=0, description="... the median over the views of how far their motion "
                                       "from the first moves the fitted axis [mm] (family paths at their true poses: "
                                       "turntables 0, hand-held 23-110; the pose graph's poses of turntables 0.1-3.7)")
    turn_axis_max_sigmas: float = Field(2.0, gt=0, description="a view whose motion still moves the turn axis by more "
                                        "than this many turn_axis_mm at the end of the joint fit makes the run "
                                        "unreliable: its points pull it off the turntable (the object slipped, or the "
                                        "depth errors bend the views)")
    predict_gain_pose: bool = Field(True, description="the poses' predicted spread under the calibration's "
                                    "residual (the adjustment's calibration_pose) includes the depth gain the "
                                    "calibration can leave between its stations (its predicted central error over "
                                    "half the station spacing, as the scale budget takes it): a range error is the "
                                    "same in every view, and its linear part tilts every camera about its own x axis "
                                    "(a 16-view pebble 0.75 deg off from noise and the range residual alone). "
                                    "False: the image-position field only")
    uncalibrated_tilt_mm: float = Field(10.0, ge=0, description="size (1 sigma) of a depth error linear in the "
                                        "image position assumed when the calibration did not calibrate it [mm per unit "
                                        "of x / z]: it enters the poses' predicted spread under the calibration's residual "
                                        "(the adjustment's calibration_pose). Family sensors carry 0-15 mm; the first-order "
                                        "prediction from a sensor's true tilt matched where the joint fit started at the "
                                        "true poses ends (0.505 vs 0.552 deg, 0.450 vs 0.472 deg)")
    amplitude_k_sigma_mm: float = Field(2.0, gt=0, description="uncertainty (1 sigma) of the amplitude-bias "
                                        "coefficient k [mm per ln unit] in the model's predicted scale uncertainty, "
                                        "directly (the scale budget) and through the self-calibrated gain it trades "
                                        "with: 30 % of the study's 6.7, which came from one sensor (unit-to-unit "
                                        "spread unknown); dk's own standard error is not used (it counts noise only, "
                                        "not the other incidence-dependent errors it trades with)")
    amplitude_min_rms_drop: float = Field(0.005, ge=0, description="the amplitude-bias correction dk is kept only "
                                          "when it lowers the global adjustment's final residual RMS by at least this "
                                          "share (other incidence-dependent errors are observed like dk: see "
                                          "keep_amplitude_if_it_explains)")
    sigma_inflation: float = Field(5.0, ge=1, description="factor on the standard errors of the global adjustment "
                                   "(neighbouring points of a view share their depth error: ~25 px patches per "
                                   "independent sample)")
    max_calibration_mm: float = Field(1.5, gt=0, description="a depth calibration that predicts a larger central error "
                                      "between its stations is a warning; the views' own checks judge the poses "
                                      "(as a reason, on 104 family runs, every wrong run it flagged was flagged "
                                      "by another reason too, and it flagged 4 right ones alone) [mm]")
    restart_check: bool = Field(True, description="when the global adjustment moved a view by more than half the pose "
                                "gate, restart it from the pose graph's poses reflected through its solution (moved at "
                                "least the pose gate); a restart that ends more than restart_share of the pose gate away makes the run "
                                "unreliable: the points leave a direction free (reconstruct._adjust_restart)")
    restart_share: float = Field(1.0, gt=0, le=1, description="a restart, or a moved view's pair registered again from "
                                 "the joint fit, that ends more than this share of the pose gate from the joint fit "
                                 "makes the run unreliable. 1: the checks flag what they show to be off by more than "
                                 "the gate. With 0.5 (until 2026-11-29), of the 144 family runs of draws 30-36 the "
                                 "runs whose restart or pair walk ended between half and the whole gate were 3 truly "
                                 "wrong (each flagged by another reason too) and 12 right")
    pose_gate_deg: float = Field(0.5, gt=0, description="pose accuracy the verdict vouches for: rotation [deg]")
    pose_gate_mm: float = Field(3.0, gt=0, description="... and displacement of the object [mm]")
    max_left_out: float = Field(0.25, ge=0, le=1, description="more than this share of the views left out of the "
                                "model (no registration links them) makes the run unreliable; fewer are a warning")
    seed: int = 0


#: the automatic truncation of :meth:`FusionConfig.trunc_for`, as the fusion reports it
TRUNCATION_RULE = "trunc = max(4 * sqrt(sigma_eff(z)^2 + sigma_views^2), 3 voxels)"


class FusionConfig(BaseModel):
    """TSDF fusion (Open3D tensor VoxelBlockGrid) and meshing.

    Defaults follow the sensor: at range z the pixel footprint is z / f (1000 / 365 = 2.7 mm at
    1 m); voxel = 0.6 * footprint (~1.6 mm at 1 m); truncation = max(4 sqrt(sigma_eff(z)^2 +
    sigma_views^2), 3 voxels), with sigma_eff the depth noise after averaging (~1.5 mm at 1 m,
    growing with z) and sigma_views what the views disagree by whatever the range: each view's
    pose and the calibration's residual where it sees a surface (1.5 mm) -> 8.5 mm at 1 m, 7 mm at
    0.6 m.

    Why sigma_views (2026-12-04): Open3D skips a view's observation more than the truncation behind
    its surface and keeps it clipped in front, so two views that disagree by about the truncation
    leave a seam or a hole where they meet. With max(4 sigma_eff, 3 voxels) alone (4 mm at
    0.65 m), ten family runs' fusions, rerun at their final poses, lost surface that the views held:
    a rocker arm at 1.24 m kept 0.84 of the reference (its bore and the flanks under its arms,
    seen by 2-4 views each), 0.89 with 8 mm; at 0.66 m 0.903 -> 0.919; a fandisk 0.969 -> 0.987; a
    pebble at 0.55 m 0.941 -> 0.952 with its mean |d| 0.63 -> 0.48 mm. Beyond 10 mm the thin plaque's
    std grew (0.50 -> 0.61 mm at 10, 0.84 at 14) and the maxima of boxes and plaques with it
    (``tests/reconstruct/test_fusion_seams.py`` has the mechanism on a sphere). Through the chain
    (draw 80, 20 runs) completeness rose on 17 and fell on none; the price is at sharp thin edges:
    the max |d| of fandisks rose by up to 1.6 mm (1048786014 on the mat: 4.8 -> 6.4 mm), and the
    study's balustrade 1.9 -> 4.1 mm while its completeness went 0.789 -> 0.884.

    The truncation's price at rims (2026-12-04, session 43): the band behind a face seen obliquely
    reaches past a convex rim, and no view carves it (only the object's pixels are fused), so the
    zero level sits outside the rim. A 16 mm slab with exact depth and poses: rim +0.45 mm, faces
    +0.02 mm (``tests/reconstruct/test_fusion_rim.py``); the family's plaques at their true poses:
    scale +0.21 / +0.16 % fused against -0.03 / +0.06 % for the views' own points. Carving with
    the views' other pixels made it worse (+0.32 %). ``refine_radius_voxels`` moves each vertex
    onto the median of the fused points about its normal (that slab: rim +0.08 mm, faces 0.00 mm).
    On development draw 87 (20 runs on the mat) it tightened the surfaces (mean |d| better in 15,
    median 0.330 -> 0.298 mm; std 0.387 -> 0.342 mm; p95 0.851 -> 0.820 mm) but moved the scales
    toward what the depth itself reads, which the fattening had partly offset (median |scale|
    0.068 -> 0.099 %, p90 0.152 -> 0.225 %), so it is not on by default. Tried (2026-12-05, session
    45, development draw 89, 20 runs): the move less the mesh's own median offset in the same
    cylinder (its response to its curvature, ``radius^2 / (4 R)`` inward on a convex patch), so that
    only the offset between mesh and points moves it. The surfaces then tightened no more than
    without the option (mean |d| median 0.284 -> 0.287 mm; 0.242 mm with the plain median), the
    scales came out smaller in 17 of 18 (by up to 0.18 %; |scale| p90 0.181 -> 0.219 %), and on the 8
    plaques of draws 88-90 the mean signed scale went +0.135 -> -0.014 % while 4 of 8 stayed beyond
    0.2 %: the rim's fattening is a bias of thin objects, but their scatter is the poses'. Not kept.

    The band cut at the silhouette (2026-12-05, session 46, ``behind_per_edge``; ``_fusion``'s
    docstring): the band behind a pixel's surface reaches no farther than 3 times the pixel's distance
    to its view's silhouette (plus 2 voxels), the chord a ray near a convex edge of 90 deg or blunter
    at least has inside the object. The slab's rim then lies 0.09 mm outside its faces' level instead of
    0.54 mm; the sphere whose views disagree keeps 0.982 of itself at 3 mm (0.984 with the whole band). Without the 2 voxels, or with a 10 mm step alone for
    a silhouette, a rocker arm at 1.29 m lost surface seen only near silhouettes or at grazing
    incidence (completeness 0.90 -> 0.79-0.83); with both, 0.90. Development draw 92 (20 runs): |scale|
    p90 0.329 -> 0.248 %, max worst 4.88 -> 3.43 mm, mean |d| p90 0.357 -> 0.373 mm. Held-out draw 93:
    plaque 236066385 (8 views at 0.70 m) read a max of 20.3 mm, mean |d| 1.01 mm and +3.2 % against
    2.7 mm, 0.40 mm and +0.39 % with Open3D's band, at the same poses: the two models lie within 2.8
    mm of each other everywhere, and the evaluation's alignment took this one turned end for end
    (misfit 1.14 mm; from Open3D's model's alignment it reads 0.43 mm, max 1.74 mm, +0.245 %). Draw
    93's 20 seeds with Open3D's band (the same poses): max |d| worst 10.48 -> 5.48 mm (fandisk
    1543838081), p90 4.59 -> 4.20 mm; |scale| p90 0.257 -> 0.214 %; mean |d| p90 0.363 -> 0.380 mm;
    completeness up to 0.007 lower (rocker arm 829592801 0.901 -> 0.894). The default since.

    The crop to the object's points (2026-12-05, session 47, ``crop_margin_px``): the fused mesh keeps
    the vertices within a margin of the views' segmented object points. A fixed 4 mm cut holes in
    surfaces one view sees obliquely from afar: the points of a surface seen at incidence i lie
    ``z / f / cos i`` apart along its slope, and the mesh between them up to
    ``0.5 sqrt(1 + 1 / cos^2 i)`` footprints from the nearest (1.55 at 70 deg; 5.7 mm at 1.34 m).
    Two rocker arms fused at their true poses (20 planned views, the family's mat): at 1.25 m the
    model kept 0.876 of the reference with 4 mm and 0.897 with 6 mm, at 0.80 m 0.914 either way; at
    1.34 m 0.896 -> 0.902, at 0.75 m 0.914 -> 0.915 (mean |d| +0.01 mm at most). The lost surface
    was the flanks inside the bore that one view sees (2 % of the arm): the views' points were
    there, the crop took the mesh between them. The margin is now 1.6 footprints at the median
    object depth, at least the 4 mm (the points' noise), and beyond 4 mm it keeps only a vertex
    whose neighbouring points lie within 4 mm of its tangent plane, higher above the ground than
    ``segment.min_height_mm`` plus the margin (``_model_build.crop_mask``): through the chain the
    rocker arm at 1.34 m kept a blend of object and fused ground ring 5-6 mm above the ground, 6-8 mm
    off the object (max |d| 4.6 -> 7.8 mm); with the rule 5.1 mm. Held-out draw 94's 20 seeds again
    (development now): completeness worst 0.888 -> 0.896 (that rocker arm); a baluster at 1.30 m
    mean |d| 0.632 -> 0.657 mm, p95 1.54 -> 1.66 mm; the other 18 within 0.006 mm of mean |d|.

    The incidence weights (2026-12-05, session 48, ``incidence_weight_power``): a view's projective
    signed distance near a surface it sees at incidence i is the normal distance over cos i, so an
    unweighted mean gives each view a share of the zero level in proportion to 1 / cos i: the most
    oblique view leads, and its readings are the ones a pixel's footprint (``tan i`` times its width in
    depth), mixed pixels and the amplitude's fall (cos i) spoil most. Weighting each sample by cos i
    gives every view an equal share in the surface's normal direction (``tests/reconstruct/
    test_fusion_weight.py``: the weighted mean of two readings). Held-out draw 95's 20 seeds again
    (development now, the same poses): mean |d| lower on 17, std on 17, p95 on 16 (medians 0.276 ->
    0.264, 0.342 -> 0.314, 0.713 -> 0.657 mm); max |d| p90 5.58 -> 4.52 mm, worst 8.26 -> 6.88 mm (a
    bunny at 0.71 m 8.26 -> 4.41 mm, a fandisk 4.26 -> 3.20 mm); completeness within 0.001. The price is
    the scale: a range error e along the ray moves a view's surface by e cos i along the normal, and
    the oblique views that led before moved it least, so |scale| grew where the range error left one
    (p90 0.169 -> 0.197 %, worst 0.257 -> 0.282 %, 15/15 still within 2 predicted sigmas), and on a 16 mm
    slab the faces' views outweigh the rim's oblique readings near it (rim 0.09 -> 0.21 mm off the
    faces' level, ``tests/reconstruct/test_fusion_rim.py``). The count of views a surface needs to be
    kept is unchanged (the extraction reads a separate count): completeness does not move.

    The bilinear reading (2026-12-05, session 49, ``interpolate_depth``, ``kink_mm``): read at the
    nearest pixel a voxel's depth is off by up to half a pixel's step, and an oblique surface fuses as
    a staircase (a plane at 65 deg and 1.3 m: vertices up to 1.47 mm off it with exact depth; 0.006 mm
    read bilinearly, ``tests/reconstruct/test_fusion_interpolate.py``). Draw 95's seeds again (18 with
    the same path as stored; the same poses): mean |d| lower on 18 (median 0.276 -> 0.232 mm), std on
    18 (0.324 -> 0.263 mm), p95 on 18 (0.663 -> 0.582 mm), max on 11 (median 2.67 -> 2.56 mm, worst
    6.88 -> 6.75 mm); completeness within 0.002. Bilinear wherever the four pixels agree within the
    silhouette's jump instead gave 0.218 mm of mean |d| but a rocker arm's max 1.99 -> 4.73 mm: steps
    below the jump were bridged. The kink rule keeps the nearest pixel there.
    """

    voxel_mm: float | None = Field(None, description="TSDF voxel [mm]; None = 0.6 * z_median / f")
    trunc_mm: float | None = Field(None, description="TSDF truncation [mm]; None = max(4 sqrt(sigma_eff(z)^2 + "
                                   "sigma_views^2), 3 voxels)")
    sigma_eff_1m_mm: float = Field(1.5, gt=0, description="depth noise at 1 m after averaging, growing with z [mm]")
    sigma_views_mm: float = Field(1.5, ge=0, description="what the views' depths disagree by at any range: poses and "
                                  "the calibration's residual between views [mm]")
    block_resolution: int = Field(8, description="voxels per block side")
    behind_per_edge: float | None = Field(3.0, gt=0, description="the band behind a pixel's surface is cut to this "
                                          "many times its distance to the view's silhouette across the ray "
                                          "(tofmetry.reconstruct._fusion's docstring; the rim of a thin object is "
                                          "not fattened); None: Open3D's own integration, the whole band")
    incidence_weight_power: float = Field(1.0, ge=0, le=4, description="each depth sample weighs "
                                          "cos(incidence) ** this in the fusion's mean; at 1 every view has an equal "
                                          "share of a surface along its normal (0: every sample weighs 1, and the "
                                          "most oblique view leads); the count of views a surface needs is "
                                          "unchanged. Only the cut integration takes it: with behind_per_edge None "
                                          "Open3D's own integration weighs every sample 1")
    interpolate_depth: bool = Field(True, description="the cut integration reads each voxel's depth bilinearly "
                                    "between the four pixels around its projection where the depth is smooth "
                                    "(kink_mm), not at the nearest pixel, whose depth is off by up to half a pixel's "
                                    "step on an oblique surface (tofmetry.reconstruct._fusion_reading)")
    kink_mm: float = Field(4.0, gt=0, description="... but only where the depth's second difference along u and v "
                           "stays within this at the four pixels: a step or a crease keeps the nearest pixel's "
                           "reading, where a bilinear one would bridge two surfaces [mm]")
    edge_jump_mm: float = Field(10.0, gt=0, description="a depth step larger than this between neighbouring pixels "
                                "is a silhouette [mm]")
    behind_min_voxels: float = Field(2.0, gt=0, description="the cut band is never shorter than this many voxels "
                                     "(a surface seen only near silhouettes keeps voxels on both sides of its zero level)")
    refine_radius_voxels: float | None = Field(None, gt=0, description="move the fused surface's vertices along "
                                               "their normals onto the median of the fused points within this many "
                                               "voxels of their normal line (tofmetry.pointcloud.move_onto_points; 2 "
                                               "measured); None (default): the TSDF's zero level as it is. Tighter "
                                               "surfaces, a scale that follows the depth's own bias: class docstring")
    refine_band_trunc: float = Field(0.5, gt=0, description="... and within this share of the truncation along it")
    poisson: bool = Field(False, description="also build a Poisson mesh of the fused cloud (density-trimmed)")
    poisson_depth: int = Field(9, description="Poisson octree depth")
    poisson_trim_quantile: float = Field(0.05, ge=0, lt=1, description="drop Poisson vertices of the lowest density quantile")
    crop_margin_mm: float = Field(4.0, ge=0, description="mesh vertices farther than this from the segmented object "
                                  "points are cropped [mm], or than crop_margin_px pixel footprints where that is more")
    crop_margin_px: float = Field(1.6, ge=0, description="the crop's margin in pixel footprints at the median object "
                                  "depth (z / f): between the samples of a surface seen at 70 deg the mesh lies up to "
                                  "0.5 sqrt(1 + 1 / cos^2 70) = 1.55 footprints from the nearest (class docstring)")

    def voxel_for(self, z_mm: float, f_px: float) -> float:
        """Voxel size [mm] at working range ``z_mm`` for focal ``f_px``."""
        return self.voxel_mm if self.voxel_mm is not None else float(min(max(0.6 * z_mm / f_px, 1.0), 8.0))

    def crop_margin_for(self, z_mm: float, f_px: float) -> float:
        """The crop's margin [mm] at working range ``z_mm`` for focal ``f_px``: ``crop_margin_mm`` or
        ``crop_margin_px`` pixel footprints, the larger."""
        return float(max(self.crop_margin_mm, self.crop_margin_px * z_mm / f_px))

    def trunc_for(self, z_mm: float, voxel_mm: float) -> float:
        """Truncation [mm] at working range ``z_mm`` [mm] for a voxel of ``voxel_mm`` (class docstring)."""
        if self.trunc_mm is not None:
            return self.trunc_mm
        return float(max(4.0 * math.hypot(self.sigma_eff_1m_mm * z_mm / 1000.0, self.sigma_views_mm), 3.0 * voxel_mm))


class ReconstructionConfig(BaseModel):
    """All stages of ``tofmetry reconstruct``."""

    world_frame: str = Field("support", description="frame of the outputs: 'support' = support plane z = 0, origin "
                             "under the object, x along the first view's direction; 'camera' = the first camera's frame")
    color: bool = Field(True, description="colour the model from the views' colour frames when they have them "
                        "(occlusion-aware; points no colour camera sees get no colour)")

    preprocess: PreprocessConfig = PreprocessConfig()
    segment: SegmentConfig = SegmentConfig()
    registration: RegistrationConfig = RegistrationConfig()
    fusion: FusionConfig = FusionConfig()


