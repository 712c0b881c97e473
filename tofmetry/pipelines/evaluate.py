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
from tofmetry.io import atomic_write_json, read_json
from tofmetry.io.mesh import read_geometry
from tofmetry.pipelines.paths import refuse_existing
from tofmetry.pipelines.plan import read_plan
from tofmetry.pipelines.plan_check import plan_check


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


def predicted_scale(scale: dict, poses_doc: dict) -> dict:
    """The reconstruction's predicted scale uncertainty (``poses.json`` -> ``scale``) beside the scale
    measured against the reference (:func:`tofmetry.evaluate.model_scale`).

    Returns
    -------
    dict: ``predicted_sigma_pct`` (1 sigma, None when the reconstruction gave none) and
    ``within_2_predicted_sigma`` (the measured scale error within twice the predicted sigma and the
    measurement's own, ``sigma_pct``, in quadrature; None when either is missing or the shape cannot
    tell the scale from a surface offset)
    """
    pred = (poses_doc.get("scale") or {}).get("predicted_scale_sigma_pct") if isinstance(poses_doc, dict) else None
    pred = float(pred) if isinstance(pred, (int, float)) and np.isfinite(pred) and pred > 0 else None
    measured = scale.get("scale_error_pct")
    own = scale.get("sigma_pct")
    own = float(own) if isinstance(own, (int, float)) and np.isfinite(own) else 0.0
    within = None if pred is None or measured is None else bool(abs(measured) <= 2 * np.hypot(pred, own))
    return {"predicted_sigma_pct": pred, "within_2_predicted_sigma": within}


def scale_summary(scale: dict) -> str:
    """One sentence on the model's scale against the reference (:func:`tofmetry.evaluate.model_scale`,
    with :func:`predicted_scale` where the reconstruction's poses.json was given)."""
    if "error" in scale:
        return f"scale against the reference: not measured ({scale['error']})"

    def pm(sigma, digits):  # a sigma below the last digit shown reads as such, not as 0
        return f"+- {sigma:.{digits}f}" if sigma is not None and sigma >= 10 ** -digits else f"+- <{10 ** -digits:g}"

    if scale["separable"]:
        line = (f"scale against the reference: {scale['scale_error_pct']:+.3f} {pm(scale['sigma_pct'], 3)} % "
                f"(surface offset {scale['offset_mm']:+.2f} {pm(scale['offset_sigma_mm'], 2)} mm)")
    else:
        line = (f"scale against the reference: this shape cannot tell a scale from a surface offset (correlation "
                f"{scale['correlation']:+.3f}); its size, both read as a scale: {scale['size_error_pct']:+.3f} "
                f"{pm(scale['size_sigma_pct'], 3)} %")
    if scale.get("predicted_sigma_pct") is not None:
        line += f"; the reconstruction predicted +-{scale['predicted_sigma_pct']:.2f} % (1 sigma)"
        if scale.get("within_2_predicted_sigma") is False:
            line += ": the measured scale is beyond 2 of its sigmas"
    return line


@dataclass
class EvaluationRun:
    """Result of :func:`evaluate_files`: the evaluation and the files written (name -> path:
    ``metrics``, ``histogram``, ``deviation_ply``, ``render``; empty without an output folder)."""

    result: EvaluationResult
    files: dict[str, Path] = field(default_factory=dict)
    plan: dict | None = None


def evaluate_files(model: str | os.PathLike, reference: str | os.PathLike, output: str | os.PathLike | None = None,
                   *, config: EvaluationConfig | None = None, init_transform: str | os.PathLike | None = None,
                   poses: str | os.PathLike | None = None, title: str | None = None,
                   plan: str | os.PathLike | None = None, force: bool = False) -> EvaluationRun:
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
    plan : a ``plan.json`` (``tofmetry plan``): its prediction beside the completeness achieved
        (:func:`tofmetry.pipelines.plan_check.plan_check`; needs ``poses`` and a mesh reference), written
        as ``plan_check.json``
    force : replace an existing, non-empty ``output`` (refused otherwise, before any work)

    Returns
    -------
    EvaluationRun
    """
    if output is not None:
        refuse_existing(output, force)
    if plan is not None and poses is None:
        raise InputError("evaluate --plan: give the reconstruction's poses.json too (--poses): the plan is judged on "
                         "the views as they were taken")
    plan_doc = None if plan is None else read_plan(plan)
    m = read_geometry(model, "model")
    r = read_geometry(reference, "reference")
    if plan is not None and not r.is_mesh:
        raise InputError(f"evaluate --plan: the reference {reference} holds no triangles; the plan needs a mesh")
    init = read_transform(init_transform) if init_transform is not None else None
    poses_doc = None if poses is None else read_json(poses, "poses")
    cams = None if poses is None else CameraViews.from_document(poses_doc, str(poses))
    res = evaluate_model(m, r, config or EvaluationConfig(), init=init, poses=cams)
    if poses_doc is not None and res.scale is not None and "error" not in res.scale:
        res.scale.update(predicted_scale(res.scale, poses_doc))
    check = None
    if plan_doc is not None:
        T = np.eye(4) if res.alignment is None else res.alignment.transform
        check = plan_check(plan_doc, (r.points, r.faces), res.points, cams, T)
    files = {} if output is None else write_evaluation(output, res, title=title or Path(model).name)
    if check is not None and output is not None:
        files["plan_check"] = Path(output) / "plan_check.json"
        atomic_write_json(files["plan_check"], check)
    return EvaluationRun(res, files, check)
