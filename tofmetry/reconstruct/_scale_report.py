"""The model's predicted scale and surface-offset uncertainty (:func:`scale_report`), from the depth chain.

The verdicts (:mod:`~tofmetry.reconstruct._verdict`) say whether the poses can be trusted; this says
how far the model's size can be: what the depth calibration's predicted error, the self-calibrated
gain's standard error, the amplitude bias's uncertainty and the joint fit's range curve
(:func:`curve_residual_mm`) leave on the model's scale and on its surfaces' offset. It is reported
beside the verdict (the reconstruction's ``scale``) and makes no run unreliable.
"""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct._calibration_support import (
    calibration_central_mm,
    calibration_gain_sigma,
    station_spacing_mm,
)


#: 1-sigma of an object's range offset from its support's at the same depth [mm], which no support
#: curve shows (its albedo and incidence, where it lies in the image): measured on development draws
#: against the truth, the object read +0.5 mm (rocker arm 1593594514) and +0.75 mm (vase 817315791)
#: farther than the mat beside it
OBJECT_SUPPORT_OFFSET_MM = 0.6


def scale_report(adjustment: dict | None, calibration_prediction: dict | None, z_ref_mm: float,
                 budget=None, k_sigma_mm: float | None = None, floor_pct: float = 0.0,
                 support: dict | None = None, depth_span_mm=None, extrapolation: dict | None = None,
                 placements_sigma_pct: float | None = None) -> dict:
    """The model's predicted scale and surface-offset uncertainty from the depth chain.

    A range offset ``e`` left by the calibration moves every point along its ray: the surfaces
    move by ``e`` toward their cameras (a normal offset of the model, which makes an object seen
    from all round ``2 e`` thinner or thicker) and the lateral size scales by ``e / z``. A gain ``g``
    left over the object's depth stretches each view along its line of sight; fused from all round
    it scales the model by about ``g / 2``. So ``sigma_scale = sqrt((e / z)^2 + (sigma_g / 2)^2)``
    with ``e`` the calibration's predicted central error (quadratic mean over its blocked folds)
    and ``sigma_g`` the self-calibrated gain's standard error when it was estimated, otherwise
    the gain a calibration with that error can leave between stations
    (:func:`~tofmetry.reconstruct._calibration_support.calibration_gain_sigma`: ``e / (spacing / 2)``
    with evenly spaced stations, fold by fold otherwise).
    Not included: the lens calibration's focal error (it scales the lateral size as well).

    A self-calibrated gain trades with the amplitude-bias coefficient ``k`` (both act through the
    depth of points seen at different incidences): with ``k_sigma_mm`` [mm per ln unit], its
    uncertainty, and the gain's regression on ``dk`` from the adjustment
    (``amplitude_bias.gain_per_mm_per_ln``), ``sigma_g`` gains ``|slope| k_sigma_mm`` in quadrature.

    ``budget``: optional callable ``(offset_sigma_m, gain_sigma) -> dict`` of
    :func:`~tofmetry.reconstruct._scale_budget.scale_budget`: the same errors, and the amplitude
    bias's uncertainty, propagated on the model's own geometry (poses held). The prediction is
    the larger of the two (``rule_scale_sigma_pct``, ``budget_scale_sigma_pct``): the budget sees
    which surfaces face the cameras, which on elongated or flat parts makes the scale far more sensitive
    than the rule says; the rule's ``g / 2`` stands for the views re-registering, which the budget does
    not model. Neither counts the registration's own errors or the fusion's. On 2026-11-25's family
    (docs/history/object-models.md), before the gain inherited ``k``'s uncertainty both undershot the
    measured scale error (1.55 sigma at the median); with it the measured error was 0.41 sigma at the
    median, 5 of 5 reliable runs within 1.645 sigma.

    Where the gain was not estimated but the joint fit estimated its range curve
    (``adjustment.range_curve``), the curve's RMS over the object's depths (:func:`curve_residual_mm`)
    is the views' own measure of the range error the calibration left there; when it exceeds ``e``,
    the gain a calibration can leave is taken from it instead (``curve_residual_mm``). Measured on the
    35 reliable runs of family draws 30-34 with a scale: two ended 2.7 and 2.8 sigma off (an igea
    -0.60 % against 0.21 %, its curve 1.43 mm RMS where the calibration predicted 0.36 mm); recomputed
    with the curve, 1 run beyond 2 sigma, |error| / sigma p68 0.31 (0.40 before), p90 0.78 (1.32).

    ``support``: the report of the range curve the flat support showed, subtracted from the views
    before the fusion (:func:`~tofmetry.reconstruct._support_curve.correct_by_support`). Where it was
    applied, the wiggle between the calibration's stations is gone from the model and the gain left
    is (a) the curve's own uncertainty over the object's depths (``object_gain_sigma_pct``, from the
    views' jackknife) and (b) the part of the calibration's residual in ``1, Z, Z^2`` over the support's
    span, which a plane cannot show: ``sqrt(2) e / span`` (the residual ``e`` at both ends of the span, of
    either sign). Measured (docs/history/object-models.md, session 34): on draw 74 with two draw-73
    sensors, 15 of 16 reliable runs with a scale within 1 sigma, all within 2 (median sigma 0.25 ->
    0.18 %); on held-out draw 75, 12 of 13 within 1 sigma, all within 2.

    ``floor_pct`` [%], the modelling chain's own scale error (registration, fusion, meshing; a
    configured figure, :attr:`RegistrationConfig.scale_floor_pct`), is added in quadrature to the
    prediction (``chain_floor_pct``).

    ``depth_span_mm``: (lo, hi) depths Z the object's points span [mm], the lever of the gain a
    calibration can leave (:func:`~tofmetry.reconstruct._calibration_support.calibration_gain_sigma`).

    ``extrapolation``: where part of the object lies beyond the calibration's stations, the scale
    1-sigma its extrapolation adds (:func:`~tofmetry.reconstruct._calibration_support.extrapolation_scale_sigma`),
    in quadrature (``extrapolation_scale_sigma_pct``).

    ``placements_sigma_pct`` [%]: where the dot mat's placements stand as the poses, unrefined by the
    joint fit, the scale 1-sigma their own pose errors leave
    (:func:`~tofmetry.reconstruct._mat_scale.placed_scale`), in quadrature
    (``placements_scale_sigma_pct``). Where the fit refined them, the budget's poses' term counts them
    (:func:`~tofmetry.reconstruct._mat_scale.budget_held`).

    Returns
    -------
    dict: depth_gain, gain_estimated, gain_sigma, predicted_scale_sigma_pct,
    predicted_offset_sigma_mm, station_spacing_mm, source
    """
    adj = adjustment or {}
    g = float(adj.get("depth_gain", 0.0) or 0.0)
    est = bool(adj.get("gain_estimated", False))
    out = {"depth_gain": g, "gain_estimated": est, "gain_note": adj.get("gain_note"), "z_ref_mm": float(z_ref_mm)}
    if calibration_prediction is None:
        return out | {"predicted_scale_sigma_pct": None, "predicted_offset_sigma_mm": None,
                      "source": "raw depth: no calibration, no prediction"}
    e = calibration_central_mm(calibration_prediction)
    spacing = station_spacing_mm(calibration_prediction)
    if e is None:
        return out | {"predicted_scale_sigma_pct": None, "predicted_offset_sigma_mm": None,
                      "source": "the calibration carries no predicted error"}
    e_gain, e_curve = e, curve_residual_mm(adj)
    if not est and e_curve is not None and e_curve > e:  # the views show more residual than predicted
        e_gain = e_curve
        out["curve_residual_mm"] = e_curve
    sg_cal = calibration_gain_sigma(calibration_prediction, depth_span_mm)
    sg = (float(adj.get("gain_sigma_data", np.nan)) if est else
          sg_cal * e_gain / e if e > 0 and sg_cal is not None else e_gain / (spacing / 2))
    on_support = bool((support or {}).get("applied"))
    anchored = on_support and bool(support.get("anchored"))
    whole = anchored and not support.get("levelled", True)  # its level at the object measured and applied too
    if on_support:
        span = float(np.diff(support["span_mm"])[0])
        # anchored, the curve is whole (its gain measured too): only its own jackknife sigma is left
        sg_support = float(np.hypot(0.0 if anchored else np.sqrt(2.0) * e_gain / span,
                                    support["object_gain_sigma_pct"] / 100))
        sg = float(np.hypot(sg, support["object_gain_sigma_pct"] / 100)) if est else sg_support
        out["gain_sigma_support"] = sg_support
    if whole:  # the offset at the object measured by the mat's planes: its 1-sigma replaces the calibration's,
        # with what the support cannot show of the object's own (OBJECT_SUPPORT_OFFSET_MM)
        e = float(np.hypot(support["object_offset_sigma_mm"], OBJECT_SUPPORT_OFFSET_MM))
    slope = (adj.get("amplitude_bias") or {}).get("gain_per_mm_per_ln")
    sg_k = abs(float(slope)) * k_sigma_mm if est and slope is not None and k_sigma_mm is not None else 0.0
    if sg_k > 0:
        out["gain_sigma_from_k"] = sg_k
        sg = float(np.hypot(sg, sg_k))
    s = float(np.hypot(e / z_ref_mm, sg / 2))
    src = "calibration's predicted central error" + (" and the self-calibrated gain's standard error"
                                                     if est else " (gain not estimated)")
    if e_gain > e:
        src += (f"; the gain it can leave taken from the joint fit's range curve, {e_gain:.2f} mm RMS over the "
                f"object's depths (more than the calibration's predicted {e:.2f} mm)")
    if sg_k > 0:
        src += f" (with k known to +-{k_sigma_mm:.2f} mm per ln unit)"
    if anchored and not whole:
        src += (f"; the range error's gain and curvature at the object read from the dot mat's support (anchored on "
                f"{support['n_anchors']} views' planes the printed dots give) and removed, +-"
                f"{support['object_gain_sigma_pct']:.3f} % left (the views' jackknife; the lens's focal length error is "
                "not in it)")
    elif whole:
        src = (f"the range error at the object read from the dot mat's support and removed, its offset, gain and "
               f"curvature from {support['n_anchors']} views' planes the printed dots give (+-"
               f"{support['object_offset_sigma_mm']:.2f} mm and +-{support['object_gain_sigma_pct']:.3f} % there, "
               f"the views' jackknife; the lens's focal length error is not in it), and +-{OBJECT_SUPPORT_OFFSET_MM:g} "
               "mm for the object's own offset from the support's at the same depth")
    elif on_support and not est:
        src += (f"; the wiggle between its stations read from the flat support and removed (the gain left: its "
                f"linear part over the support's {span:.0f} mm of depth, and the support curve's own "
                f"+-{support['object_gain_sigma_pct']:.3f} %)")
    out |= {"gain_sigma": sg, "predicted_scale_sigma_pct": 100 * s, "rule_scale_sigma_pct": 100 * s,
            "predicted_offset_sigma_mm": float(e), "station_spacing_mm": spacing, "source": src}
    b = budget(e * 1e-3, sg) if budget is not None and np.isfinite(sg) else None
    if b is not None:
        out["budget"] = b
        out["budget_scale_sigma_pct"] = 100 * float(b["sigma"]) if np.isfinite(b.get("sigma", np.nan)) else None
        if out["budget_scale_sigma_pct"] is not None and out["budget_scale_sigma_pct"] > 100 * s:
            out["predicted_scale_sigma_pct"] = out["budget_scale_sigma_pct"]
            out["source"] = src + ", propagated on the model's geometry" + (
                "" if "amplitude" not in b else " with the amplitude bias's uncertainty") + (
                "" if "sigma_poses_held" not in b else ", and the poses' own uncertainty")
    if extrapolation and extrapolation.get("sigma_pct", 0) > 0:
        out["extrapolation"] = extrapolation
        out["extrapolation_scale_sigma_pct"] = float(extrapolation["sigma_pct"])
        out["predicted_scale_sigma_pct"] = float(np.hypot(out["predicted_scale_sigma_pct"], extrapolation["sigma_pct"]))
        out["source"] += (f"; {100 * extrapolation['share']:.0f} % of the object's points lie beyond the calibration's "
                          f"stations, where its correction drifts by up to {extrapolation['error_mm']:.1f} mm per "
                          f"{extrapolation['spacing_mm']:.0f} mm of depth: +-{extrapolation['sigma_pct']:.2f} %")
    if placements_sigma_pct is not None and np.isfinite(placements_sigma_pct) and placements_sigma_pct > 0:
        out["placements_scale_sigma_pct"] = float(placements_sigma_pct)
        out["predicted_scale_sigma_pct"] = float(np.hypot(out["predicted_scale_sigma_pct"], placements_sigma_pct))
        out["source"] += (f"; the dot mat's placements, standing unrefined as the poses, +-{placements_sigma_pct:.3f} % "
                          "from their own dots, tilt and height")
    if floor_pct > 0:
        out["chain_floor_pct"] = float(floor_pct)
        out["predicted_scale_sigma_pct"] = float(np.hypot(out["predicted_scale_sigma_pct"], floor_pct))
        out["source"] += f"; the modelling chain's own {floor_pct:g} % in quadrature"
    return out


def curve_residual_mm(adjustment: dict | None) -> float | None:
    """RMS [mm] of the joint fit's estimated range curve at its five reported depths
    (``adjustment.range_curve.dz_mm``, zero at ``z_ref``): the range error the views show the
    calibration left over the object's depths; None when the curve was not estimated."""
    rc = (adjustment or {}).get("range_curve") or {}
    dz = rc.get("dz_mm")
    if not rc.get("estimated") or not dz:
        return None
    return float(np.sqrt(np.mean(np.square(np.asarray(dz, float)))))
