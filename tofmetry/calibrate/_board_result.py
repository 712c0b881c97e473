"""The result of a board-based depth calibration (:class:`BoardCalibrationResult`). Part of
:mod:`tofmetry.calibrate.board`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tofmetry.calibrate._board_folds import predict_error
from tofmetry.calibrate._board_model import BoardDepthModel, ModelSpec, to_depth_calibration
from tofmetry.calibrate._board_support import DarkBias
from tofmetry.calibrate._support import CalibrationSupport
from tofmetry.sensor.intrinsics import CameraIntrinsics


# ----------------------------------------------------------------------------- result
@dataclass
class BoardCalibrationResult:
    """Board-based depth calibration.

    Attributes
    ----------
    model : BoardDepthModel fitted on all usable views with the selected candidate.
    spec : the selected :class:`ModelSpec`; use_dark_views : whether views whose white squares
        are saturated entered the fit (through their dark squares and the measured dark bias).
    intrinsics, intrinsics_source : the IR/depth intrinsics used, and where they came from
        ("given", or "fitted on the board corners of N views").
    selection : list of dict per candidate: per design pooled held-out RMS [mm], score, paired
        difference to the best and its standard error; ``chosen`` marks the selected one.
    validation : {design: error stats of the chosen model on held-out folds}; designs "time",
        "range", "region" are blocked, "random" is labelled so and never used to select.
    cv : {"none", "constant_refit", "model"} -> error stats on the time-blocked folds (the
        former table of the CLI).
    cv_per_pose : {"none", "constant_refit", "model"} -> (V,) held-out RMS per view [mm] (time blocks).
    prediction : predicted error on new views (:func:`predict_error`, time-blocked folds).
    prediction_by_design : the same from each blocked design.
    support : :func:`support_counts` of the samples the final fit used.
    dark_bias : :class:`DarkBias`.
    views : list of dict per view (name, status, samples, RMS of its grids, ...).
    grid_screen : dict (corner noise, threshold, rejected grids).
    notes : list of str (what was decided and why).
    samples : {"u", "v", "z_mm"}: pixels and measured Z [mm] of the samples the final fit used.
    z_support_mm : (lo, hi) measured Z [mm] of the training samples (0.5-99.5 %); beyond it the
        correction is held (clamped), never extrapolated.
    held_out : {"view_ids", "errors", "view_order"}: the chosen model's held-out errors on the
        time blocks (for :meth:`predict`).
    grids : per input view, the list of accepted corner grids (cols*rows, 2) [px].
    """

    model: BoardDepthModel
    spec: ModelSpec
    use_dark_views: bool
    intrinsics: CameraIntrinsics
    intrinsics_source: str
    selection: list
    validation: dict
    cv: dict
    cv_per_pose: dict
    prediction: dict
    prediction_by_design: dict
    support: dict
    dark_bias: DarkBias
    views: list
    grid_screen: dict
    fit_residual: dict
    before: dict
    notes: list = field(default_factory=list)
    squares: str = "white"
    k_folds: int = 0
    constant_mm: float = float("nan")
    z_support_mm: tuple = (float("nan"), float("nan"))
    intrinsics_fit: dict | None = None
    samples: dict = field(default_factory=dict, repr=False)
    held_out: dict = field(default_factory=dict, repr=False)
    grids: list = field(default_factory=list, repr=False)

    def predict(self, n_new_views: int, seed: int = 0) -> dict:
        """Predicted error on a set of ``n_new_views`` new views (time-blocked held-out errors,
        moving-block bootstrap; :func:`predict_error`)."""
        h = self.held_out
        if not h:
            return predict_error(np.zeros(0), np.zeros(0))
        return predict_error(h["view_ids"], h["errors"], n_new_views, view_order=h["view_order"], seed=seed)

    @property
    def pose_index(self) -> list:
        """Indices (into the input views) of the views used."""
        return [r["index"] for r in self.views if r.get("used")]

    @property
    def skipped(self) -> list:
        return [(r["index"], r["reason"]) for r in self.views if r["status"] not in ("white", "dark-only")]

    @property
    def unused_dark_views(self) -> list:
        """Indices of the views with saturated white squares the selection left out."""
        return [r["index"] for r in self.views if r["status"] == "dark-only" and not r.get("used")]

    @property
    def dark_minus_white_mm(self) -> np.ndarray:
        return np.array([r["dark_minus_white_mm"] for r in self.views if r["index"] in set(self.pose_index)])

    @property
    def pose_rms_px(self) -> np.ndarray:
        return np.array([r["grid_rms_px"] for r in self.views if r["index"] in set(self.pose_index)])

    @property
    def n_samples(self) -> np.ndarray:
        return np.array([r["n_used"] for r in self.views if r["index"] in set(self.pose_index)])

    def depth_calibration(self, intrinsics: CameraIntrinsics | None = None, sensor: str = "kinect_v2",
                          provenance: dict | None = None):
        """The fitted model as a core ``DepthCalibration`` (save with
        ``tofmetry.io.calibration_file.save_calibration``); its diagnostics carry the summary,
        the prediction and the (sparse) support."""
        intr = intrinsics or self.intrinsics
        sup = self.support
        nz = np.argwhere(sup["counts"] > 0)
        by_n = {str(n): self.predict(n) for n in (1, 5, 10, 20, 50)} if self.held_out else {}
        diag = {"board": self.summary(), "predicted_error": self.prediction, "predicted_error_for_n_views": by_n,
                "support": {"cell_px": sup["cell_px"], "bin_mm": sup["bin_mm"], "u_edges": sup["u_edges"].tolist(),
                            "v_edges": sup["v_edges"].tolist(), "z_edges_mm": sup["z_edges_mm"].tolist(),
                            "index_vuz": nz.tolist(), "count": sup["counts"][tuple(nz.T)].tolist()}}
        support = CalibrationSupport.from_samples(self.samples["u"], self.samples["v"], self.samples["z_mm"], intr.shape) \
            if self.samples else None
        pred = {"method": "blocked validation over the board poses (contiguous blocks of poses in recording order, "
                          "bins of range, regions of the image); per-pose figures", "board": self.prediction,
                "board_for_n_views": by_n} if self.prediction else {}
        return to_depth_calibration(self.model, intr, sensor, provenance=provenance, diagnostics=diag, support=support,
                                    prediction=pred)

    def summary(self) -> dict:
        used = self.pose_index
        dmw = self.dark_minus_white_mm
        return {"model": self.spec.name, "model_description": self.model.describe(), "spec": self.spec.to_dict(),
                "use_dark_views": self.use_dark_views, "intrinsics_source": self.intrinsics_source,
                "squares": self.squares, "k_folds": self.k_folds,
                "cv_held_out": self.cv, "validation": self.validation, "prediction": self.prediction,
                "prediction_by_design": self.prediction_by_design, "selection": self.selection,
                "fit_residual": self.fit_residual, "before": self.before, "dark_bias": self.dark_bias.to_dict(),
                "grid_screen": self.grid_screen,
                "dark_minus_white_mm_median": (float(np.median(dmw[np.isfinite(dmw)])) if np.isfinite(dmw).any()
                                               else None),
                "pose_rms_px_median": float(np.median(self.pose_rms_px)) if len(used) else None,
                "n_poses": len(used), "n_samples": int(np.sum(self.n_samples)),
                "n_dark_only_views": sum(r["status"] == "dark-only" for r in self.views),
                "skipped_poses": self.skipped, "constant_mm": self.constant_mm,
                "z_support_mm": list(self.z_support_mm), "range_support_mm": list(self.model.x_support_mm),
                "range_variable": self.model.range_variable,
                "unsupported_surface_nodes": int(np.sum(self.model.support == 0)) if self.model.support.size else None,
                "support_samples": int(self.support["counts"].sum()), "notes": self.notes}
