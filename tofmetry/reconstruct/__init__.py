"""3D modelling of small objects from several ToF views (study §5), fully automatic.

Stages (one module each): :mod:`._preprocess` (robust mean, calibration, flying pixels,
range, normals) -> :mod:`._segment` (support plane + object) -> :mod:`._register` (plane-yaw
or FPFH coarse, free-space test, robust point-to-plane ICP; alternatives kept) -> :mod:`._posegraph`
(multi-view hypothesis selection over the loops, LM global optimisation, loop gate) -> :mod:`._adjust` (joint multi-view ICP of all views + depth-gain self-calibration, optional range-error curve :mod:`._range_curve`) -> :mod:`._fusion` (TSDF VoxelBlockGrid on undistorted depth, mesh, Poisson) -> :mod:`._colour` (occlusion-aware colour from the views' colour frames).
:class:`ReconstructionPipeline` runs them; :func:`write_reconstruction` writes the outputs.
:class:`RigReconstruction` (:mod:`._rig`) fuses one capture per sensor of a calibrated rig in the rig frame.
"""

from tofmetry.reconstruct._adjust import AdjustView, apply_depth_gain, global_adjust
from tofmetry.reconstruct._adjust_result import AdjustResult, keep_amplitude_if_it_explains
from tofmetry.reconstruct._amplitude import (
    PAPER_K_MM_PER_LN,
    amplitude_bias_mm,
    white_amplitude_map,
)
from tofmetry.reconstruct._calibration_support import extrapolated_points, extrapolation_error_mm
from tofmetry.reconstruct._colour import (
    ModelColours,
    colour_model,
    combine_view_colours,
    incidence_cosine,
    model_colours_in_view,
    weighted_median,
)
from tofmetry.reconstruct._config import (
    FusionConfig,
    PreprocessConfig,
    ReconstructionConfig,
    RegistrationConfig,
    SegmentConfig,
)
from tofmetry.reconstruct._fusion import (
    TSDFFusion,
    crop_mesh,
    poisson_mesh,
    undistort_depth,
    undistort_maps,
)
from tofmetry.reconstruct._loops import loop_closures, select_hypotheses
from tofmetry.reconstruct._o3d import (
    Match,
    estimate_normals,
    global_register,
    icp,
    voxel_down,
)
from tofmetry.reconstruct._output import poses_document, write_reconstruction
from tofmetry.reconstruct._pipeline import ReconstructionPipeline, ReconstructionResult
from tofmetry.reconstruct._posegraph import (
    PoseGraphBuilder,
    PoseGraphResult,
    consistency_gate,
    relative_pose_errors,
    rotation_angle_deg,
)
from tofmetry.reconstruct._preprocess import (
    ViewData,
    corrected_mean_depth,
    image_normals,
    prepare_view,
)
from tofmetry.reconstruct._range_curve import apply_range_curve, range_curve_m
from tofmetry.reconstruct._register import PairResult, plane_consistent, register_pair
from tofmetry.reconstruct._regview import (
    RegView,
    constrained_stiffness,
    free_space_violation,
    make_reg_view,
    point_to_plane_rows,
    registration_conditioning,
    visibility_violation,
)
from tofmetry.reconstruct._rig import RigReconstruction, overlap_residuals, rig_correction
from tofmetry.reconstruct._segment import (
    Segmentation,
    fit_support_plane,
    segment_object,
)
from tofmetry.reconstruct._view_graph import connected_components, spanning_tree
from tofmetry.reconstruct._world import support_plane_frame, transform_plane

__all__ = [
    "PAPER_K_MM_PER_LN",
    "point_to_plane_rows",
    "constrained_stiffness",
    "AdjustResult",
    "keep_amplitude_if_it_explains",
    "AdjustView",
    "FusionConfig",
    "Match",
    "ModelColours",
    "PairResult",
    "PoseGraphBuilder",
    "PoseGraphResult",
    "PreprocessConfig",
    "ReconstructionConfig",
    "ReconstructionPipeline",
    "ReconstructionResult",
    "RegView",
    "RegistrationConfig",
    "RigReconstruction",
    "SegmentConfig",
    "Segmentation",
    "TSDFFusion",
    "ViewData",
    "amplitude_bias_mm",
    "apply_depth_gain",
    "apply_range_curve",
    "colour_model",
    "combine_view_colours",
    "connected_components",
    "consistency_gate",
    "corrected_mean_depth",
    "crop_mesh",
    "estimate_normals",
    "extrapolated_points",
    "extrapolation_error_mm",
    "fit_support_plane",
    "free_space_violation",
    "global_adjust",
    "global_register",
    "icp",
    "image_normals",
    "incidence_cosine",
    "loop_closures",
    "make_reg_view",
    "model_colours_in_view",
    "overlap_residuals",
    "plane_consistent",
    "poisson_mesh",
    "poses_document",
    "prepare_view",
    "range_curve_m",
    "register_pair",
    "rig_correction",
    "registration_conditioning",
    "relative_pose_errors",
    "rotation_angle_deg",
    "segment_object",
    "support_plane_frame",
    "transform_plane",
    "select_hypotheses",
    "spanning_tree",
    "undistort_depth",
    "undistort_maps",
    "visibility_violation",
    "voxel_down",
    "weighted_median",
    "white_amplitude_map",
    "write_reconstruction",
]
