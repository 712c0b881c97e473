"""Accuracy assessment of a 3D model against a reference (study section 5.3).

:func:`evaluate_model` aligns (optional coarse FPFH/RANSAC, then robust ICP), measures signed
cloud-to-mesh / mesh-to-mesh (sampled) / cloud-to-cloud deviations, statistics, completeness
and F-score; :func:`write_evaluation` writes metrics.json and the figures.
"""

from tofmetry.evaluate._align import (
    AlignmentResult,
    align_to_reference,
    apply_transform,
)
from tofmetry.evaluate._distance import (
    ClosestPoints,
    distances_to_cloud,
    distances_to_mesh,
    face_normals,
    sample_mesh,
    sharp_edge_samples,
)
from tofmetry.evaluate._evaluate import (
    EvaluationConfig,
    EvaluationResult,
    evaluate_model,
)
from tofmetry.evaluate._figures import deviation_colors, histogram_figure, render_figure
from tofmetry.evaluate._output import write_evaluation
from tofmetry.evaluate._poses import PoseErrors, model_scale, pose_errors, scale_from_reference
from tofmetry.evaluate._stats import (
    DeviationStats,
    check_units,
    completeness_fscore,
    deviation_stats,
)
from tofmetry.evaluate._visibility import CameraViews, observed_mask, view_cosines

__all__ = [
    "AlignmentResult",
    "CameraViews",
    "ClosestPoints",
    "DeviationStats",
    "PoseErrors",
    "EvaluationConfig",
    "EvaluationResult",
    "align_to_reference",
    "apply_transform",
    "check_units",
    "completeness_fscore",
    "deviation_colors",
    "deviation_stats",
    "distances_to_cloud",
    "distances_to_mesh",
    "evaluate_model",
    "face_normals",
    "histogram_figure",
    "observed_mask",
    "pose_errors",
    "render_figure",
    "sample_mesh",
    "scale_from_reference",
    "model_scale",
    "sharp_edge_samples",
    "view_cosines",
    "write_evaluation",
]
