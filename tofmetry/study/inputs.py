"""Simulate every input of the study on the virtual Kinect v2 (the embedded default).

Writes a DATA_DIR laid out exactly as a user's recordings would be::

    DATA_DIR/warmup/ noise/ materials/ materials-samples/ outdoor/ checkerboard/ tilt-boards/ wall/
    DATA_DIR/wall-validation/ scan/ reference.ply

Each folder carries its own ``truth.json``/``truth.npz``; the study never reads them. The datasets
are independent, so they are written by a small process pool (one worker per core, at most 2 by
default): rendering and PNG encoding are CPU-bound.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import shutil
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Callable

from tofmetry.simulate import board_datasets, datasets
from tofmetry.study.config import SimulationConfig


def _tasks(data_dir: Path, cfg: SimulationConfig) -> list[tuple[str, str, dict, float]]:
    """(label, dataset function, kwargs, relative cost) for every simulated input."""
    s = cfg.seed
    tilt = [("checkerboard captures with depth", "board_dataset",
             dict(out=data_dir / "tilt-boards", n_poses=cfg.tilt_board_poses, board="checkerboard", seed=s + 10),
             cfg.tilt_board_poses * 4)] if cfg.tilt_board_poses else []
    return tilt + [
        ("wall stations", "wall_dataset", dict(out=data_dir / "wall", distances_mm=cfg.wall_distances_mm,
                                               n_frames=cfg.wall_frames, seed=s + 7), len(cfg.wall_distances_mm) * cfg.wall_frames),
        ("warm-up series", "warmup", dict(out=data_dir / "warmup", duration_s=cfg.warmup_duration_s,
                                          interval_s=cfg.warmup_interval_s, seed=s + 1),
         cfg.warmup_duration_s / cfg.warmup_interval_s),
        ("8-view object scan", "scan", dict(out=data_dir / "scan", n_views=cfg.scan_views, radius_m=cfg.scan_radius_m,
                                            n_frames=cfg.scan_frames, seed=s + 9), cfg.scan_views * (cfg.scan_frames + 8)),
        ("checkerboard images", "checkerboard_images", dict(out=data_dir / "checkerboard",
                                                            n_images=cfg.checkerboard_images, seed=s + 6),
         cfg.checkerboard_images * 8),
        ("held-out wall stations", "wall_dataset", dict(out=data_dir / "wall-validation",
                                                        distances_mm=cfg.validation_distances_mm,
                                                        n_frames=cfg.validation_frames, seed=s + 8),
         len(cfg.validation_distances_mm) * cfg.validation_frames),
        ("noise capture", "noise", dict(out=data_dir / "noise", n_frames=cfg.noise_frames,
                                        distance_m=cfg.noise_distance_m, seed=s + 2), cfg.noise_frames),
        ("grey-level board", "materials", dict(out=data_dir / "materials", board="grey", n_frames=cfg.material_frames,
                                               seed=s + 3), cfg.material_frames + 5),
        ("material samples board", "materials", dict(out=data_dir / "materials-samples", board="samples",
                                                     n_frames=cfg.material_frames, seed=s + 4), cfg.material_frames + 5),
        ("outdoor scene", "outdoor", dict(out=data_dir / "outdoor", n_frames=cfg.outdoor_frames, seed=s + 5),
         cfg.outdoor_frames + 5),
    ]


def _run_task(func: str, kwargs: dict) -> str:
    getattr(board_datasets if func == "board_dataset" else datasets, func)(**kwargs)
    return func


def simulate_study_inputs(data_dir: Path, cfg: SimulationConfig, on_step: Callable[[str], None] | None = None,
                          workers: int | None = None) -> Path:
    """Write all simulated inputs into ``data_dir``; returns it.

    Parameters
    ----------
    workers : processes to use (default: ``min(2, os.cpu_count())``; 1 runs in this process).
    """
    data_dir = Path(data_dir)
    data_dir.mkdir(parents=True, exist_ok=True)
    step = on_step or (lambda s: None)
    tasks = sorted(_tasks(data_dir, cfg), key=lambda t: -t[3])
    workers = workers or min(2, os.cpu_count() or 1)
    if workers <= 1:
        for label, func, kw, _ in tasks:
            step(label)
            _run_task(func, kw)
    else:
        # 'spawn' keeps workers independent of this process's threads (numba/OpenMP, rich)
        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
            futs = {pool.submit(_run_task, func, kw): label for label, func, kw, _ in tasks}
            for fut in as_completed(futs):
                fut.result()  # re-raise a worker's error here
                step(futs[fut])
    ref = data_dir / "scan" / "reference.ply"
    if ref.is_file():
        shutil.copyfile(ref, data_dir / "reference.ply")
    return data_dir
