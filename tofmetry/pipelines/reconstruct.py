"""Pipeline ``reconstruct``: a scan dataset [+ calibration] [+ amplitude reference] -> a 3D model.

Opens the dataset and the calibration, measures the white-wall amplitude reference when asked
(:func:`white_map_from_wall`),
runs :class:`~tofmetry.reconstruct.ReconstructionPipeline` and writes the model folder
(``points.ply``, ``mesh.ply``, ``poses.json``): the one composition that ``tofmetry reconstruct``,
the study and :func:`tofmetry.reconstruct` share. :func:`reconstruct_rig` does the same for one
capture per sensor of a calibrated rig (``rig.json``), fused in the rig frame.
"""

from __future__ import annotations

import os
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Callable

import numpy as np

from tofmetry.calibrate import DepthCalibration
from tofmetry.errors import InputError
from tofmetry.io import ScanDataset, WallDataset
from tofmetry.io.rig_json import read_rig
from tofmetry.pipelines.amplitude_slope import AmplitudeSlope, amplitude_slope_from_boards
from tofmetry.pipelines.calibration_files import load_calibration
from tofmetry.pipelines.plan_check import plan_followed
from tofmetry.reconstruct import (
    ReconstructionConfig, ReconstructionPipeline, ReconstructionResult, RigReconstruction, corrected_mean_depth,
    white_amplitude_map, write_reconstruction,
)
from tofmetry.sensor import CameraIntrinsics

#: progress(description, total) -> context manager yielding advance(n=1)
Progress = Callable[[str, int | None], AbstractContextManager]


def white_map_from_wall(wall_dir, calibration: DepthCalibration | None = None,
                        intrinsics: CameraIntrinsics | None = None, max_mm: float = 2500.0,
                        advance=None, max_frames: int = 10) -> np.ndarray:
    """White-frontal amplitude per pixel from a wall dataset (the amplitude reference of the scan).

    Per station: mean IR and robust mean depth of the first ``max_frames`` frames, calibrated with
    ``calibration`` when given, then :func:`tofmetry.reconstruct.white_amplitude_map`.

    Parameters
    ----------
    wall_dir : path of a wall dataset (stations.csv + captures with IR; white, frontal wall)
    calibration : DepthCalibration or None; its intrinsics are used when present
    intrinsics : CameraIntrinsics used without calibration (None: the first station's own)
    max_mm : stations farther than this [mm] are not used (the nearest one is kept if none remains)
    advance : optional callable, called once per station processed (progress)

    Returns
    -------
    (H, W) float64 white amplitude at 1 m [amplitude * m^2], NaN where unknown.

    Raises
    ------
    InputError when a station has no IR frames or its size differs from the intrinsics.
    """
    wall = WallDataset(wall_dir)
    stations = [st for st in wall.stations if st.distance_mm <= max_mm] or wall.stations[:1]
    intr = calibration.intrinsics if calibration is not None else intrinsics
    irs, depths = [], []
    for st in stations:
        cap = st.open()
        if intr is None:
            intr = cap.intrinsics()[0]
        if not cap.has_ir:
            raise InputError(f"amplitude reference {wall_dir}: station {st.path} has no IR frames (IR is needed)")
        if cap.shape != intr.shape:
            raise InputError(f"amplitude reference {wall_dir}: station {st.path} is {cap.shape}, "
                             f"expected {intr.shape} (the scan's depth size)")
        d = corrected_mean_depth(cap.depth_stack(range(min(max_frames, len(cap)))), calibration, 3.0, 1)
        irs.append(cap.ir_mean())
        depths.append(d)
        if advance is not None:
            advance()
    return white_amplitude_map(irs, depths, intr)


def amplitude_reference(wall_dir: str | os.PathLike, calibration: DepthCalibration | None, scan: ScanDataset,
                        max_mm: float = 2500.0, progress: Progress | None = None) -> np.ndarray:
    """White-frontal amplitude per pixel from a wall dataset, for the scan's amplitude correction.

    Parameters
    ----------
    wall_dir : wall dataset with IR (white, frontal wall; e.g. the depth calibration's)
    calibration : applied to the stations' depth (its intrinsics are used), or None
    scan : the scan (its first view's intrinsics are used without calibration)
    max_mm : stations up to this distance [mm] are used
    progress : optional progress factory (one step per station)

    Returns
    -------
    (H, W) float64 white amplitude at 1 m [amplitude * m^2], NaN where unknown
    """
    intr = None if calibration is not None else scan[0].intrinsics()[0]
    n_st = sum(st.distance_mm <= max_mm for st in WallDataset(wall_dir).stations) or 1
    if progress is None:
        return white_map_from_wall(wall_dir, calibration, intr, max_mm)
    with progress("amplitude reference (wall)", n_st) as adv:
        return white_map_from_wall(wall_dir, calibration, intr, max_mm, advance=adv)


def with_measured_amplitude_slope(config: ReconstructionConfig, slope: AmplitudeSlope) -> ReconstructionConfig:
    """A copy of ``config`` using a measured amplitude-bias coefficient: ``k`` in the preprocessing,
    its uncertainty in the scale budget and as the prior of the scan's own correction ``dk`` (a
    scan rarely determines ``k`` as well as boards do)."""
    cfg = config.model_copy(deep=True)
    cfg.preprocess.amplitude_k_mm_per_ln = slope.k_mm_per_ln
    cfg.registration.amplitude_k_sigma_mm = slope.sigma_mm_per_ln
    if cfg.registration.amplitude_k_prior_mm is not None:
        cfg.registration.amplitude_k_prior_mm = slope.sigma_mm_per_ln
    return cfg


def reconstruct_scan(scan_dir: str | os.PathLike, calibration: str | os.PathLike | DepthCalibration | None = None,
                     output: str | os.PathLike | None = None, *, config: ReconstructionConfig | None = None,
                     amplitude_wall: str | os.PathLike | None = None, amplitude_max_mm: float = 2500.0,
                     white_map: np.ndarray | None = None, amplitude_boards: list | None = None,
                     force: bool = False, progress: Progress | None = None,
                     plan: dict | None = None) -> ReconstructionResult:
    """Reconstruct the object of a scan dataset and optionally write the model folder.

    Parameters
    ----------
    scan_dir : scan dataset (``views/<name>/`` captures, processed in name order)
    calibration : calibration file or DepthCalibration, or None (raw depth)
    output : model folder to write atomically (``points.ply``, ``mesh.ply``, ``poses.json``), or None
    config : ReconstructionConfig (default settings when None)
    amplitude_wall : wall dataset giving the white amplitude per pixel (enables the amplitude-bias
        correction, needs IR); ``amplitude_max_mm`` limits its stations [mm]
    white_map : an amplitude reference already measured (instead of ``amplitude_wall``)
    amplitude_boards : grey-level board captures measuring the sensor's amplitude-bias coefficient
        ``k`` and its uncertainty (:func:`~tofmetry.pipelines.amplitude_slope.amplitude_slope_from_boards`,
        corrected with ``calibration``); they replace the configured ``k``, its uncertainty in the
        scale budget and the prior of the scan's own ``dk``. Needs an amplitude reference.
    force : replace an existing output folder
    progress : optional ``progress(description, total)`` context-manager factory
    plan : the content of a ``plan.json`` (:func:`~tofmetry.pipelines.plan.read_plan`): the views as
        registered are set beside the views it asked for (:func:`~tofmetry.pipelines.plan_check.plan_followed`,
        ``diagnostics["plan"]``, written to ``poses.json``); needs the model in its ground frame

    Returns
    -------
    ReconstructionResult (``diagnostics["reliable"]`` says whether the poses can be trusted)
    """
    ds = ScanDataset(scan_dir)
    cal = calibration
    if cal is not None and not isinstance(cal, DepthCalibration):
        cal = load_calibration(cal)
    if white_map is None and amplitude_wall is not None:
        white_map = amplitude_reference(amplitude_wall, cal, ds, amplitude_max_mm, progress)
    cfg = config or ReconstructionConfig()
    slope = None
    if amplitude_boards:
        if white_map is None:
            raise InputError("amplitude boards: the amplitude-bias correction also needs the white amplitude per "
                             "pixel (an amplitude reference: --amplitude-reference WALL)")
        with progress("amplitude coefficient (boards)", len(amplitude_boards)) if progress else nullcontext() as adv:
            slope = amplitude_slope_from_boards(amplitude_boards, cal, adv)
        cfg = with_measured_amplitude_slope(cfg, slope)
    res = ReconstructionPipeline(ds, cal, cfg, progress=progress, white_map=white_map).run()
    if slope is not None:
        res.diagnostics["amplitude_slope"] = slope.to_dict()
    if plan is not None:
        res.diagnostics["plan"] = _plan_followed(res, plan)
    if output is not None:
        write_reconstruction(Path(output), res, force=force)
    return res


def _plan_followed(res: ReconstructionResult, plan: dict) -> dict:
    """:func:`~tofmetry.pipelines.plan_check.plan_followed` of a reconstruction, or why it was not made."""
    if res.support_plane is None:
        return {"skipped": "no support plane was found, so the model is not in a ground frame to set the plan's "
                           "views in (the plan stands its object on its support)"}
    lo, hi = (res.diagnostics.get("working_range_mm") or [500.0, 2500.0])[:2]
    intr = CameraIntrinsics.from_dict(res.diagnostics["intrinsics"])
    return plan_followed(plan, res.mesh_vertices if len(res.mesh_vertices) else res.points, res.poses, intr,
                         min_mm=lo, max_mm=hi)


def reconstruct_rig(scan_dir: str | os.PathLike, rig: str | os.PathLike | list, output: str | os.PathLike | None = None,
                    *, calibrations: dict | None = None, config: ReconstructionConfig | None = None,
                    force: bool = False, progress: Progress | None = None) -> ReconstructionResult:
    """Fuse one capture per sensor of a calibrated rig into a model in the rig frame.

    Parameters
    ----------
    scan_dir : scan dataset with one view per sensor, named after it (``views/<sensor>/``)
    rig : ``rig.json`` (``tofmetry calibrate rig``) or its sensors (:func:`tofmetry.io.rig_json.read_rig`)
    output : model folder to write atomically (``points.ply``, ``mesh.ply``, ``poses.json``), or None
    calibrations : sensor name -> depth calibration file or DepthCalibration (others: raw depth)
    config : ReconstructionConfig (default settings when None)
    force : replace an existing output folder
    progress : optional ``progress(description, total)`` context-manager factory

    Returns
    -------
    ReconstructionResult in the rig frame (``diagnostics["rig"]``: the sensors' uncertainties;
    ``edges``: the overlap residuals that check the rig against the data)
    """
    sensors = read_rig(rig) if isinstance(rig, (str, os.PathLike)) else list(rig)
    cals = {n: c if isinstance(c, DepthCalibration) else load_calibration(c) for n, c in (calibrations or {}).items()}
    res = RigReconstruction(ScanDataset(scan_dir), sensors, cals, config or ReconstructionConfig(), progress=progress).run()
    if output is not None:
        write_reconstruction(Path(output), res, force=force)
    return res
