"""Pipeline of the sensor assessments (study §3): an assessment result -> its files.

JSON, PNG figures and, for the strong-light assessment, the flying-pixel cloud: the one place
where the CLI (``tofmetry assess ...``) and the study write them. The cloud of the kept frame
comes from the frame path (:class:`~tofmetry.pipelines.frame_path.FramePath`, no calibration).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tofmetry.assess import OutdoorResult, flying_cloud, save_figures
from tofmetry.errors import InputError
from tofmetry.io import atomic_write_json, write_ply
from tofmetry.pipelines.frame_path import FramePath
from tofmetry.sensor import CameraIntrinsics


def outdoor_cloud(result: OutdoorResult, intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kept frame of a strong-light assessment as a display cloud.

    Parameters
    ----------
    result : OutdoorResult
    intrinsics : of the depth camera

    Returns
    -------
    points : (N, 3) [m]; colors : (N, 3) uint8 (flying pixels red); is_flying : (N,) bool
    """
    path = FramePath(intrinsics)
    depth = result.depth
    if depth.dtype == np.uint16:
        pts, idx = path.points(depth), path.index(depth)
    else:  # frames given as float arrays
        pts, idx = path.backproject(depth)
    return flying_cloud(result, pts, idx)


def write_assessment(result, out_dir: str | os.PathLike, json_name: str, *,
                     intrinsics: CameraIntrinsics | None = None, cloud_ply: str | None = None) -> dict[str, Path]:
    """Write an assessment result: ``json_name`` (its ``to_dict()``), its PNG figures and, for an
    :class:`~tofmetry.assess.OutdoorResult`, optionally its cloud as PLY.

    Parameters
    ----------
    result : WarmupResult, NoiseResult, MaterialsResult or OutdoorResult
    out_dir : folder (created if needed)
    json_name : file name of the JSON (e.g. ``"warmup.json"``)
    intrinsics : depth-camera intrinsics; needed for an OutdoorResult (its cloud)
    cloud_ply : file name of the outdoor cloud PLY (flying pixels red, scalar ``flying``), or None

    Returns
    -------
    dict name -> path: ``"json"``, ``"figures"`` (list), ``"cloud"`` when written
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: dict = {"json": atomic_write_json(out / json_name, result.to_dict())}
    kwargs = {}
    if isinstance(result, OutdoorResult):
        if intrinsics is None:
            raise InputError("write_assessment: intrinsics are needed for an OutdoorResult (its cloud is drawn)")
        cloud = outdoor_cloud(result, intrinsics)
        kwargs["cloud"] = cloud
        if cloud_ply is not None:
            pts, cols, fly = cloud
            paths["cloud"] = write_ply(out / cloud_ply, pts, colors=cols, scalars={"flying": fly.astype(np.float32)})
    paths["figures"] = save_figures(result, out, **kwargs)
    return paths
