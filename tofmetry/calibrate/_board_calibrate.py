"""The body of :func:`tofmetry.calibrate.board.calibrate_depth_from_board`: grids, intrinsics,
samples per view, the pool, model selection on the blocked folds, the final fit and its
validation tables.
"""

from __future__ import annotations

import numpy as np

from tofmetry.calibrate._board_folds import (
    _design_masks, _done, _finite_mean, _fit, _fold_mse, _held_out_errors, _Pool, _subsample, blocked_folds,
    candidate_ladder, predict_error, region_folds,
)
from tofmetry.calibrate._board_model import ModelSpec
from tofmetry.calibrate._board_result import BoardCalibrationResult
from tofmetry.calibrate._board_samples import BoardSamples, board_samples, collect_grids, find_boards, screen_grids
from tofmetry.calibrate._board_support import error_stats, fit_dark_bias, support_counts
from tofmetry.calibrate._board_pose import board_inner, is_charuco, seen_corners
from tofmetry.calibrate._lens_fit import calibrate_intrinsics
from tofmetry.errors import EstimationError, InputError


def calibrate_intrinsics_on_grids(grids: list, names: list | None, board, square_mm: float,
                                  image_size: tuple[int, int], **kwargs):
    """:func:`~tofmetry.calibrate._lens_fit.calibrate_intrinsics` on board grids (a ChArUco grid: its
    seen corners with their own object points), without the leave-one-out refits."""
    kwargs.setdefault("leave_one_out", False)
    if not is_charuco(board):
        return calibrate_intrinsics(grids, names, board, square_mm, image_size, **kwargs)
    so = [seen_corners(c, board, square_mm) for c in grids]
    return calibrate_intrinsics([c for _, c in so], names, board_inner(board), board.square_mm, image_size,
                                object_points=[o for o, _ in so], **kwargs)


def _calibrate(poses, board, square_mm, intrinsics, names, seed, sensor, min_samples, candidates, use_dark_views,
               max_boards, max_samples_per_view, k_folds, sample_kwargs, advance) -> BoardCalibrationResult:
    """:func:`calibrate_depth_from_board` (its body)."""
    adv = advance or (lambda *a: None)
    sample_kwargs = sample_kwargs or {}
    V0 = len(poses)
    if V0 == 0:
        raise EstimationError("no board views given")
    names = list(names) if names is not None else [f"view{i:03d}" for i in range(V0)]
    if len(names) != V0:
        raise InputError(f"calibrate_depth_from_board: {len(names)} names for {V0} views")
    shape = np.asarray(poses[0][0]).shape
    notes: list[str] = []
    grids, gsource = collect_grids(poses, board, max_boards)
    # ---- intrinsics
    ifit = None
    if intrinsics is not None:
        intr, isrc = intrinsics, "given"
        if tuple(intr.shape) != tuple(shape):
            raise InputError(f"intrinsics {intr.width}x{intr.height} do not match the depth images {shape[1]}x{shape[0]}")
    else:
        flat = [(i, c) for i, g in enumerate(grids) for c in g]
        if len(flat) < 3:
            raise EstimationError(f"no intrinsics given and only {len(flat)} board grid(s) to fit them on (need >= 3): "
                                  "pass the device's intrinsics")
        ifit = calibrate_intrinsics_on_grids([c for _, c in flat], [f"{names[i]}#{j}" for j, (i, _) in enumerate(flat)],
                                             board, square_mm, (shape[1], shape[0]))
        intr = ifit.intrinsics
        isrc = (f"fitted on the board corners of {len(ifit.used)} grids (RMS {ifit.rms_px:.3f} px; "
                f"{len(ifit.rejected_views)} rejected)")
        notes.append(f"no intrinsics given: {isrc}")
    # ---- screen grids (a threshold from the measured corner noise), re-detect where the given grid fails
    allg = [c for g in grids for c in g]
    scr = screen_grids(allg, board, square_mm, intr)
    sigma = scr.sigma_px
    rows: list[dict] = []
    per_view: list[list[np.ndarray]] = []
    rejected = []
    pos = 0
    for i, g in enumerate(grids):
        acc = []
        rms_i = []
        for c in g:
            if scr.accepted[pos]:
                acc.append(c)
                rms_i.append(scr.rms_px[pos])
            else:
                rejected.append({"view": names[i], "rms_px": float(scr.rms_px[pos]), "source": gsource[i]})
            pos += 1
        if not acc and gsource[i] == "given":
            found = find_boards(poses[i][1], board, max_boards)
            if found:
                s2 = screen_grids(found, board, square_mm, intr, sigma_px=sigma)
                acc = [c for c, ok in zip(found, s2.accepted) if ok]
                rms_i = [r for r, ok in zip(s2.rms_px, s2.accepted) if ok]
                if acc:
                    notes.append(f"{names[i]}: the given corners were rejected; {len(acc)} board(s) detected in the IR "
                                 f"image used instead (RMS {max(rms_i):.2f} px)")
        per_view.append(acc)
        rows.append({"index": i, "name": names[i], "n_grids": len(acc), "grid_rms_px": float(max(rms_i)) if rms_i
                     else float("nan"), "n_corners": int(sum(np.isfinite(c).all(axis=1).sum() for c in acc))})
    grid_info = {"corner_noise_px": sigma, "threshold_px": scr.threshold_px, "rejected": rejected,
                 "n_grids": len(allg), "n_accepted": int(sum(len(a) for a in per_view))}
    if rejected:
        notes.append(f"{len(rejected)} corner grid(s) rejected: reprojection RMS above {scr.threshold_px:.2f} px "
                     f"(corner noise {sigma:.3f} px): " + ", ".join(f"{r['view']} {r['rms_px']:.2f} px" for r in rejected))
    # ---- samples per view
    samples: list[BoardSamples | None] = []
    for i, acc in enumerate(per_view):
        r = rows[i]
        depth, ir, _ = poses[i]
        parts = []
        for c in acc:
            try:
                parts.append(board_samples(depth, ir, c, board, square_mm, intr, **sample_kwargs))
            except EstimationError as exc:
                r.setdefault("errors", []).append(str(exc))
        s = BoardSamples.concat(parts) if parts else None
        samples.append(s)
        if s is None:
            r.update(status="skipped", reason="no accepted board grid" if not acc else "; ".join(r.get("errors", [])),
                     n_white=0, n_dark=0, n_used=0, z_median_mm=float("nan"), dark_minus_white_mm=float("nan"))
            adv()
            continue
        nw, nd = int(s.white.sum()), int(s.dark.sum())
        r.update(n_white=nw, n_dark=nd, n_saturated=s.n_saturated, z_median_mm=float(np.median(s.measured_mm)),
                 dark_minus_white_mm=s.dark_minus_white_mm, dark_amplitude=float(np.median(s.amplitude[s.dark]))
                 if nd else float("nan"))
        if nw >= min_samples:
            r.update(status="white", reason="", n_used=nw)
        elif nd >= min_samples:
            why = (f"white squares saturated ({s.n_saturated} px lost)" if s.n_saturated >= nw else
                   f"only {nw} white pixels (a ChArUco board's white margins are narrow at this range)")
            r.update(status="dark-only", reason=f"{why}: dark squares used", n_used=nd)
        else:
            r.update(status="skipped", reason=f"only {nw} white and {nd} dark usable pixels (< {min_samples})", n_used=0)
        adv()
    dark = fit_dark_bias([s for s, r in zip(samples, rows) if s is not None and r["status"] == "white"])
    n_white_views = sum(r["status"] == "white" for r in rows)
    if n_white_views == 0:
        reasons = "; ".join(f"{r['name']}: {r['reason']}" for r in rows)
        raise EstimationError(f"no view with usable white board squares ({reasons})")
    if any(r["status"] == "dark-only" for r in rows) and not dark.known:
        for r in rows:
            if r["status"] == "dark-only":
                r.update(status="skipped", reason=r["reason"].split(":")[0] + " and the dark-square bias could not "
                         "be measured (no view with both parities)", n_used=0)
    # ---- pool
    used = [i for i, r in enumerate(rows) if r["status"] in ("white", "dark-only")]
    vidx = {i: j for j, i in enumerate(used)}
    parts = {k: [] for k in ("u", "v", "z", "zref", "view", "judge", "dark_view")}
    for i in used:
        s = samples[i]
        if rows[i]["status"] == "white":
            m = s.white
            z = s.measured_mm[m]
            judge = np.ones(m.sum(), bool)
        else:
            m = s.dark
            z = s.measured_mm[m] - dark(s.amplitude[m])
            judge = np.zeros(m.sum(), bool)
        parts["u"].append(s.u[m])
        parts["v"].append(s.v[m])
        parts["z"].append(z)
        parts["zref"].append(s.reference_mm[m])
        parts["view"].append(np.full(m.sum(), vidx[i]))
        parts["judge"].append(judge)
        parts["dark_view"].append(~judge)
    pool = _Pool(*(np.concatenate(parts[k]) for k in ("u", "v", "z", "zref", "view", "judge", "dark_view")))
    V = len(used)
    view_z = np.array([rows[i]["z_median_mm"] for i in used])
    white_views = np.array([rows[i]["status"] == "white" for i in used])
    has_dark_views = not white_views.all()
    z_span = float(np.ptp(view_z[white_views])) if white_views.sum() > 1 else 0.0
    # ---- candidates and validation designs
    sub = pool.take(_subsample(pool.view, max_samples_per_view, seed))
    designs: dict = {}
    nwv = int(white_views.sum())
    if nwv >= 2:
        order = np.array(used, float)
        designs["time"] = blocked_folds(order, view_z, "time", k=k_folds)
        if nwv >= 3:
            designs["range"] = blocked_folds(order, view_z, "range", k=min(4, nwv))
        designs["region"] = region_folds(shape)
    masks = _design_masks(sub, designs)
    force_dark = has_dark_views and use_dark_views is True
    selection: list[dict] = []
    results_by: dict = {}

    def evaluate(spec: ModelSpec, ud: bool) -> dict:
        res = {d: _held_out_errors(sub, spec, shape, intr, ud, masks[d]) for d in designs}
        results_by[(spec.name, ud)] = res
        row = {"name": spec.name, "use_dark_views": ud, "complexity": spec.complexity, "spec": spec}
        for d in designs:
            done = _done(res[d])
            e = np.concatenate([x for _, _, x in done]) if done else np.zeros(0)
            row[f"{d}_rms_mm"] = float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")
        row["score_mm"] = float(np.sqrt(_finite_mean([row[f"{d}_rms_mm"] ** 2 for d in designs])))
        row["_folds"] = np.concatenate([_fold_mse(res[d]) for d in designs])
        selection.append(row)
        adv()
        return row

    # "No correction" is not a simpler model of the same error but a claim that the sensor has
    # none: it is a candidate only when the views' mean errors do not show an offset (within two
    # standard errors of their mean; with few views one standard error of the held-out scores is
    # wide, and a ToF camera's constant offset is usually there)
    jv = pool.judge
    view_mean = np.array([np.mean((pool.zref - pool.z)[jv & (pool.view == k)]) for k in range(V)
                          if (jv & (pool.view == k)).any()])
    offset_shown = len(view_mean) >= 2 and abs(view_mean.mean()) > 2 * view_mean.std(ddof=1) / np.sqrt(len(view_mean))

    def one_se(rows: list[dict]) -> dict:
        """Simplest row whose mean held-out MSE over all blocked folds exceeds the best one's by
        at most one standard error of the paired fold differences ("no correction" only when the
        views show no offset, see above)."""
        best = min(rows, key=lambda r: _finite_mean(r["_folds"]))
        for r in rows:
            dv = r["_folds"] - best["_folds"]
            dv = dv[np.isfinite(dv)]
            r["paired_excess_mse"] = float(np.mean(dv)) if dv.size else 0.0
            r["paired_excess_se"] = float(np.std(dv, ddof=1) / np.sqrt(dv.size)) if dv.size > 1 else 0.0
        ok = [r for r in rows if r["paired_excess_mse"] <= r["paired_excess_se"]
              and not (r["spec"].identity and offset_shown)] or [best]
        return min(ok, key=lambda r: (r["complexity"], _finite_mean(r["_folds"])))

    if candidates is not None:
        ladder = list(candidates)
    else:
        ladder = candidate_ladder(nwv, z_span, range_variable="radial")
        ladder = [c for c in ladder if c.complexity <= 2]
    if designs:
        stage1 = [evaluate(c, force_dark) for c in ladder]
        if candidates is None and nwv >= 6:
            # the range variable of the best range-only candidate carries the surfaces
            rv = min((r for r in stage1 if r["complexity"] > 0), key=lambda r: r["score_mm"], default=None)
            rv = rv["spec"].range_variable if rv is not None else "radial"
            more = [c for c in candidate_ladder(nwv, z_span, range_variable=rv) if c.complexity >= 3]
            ladder += more
            stage1 += [evaluate(c, force_dark) for c in more]
        chosen = one_se(stage1)
        if has_dark_views and use_dark_views == "auto":
            with_dark = evaluate(chosen["spec"], True)
            dv = with_dark["_folds"] - chosen["_folds"]
            dv = dv[np.isfinite(dv)]
            with_dark["paired_excess_mse"] = float(np.mean(dv)) if dv.size else 0.0
            with_dark["paired_excess_se"] = float(np.std(dv, ddof=1) / np.sqrt(dv.size)) if dv.size > 1 else 0.0
            # all poses are used unless the blocked folds show that the dark-square views (and the
            # bias model they need) make the held-out error worse by more than one standard error
            if not dv.size or with_dark["paired_excess_mse"] <= with_dark["paired_excess_se"]:
                chosen = with_dark
    else:
        ladder = [ModelSpec("constant", "z", 0.0, complexity=0)]
        chosen = {"name": "constant", "use_dark_views": force_dark, "complexity": 0, "spec": ladder[0]}
        selection.append(chosen)
        notes.append("a single usable view: no validation possible, a constant is fitted")
    for row in selection:
        row["chosen"] = row is chosen
        row.pop("_folds", None)
    spec = chosen.pop("spec")
    for row in selection:
        row.pop("spec", None)
    use_dark = bool(chosen["use_dark_views"])
    for r in rows:
        r["used"] = r["status"] == "white" or (r["status"] == "dark-only" and use_dark)
    # ---- final fit: the validated procedure on all views (same per-view sample cap)
    model = _fit(sub, spec, shape, intr, use_dark)
    fitm = sub.judge | (sub.dark_view if use_dark else False)
    supp = support_counts(sub.u[fitm], sub.v[fitm], sub.z[fitm], shape)
    zfit = sub.z[fitm]
    z_support = (float(np.percentile(zfit, 0.5)), float(np.percentile(zfit, 99.5)))
    const = float(np.mean(pool.zref[pool.judge] - pool.z[pool.judge]))
    # ---- validation tables of the chosen model
    validation, pred_by, held_out = {}, {}, {}
    res = results_by.get((spec.name, use_dark), {})
    for d in designs:
        done = _done(res[d])
        if done:
            ids = np.concatenate([x for _, x, _ in done])
            e = np.concatenate([x for _, _, x in done])
            validation[d] = {**error_stats(e), "folds": len(done), "blocked": True}
            order = np.array(used)[np.unique(ids)] if d == "time" else None
            pred_by[d] = predict_error(ids, e, view_order=order, seed=seed)
            if d == "time":
                held_out = {"view_ids": ids, "errors": e, "view_order": order}
    cv, per_pose = {}, {}
    if "time" in designs:
        fm = masks["time"]
        base = {"none": [], "constant_refit": [], "model": []}
        per_pose = {c: np.full(V, np.nan) for c in base}
        for (label, test), r in zip(fm, res["time"]):
            if r is None:
                continue
            e = r[2]
            tr = sub.take(~test & sub.judge)
            cst = float(np.mean(tr.zref - tr.z)) if tr.z.size else 0.0
            te = sub.take(test & sub.judge)
            e0 = te.z - te.zref
            for c, ee in (("none", e0), ("constant_refit", e0 + cst), ("model", e)):
                base[c].append(ee)
                for k in np.unique(te.view):
                    per_pose[c][k] = float(np.sqrt(np.mean(ee[te.view == k] ** 2)))
        cv = {c: error_stats(np.concatenate(v)) if v else error_stats([]) for c, v in base.items()}
    if nwv >= 2:
        rf = [(f"random {j}", np.isin(sub.view, f)) for j, f in
              enumerate(blocked_folds(np.arange(V), view_z, "random", k=k_folds, seed=seed))]
        rr = _done(_held_out_errors(sub, spec, shape, intr, use_dark, rf))
        if rr:
            validation["random"] = {**error_stats(np.concatenate([x for _, _, x in rr])), "folds": len(rr),
                                    "blocked": False, "label": "random k-fold over views (not blocked)"}
    prediction = pred_by.get("time") or {}
    for i, r in enumerate(rows):
        if i in vidx and per_pose:
            r["held_out_rms_mm"] = {c: float(v[vidx[i]]) for c, v in per_pose.items()}
    # final notes
    if designs and spec.identity:
        notes.append(f"no correction: on the blocked folds no model beat the raw depth ({nwv} view(s) with white "
                     "squares); the calibration leaves depth unchanged")
    elif designs and spec.complexity <= 1:
        notes.append(f"the blocked validation supports only '{spec.name}' with {nwv} view(s) holding white squares")
    if has_dark_views:
        nd = int((~white_views).sum())
        what = "too few white pixels (saturated white squares, or a ChArUco board's narrow white margins)" \
            if is_charuco(board) else "saturated white squares"
        notes.append(f"{nd} view(s) with {what}: " + (
            "used through their dark squares (dark-square bias measured vs amplitude on "
            f"{len(dark.contrast_mm)} views, residual {dark.residual_mm:.1f} mm)" if use_dark else
            "left out of the fit (on the blocked folds they made the held-out error worse by more than one "
            "standard error)"))
    e_fit = pool.z[pool.judge] + model.correction(pool.u[pool.judge], pool.v[pool.judge], pool.z[pool.judge]) \
        - pool.zref[pool.judge]
    return BoardCalibrationResult(
        model=model, spec=spec, use_dark_views=use_dark, intrinsics=intr, intrinsics_source=isrc,
        selection=selection, validation=validation, cv=cv, cv_per_pose=per_pose, prediction=prediction,
        prediction_by_design=pred_by, support=supp, dark_bias=dark, views=rows, grid_screen=grid_info,
        fit_residual=error_stats(e_fit), before=error_stats(pool.z[pool.judge] - pool.zref[pool.judge]), notes=notes,
        squares="white" + (" + dark (saturated views)" if use_dark else ""), k_folds=len(designs.get("time", [])),
        constant_mm=const, z_support_mm=z_support, intrinsics_fit=ifit.to_dict() if ifit is not None else None,
        samples={"u": sub.u[fitm], "v": sub.v[fitm], "z_mm": sub.z[fitm]}, held_out=held_out, grids=per_view,
    )
