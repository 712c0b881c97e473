"""Point clouds from depth maps: back-projection, colouring, temporal statistics."""

from tofmetry.pointcloud._colour import ColourSample, colour_points, colour_zbuffer
from tofmetry.pointcloud._project import (
    amplitude_colors,
    depth_to_points,
    depth_to_xyz_image,
    sample_colors,
)
from tofmetry.pointcloud._smooth import move_onto_points, project_to_local_planes
from tofmetry.pointcloud._temporal import RunningDepthStats, TemporalStats, robust_mean_depth, temporal_stats

__all__ = [
    "ColourSample", "colour_points", "colour_zbuffer", "amplitude_colors", "depth_to_points", "depth_to_xyz_image", "sample_colors",
    "move_onto_points", "project_to_local_planes", "RunningDepthStats", "TemporalStats", "robust_mean_depth", "temporal_stats",
]
