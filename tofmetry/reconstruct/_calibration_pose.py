"""How far the depth calibration's per-pixel residual can move the poses of one finished joint fit.

The prediction (:mod:`~tofmetry.reconstruct._adjust_field`) needs the normal equations the global
adjustment (:func:`~tofmetry.reconstruct._adjust.global_adjust`) ended with: one more pass over its
final correspondences gives their response to each term of the residual field
(:func:`field_pose_response`), and that response, drawn over fields of the calibration's size, the
poses' spread (:func:`calibration_pose`). It is asked for once, on the adjustment a pipeline keeps
(:mod:`~tofmetry.reconstruct._adjust_stage`), from the state the fit leaves on its result
(:attr:`~tofmetry.reconstruct._adjust_result.AdjustResult.final_state`), not on each run the
pipeline tries; the fit computes it itself when it is given the field's size (``depth_field``).
"""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct._adjust_field import DepthFieldPrior, pose_spread
from tofmetry.reconstruct._adjust_result import AdjustResult
from tofmetry.reconstruct._adjust_terms import _normal_equations, world_sources


def field_pose_response(res: AdjustResult, depth_field: DepthFieldPrior) -> np.ndarray:
    """How the calibration's residual field moves the poses of the adjustment ``res``: (6 (V - 1), T)
    left increments (rotation vector [rad], translation [m], view 0 fixed) per unit coefficient of each
    term of ``depth_field`` (``dx = -H^-1 F c``, :mod:`~tofmetry.reconstruct._adjust_field`), from one
    more pass over its final correspondences (~0.5 s on 8 views)."""
    views, P, g, z_ref_m, corr, k, estimate_gain, curve, amp, tilt, H_solve, _, sym = res.final_state
    F = _normal_equations(views, P, g, z_ref_m, corr, k, estimate_gain, curve, amp, tilt, depth_field.basis,
                          symmetric=sym)[-1]
    return -np.linalg.solve(H_solve, F)[:6 * (len(views) - 1)]


def calibration_pose(res: AdjustResult, depth_field: DepthFieldPrior, response: np.ndarray | None = None) -> dict:
    """The poses' spread of the adjustment ``res`` under random depth fields of ``depth_field``'s
    size (:func:`~tofmetry.reconstruct._adjust_field.pose_spread`), propagated through the normal
    equations it ended with (:attr:`AdjustResult.final_state`; ``response``: :func:`field_pose_response`,
    computed when not given). Asked for on the adjustment a pipeline keeps, not on each run it tries.

    Returns
    -------
    dict of :func:`~tofmetry.reconstruct._adjust_field.pose_spread` (the field alone, and
    ``with_noise``: with the poses' own noise covariance from the data, as ``pose_sigma_deg``) with
    the prior's size (``offset_sigma_mm``, ``shape_rms_mm``, ``degree``, ``gain_sigma_pct``: the depth
    gain's standard deviation [%], 0 without the range term)
    """
    views, P, *_, noise_cov, _ = res.final_state
    resp = field_pose_response(res, depth_field) if response is None else response
    obj = world_sources(views, P)
    return pose_spread(resp, depth_field.coefficient_sigmas(), len(views), obj, noise_cov=noise_cov) | {
        "offset_sigma_mm": round(depth_field.offset_sigma_m * 1e3, 4),
        "shape_rms_mm": round(depth_field.shape_rms_m * 1e3, 4), "degree": depth_field.degree,
        "gain_sigma_pct": round(depth_field.gain_sigma * 100, 4)}
