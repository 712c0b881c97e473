"""Simulate every input of the study on the virtual Kinect v2 (the embedded default).

Writes a DATA_DIR laid out exactly as a user's recordings would be::

    DATA_DIR/warmup/ noise/ materials/ outdoor/ checkerboard/ wall/ wall-validation/ scan/ reference.ply

Each folder carries its own ``truth.json``/``truth.npz``; the study never reads them.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Callable

from tofmetry.study.config import SimulationConfig


def simulate_study_inputs(data_dir: Path, cfg: SimulationConfig,
                          on_step: Callable[[str], None] | None = None) -> Path:
    """Write all simulated inputs into ``data_dir`` (created; must not exist or be empty)."""
    from tofmetry.simulate import datasets

    data_dir = Path(data_dir)
    data_dir.mkdir(parents=True, exist_ok=True)
    step = on_step or (lambda s: None)
    seed = cfg.seed

    step("warm-up series")
    datasets.warmup(data_dir / "warmup", duration_s=cfg.warmup_duration_s, interval_s=cfg.warmup_interval_s, seed=seed + 1)
    step("noise capture")
    datasets.noise(data_dir / "noise", n_frames=cfg.noise_frames, distance_m=cfg.noise_distance_m, seed=seed + 2)
    step("grey-level board")
    datasets.materials(data_dir / "materials", board="grey", n_frames=cfg.material_frames, seed=seed + 3)
    step("material samples board")
    datasets.materials(data_dir / "materials-samples", board="samples", n_frames=cfg.material_frames, seed=seed + 4)
    step("outdoor scene")
    datasets.outdoor(data_dir / "outdoor", n_frames=cfg.outdoor_frames, seed=seed + 5)
    step("checkerboard images")
    datasets.checkerboard_images(data_dir / "checkerboard", n_images=cfg.checkerboard_images, seed=seed + 6)
    step("wall stations")
    datasets.wall_dataset(data_dir / "wall", distances_mm=cfg.wall_distances_mm, n_frames=cfg.wall_frames, seed=seed + 7)
    step("held-out wall stations")
    datasets.wall_dataset(data_dir / "wall-validation", distances_mm=cfg.validation_distances_mm,
                          n_frames=cfg.validation_frames, seed=seed + 8)
    step("8-view object scan")
    datasets.scan(data_dir / "scan", n_views=cfg.scan_views, radius_m=cfg.scan_radius_m, n_frames=cfg.scan_frames,
                  seed=seed + 9)
    ref = data_dir / "scan" / "reference.ply"
    if ref.is_file():
        shutil.copyfile(ref, data_dir / "reference.ply")
    return data_dir
