"""Rendered scans shared by the dot-mat tests."""

from __future__ import annotations

from pathlib import Path

from tofmetry._shared.dot_mat import DotMat


def perfect_mat_scan(root: Path, elevation_deg: float) -> tuple[Path, DotMat]:
    """Three views of the balustrade standing on a dot mat (seed 5, turned 30 deg), rendered with
    perfect depth at 0.9 m and ``elevation_deg``: (scan folder, the mat as it lies)."""
    from tofmetry.simulate import datasets
    from tofmetry.simulate.errors import ErrorModel
    from tofmetry.simulate.meshes import balustrade_mesh

    mat = DotMat(seed=5, yaw_deg=30.0)
    out = datasets.scan(root / "scan", n_views=3, n_frames=2, radius_m=0.9, elevation_deg=elevation_deg,
                        errors=ErrorModel.none(), mesh=balustrade_mesh(), mat=mat, seed=3)
    return out, mat
