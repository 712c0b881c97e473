"""Pipeline ``evaluate``: a model file + a reference file -> accuracy figures and files.

Reads both geometries (PLY/OBJ/STL, metres), the optional initial transform and the
reconstruction's ``poses.json``, runs :func:`~tofmetry.evaluate.evaluate_model` and writes
``metrics.json``, the figures and ``deviation.ply``: the composition that ``tofmetry evaluate``,
the study and :func:`tofmetry.evaluate` share.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.errors import InputError
from tofmetry.evaluate import CameraViews, EvaluationConfig, EvaluationResult, evaluate_model, write_evaluation
from tofmetry.io import read_json
from tofmetry.io.mesh import read_geometry
from tofmetry.pipelines.paths import refuse_existing


def read_transform(path: str | os.PathLike) -> np.ndarray:
    """A 4x4 model -> reference transform from JSON: ``{"transform": 4x4}`` or a bare 4x4 list.

    Raises
    ------
    InputError naming the file: a poses.json (it holds no such transform), or not a 4x4 matrix.
    """
    d = read_json(path, "initial transform")
    if isinstance(d, dict) and "views" in d:  # a poses.json: no transform inside, only the model frame
        raise InputError(f"{path}: a poses.json does not hold a model->reference transform; pass a JSON "
                         "{'transform': 4x4} or a bare 4x4 list")
    T = np.asarray(d["transform"] if isinstance(d, dict) else d, dtype=float)
    if T.shape != (4, 4):
        raise InputError(f"{path}: expected a 4x4 matrix, found shape {T.shape}")
    return T


@dataclass
class EvaluationRun:
    """Result of :func:`evaluate_files`: the evaluation and the files written (name -> path:
    ``metrics``, ``histogram``, ``deviation_ply``, ``render``; empty without an output folder)."""

    result: EvaluationResult
    files: dict[str, Path] = field(default_factory=dict)


def evaluate_files(model: str | os.PathLike, reference: str | os.PathLike, output: str | os.PathLike | None = None,
                   *, config: EvaluationConfig | None = None, init_transform: str | os.PathLike | None = None,
                   poses: str | os.PathLike | None = None, title: str | None = None,
                   force: bool = False) -> EvaluationRun:
    """Accuracy of a model against a reference, optionally written into a folder.

    Parameters
    ----------
    model, reference : PLY/OBJ/STL cloud or mesh [m]
    output : folder for ``metrics.json``, ``histogram.png``, ``deviation.ply``, ``deviation_render.png``
    config : EvaluationConfig (default settings when None)
    init_transform : JSON file with an initial model -> reference transform (:func:`read_transform`)
    poses : the reconstruction's ``poses.json``: also report completeness over the reference
        surface the registered cameras could see
    title : figure title (default: the model's file name)
    force : replace an existing, non-empty ``output`` (refused otherwise, before any work)

    Returns
    -------
    EvaluationRun
    """
    if output is not None:
        refuse_existing(output, force)
    m = read_geometry(model, "model")
    r = read_geometry(reference, "reference")
    init = read_transform(init_transform) if init_transform is not None else None
    cams = None if poses is None else CameraViews.from_document(read_json(poses, "poses"), str(poses))
    res = evaluate_model(m, r, config or EvaluationConfig(), init=init, poses=cams)
    files = {} if output is None else write_evaluation(output, res, title=title or Path(model).name)
    return EvaluationRun(res, files)
