"""CLI commands: ``reconstruct`` (scan folder -> mesh; ``--rig``: one capture per sensor of a rig, fused in
the rig frame), ``evaluate`` (model vs reference) and ``plan``."""

from __future__ import annotations

import math
from pathlib import Path

import typer
from rich.table import Table

from tofmetry._shared.study_constants import AMPLITUDE_BIAS_MM_PER_LN
from tofmetry.cli._common import console, progress
from tofmetry.errors import InputError


def reconstruct(
    scan_dir: Path = typer.Argument(..., help="Scan dataset (views/<name>/ captures, processed in name order)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder (points.ply, mesh.ply, poses.json)."),
    calibration: Path | None = typer.Option(None, "--calibration", help="Depth calibration file (tofmetry calibrate depth)."),
    no_calibration: bool = typer.Option(False, "--no-calibration", help="Run on raw depth (no calibration)."),
    amplitude_reference: Path | None = typer.Option(
        None, "--amplitude-reference", help="Wall dataset (white, frontal; e.g. the one of the depth calibration) "
        "giving the white amplitude per pixel: enables the amplitude-dependent bias correction (needs IR)."),
    amplitude_max_mm: float = typer.Option(2500.0, help="Use wall stations up to this distance for the amplitude reference [mm]."),
    amplitude_k: float | None = typer.Option(
        None, "--amplitude-k",
        help=f"Slope k of the amplitude bias k ln(A_white / A) [mm per unit ln]; default the paper's 12 / ln 6 = "
        f"{AMPLITUDE_BIAS_MM_PER_LN:.2f}, which came from one sensor (better: --amplitude-board)."),
    amplitude_board: list[Path] | None = typer.Option(
        None, "--amplitude-board", help="Capture (depth + IR) of a grey-level checkerboard seen frontally, e.g. "
        "'tofmetry simulate materials' (repeatable: boards at other distances): measures this sensor's k and its "
        "uncertainty after the depth calibration, used instead of the default. Needs --amplitude-reference."),
    keep_all: bool = typer.Option(False, "--keep-all", help="Skip object segmentation: keep the whole working range."),
    poisson: bool = typer.Option(False, "--poisson", help="Also write a density-trimmed Poisson mesh (mesh_poisson.ply)."),
    voxel_mm: float | None = typer.Option(None, help="TSDF voxel [mm] (default: 0.6 * range / focal)."),
    onto_views: bool = typer.Option(
        False, "--onto-views", help="Move the fused surface onto the views' own points (each vertex along its normal "
        "to the median of the points within 2 voxels of it): tighter surfaces, and thin rims without the fattening "
        "of the TSDF's truncation band; the scale then follows what the depth itself reads "
        "(docs/history/object-models.md, 'Session 43')."),
    max_mm: float = typer.Option(2500.0, help="Farthest depth kept [mm]."),
    global_adjust: bool = typer.Option(True, "--global-adjust/--no-global-adjust",
                                       help="Refine all poses jointly after the pose graph (multi-view ICP)."),
    depth_gain: bool = typer.Option(False, "--depth-gain/--no-depth-gain",
                                    help="Let the global adjustment estimate a depth gain g (z -> z + g (z - z_ref)): the "
                                    "range-dependent residual a few-station depth calibration leaves over the object's depth. "
                                    "Off by default: the views rarely determine it and depth noise biases it."),
    rig: Path | None = typer.Option(None, "--rig", help="rig.json (tofmetry calibrate rig): the scan holds one capture per "
                                    "sensor, views/<sensor name>/; they are fused at the rig's poses (no registration) "
                                    "into a model in the rig frame (sensor 0's camera frame)."),
    sensor_calibration: list[str] | None = typer.Option(
        None, "--sensor-calibration", help="With --rig: NAME=FILE, the depth calibration of sensor NAME (repeatable; "
        "sensors without one use raw depth)."),
    color: bool = typer.Option(True, "--color/--no-color", help="Colour the model from the views' colour frames when "
                               "they have them (occlusion-aware: points no colour camera sees get no colour, flagged "
                               "'colored' 0 in the PLYs)."),
    turntable_step: float | None = typer.Option(
        None, "--turntable-step", help="The views were taken on a turntable turning by this step "
        "[deg] between successive views (name order, either sense): only registrations that turn by the declared "
        "steps (within 5 deg) are accepted, which removes the turned-over matches of thin or symmetric objects; "
        "where none passes, the step itself links the views."),
    turntable_accuracy: float = typer.Option(
        1.0, "--turntable-accuracy", help="How accurately the turntable turns by its step [deg] (manual marks ~1, a "
        "stepper motor ~0.1): views linked by the step alone are this accurate; above 0.5 deg the run is flagged."),
    mat: Path | None = typer.Option(
        None, "--mat", help="The mat.json of the printed dot mat the object stood on (tofmetry mat): each view is "
        "placed on the mat on its own (no chain of pairwise registrations: any shape, a vase of revolution or a thin "
        "plaque as well as a bust), the joint fit refines the placements, and the model comes out in the mat's frame."),
    plan: Path | None = typer.Option(
        None, "--plan", help="A plan.json (tofmetry plan): the views as registered are set beside the views it asked "
        "for, both predicted on its object size (written to poses.json as diagnostics.plan). No reference needed; "
        "the completeness achieved: tofmetry evaluate --poses poses.json --plan plan.json."),
    force: bool = typer.Option(False, "--force", help="Replace an existing output folder."),
    allow_unreliable: bool = typer.Option(
        False, "--allow-unreliable", help="Exit 0 even when the pose-graph consistency gate flags the registration "
        "unreliable (the outputs are written and flagged in poses.json either way; without this option the exit code is 3)."),
) -> None:
    """Automatic 3D model of an object from several views: segment, register (pose graph), fuse (TSDF), mesh."""
    from tofmetry.io.mat_json import read_mat
    from tofmetry.pipelines.paths import refuse_existing
    from tofmetry.pipelines.plan import read_plan
    from tofmetry.pipelines.reconstruct import reconstruct_scan
    from tofmetry.reconstruct import ReconstructionConfig

    if rig is not None:
        if calibration is not None or amplitude_reference is not None:
            raise InputError("--rig: pass the depth calibrations per sensor (--sensor-calibration NAME=FILE), not "
                             "--calibration; --amplitude-reference is not available with --rig")
        if no_calibration == bool(sensor_calibration):
            raise InputError("--rig: pass either --sensor-calibration NAME=FILE (repeatable) or --no-calibration (raw "
                             "depth), not both / not neither")
    elif sensor_calibration:
        raise InputError("--sensor-calibration needs --rig (a single sensor's scan takes --calibration FILE)")
    elif (calibration is None) == (not no_calibration):
        raise InputError("pass either --calibration FILE or --no-calibration (raw depth), not both / not neither")
    if amplitude_board and amplitude_k is not None:
        raise InputError("pass either --amplitude-k K or --amplitude-board CAPTURE (k measured), not both")
    if amplitude_board and (amplitude_reference is None or rig is not None):
        raise InputError("--amplitude-board needs --amplitude-reference WALL (the white amplitude per pixel) and is "
                         "not available with --rig")
    if plan is not None and rig is not None:
        raise InputError("--plan is not available with --rig (the rig's sensors stand where the rig holds them)")
    plan_doc = read_plan(plan) if plan is not None else None  # a bad plan.json fails before the reconstruction
    if mat is not None and (rig is not None or turntable_step is not None):
        raise InputError("--mat places each view on the mat: it does not go with --rig or --turntable-step")
    mat_doc = read_mat(mat) if mat is not None else None
    refuse_existing(output, force)
    cfg = ReconstructionConfig()
    cfg.segment.keep_all = keep_all
    cfg.fusion.poisson = poisson
    cfg.fusion.voxel_mm = voxel_mm
    cfg.fusion.refine_radius_voxels = 2.0 if onto_views else None
    cfg.preprocess.max_mm = max_mm
    if amplitude_k is not None:
        cfg.preprocess.amplitude_k_mm_per_ln = amplitude_k
    cfg.registration.global_adjust = global_adjust
    cfg.registration.estimate_depth_gain = depth_gain
    if turntable_step is not None:
        if not 0.0 < turntable_step < 360.0:
            raise InputError(f"--turntable-step: expected a step between 0 and 360 deg (exclusive), found {turntable_step}")
        cfg.registration.turntable_step_deg = turntable_step
        if not 0.0 < turntable_accuracy <= 90.0:
            raise InputError(f"--turntable-accuracy: expected an accuracy above 0 and at most 90 deg, found {turntable_accuracy}")
        cfg.registration.turntable_accuracy_deg = turntable_accuracy
    cfg.color = color
    if mat_doc is not None:
        cfg.registration.mat = mat_doc.to_dict()
    if rig is not None:
        _reconstruct_rig(scan_dir, rig, sensor_calibration or [], output, cfg, force, allow_unreliable)
        return
    console.print(f"scan {scan_dir}; calibration: {calibration or 'none (raw depth)'}")
    res = reconstruct_scan(scan_dir, calibration, output, config=cfg, amplitude_wall=amplitude_reference,
                           amplitude_max_mm=amplitude_max_mm, amplitude_boards=amplitude_board, force=force,
                           progress=progress, plan=plan_doc)
    _print_amplitude_slope(res.diagnostics.get("amplitude_slope"))
    console.print(f"{len(res.names)} views: {', '.join(res.names)}")
    t = Table(title="registration edges (fitness = matched share of the object points the other camera could see)")
    for col in ("source", "target", "method", "fitness", "RMSE [mm]", "seen-through", "kept", "resid [deg]",
                "resid [mm]", "verdict"):
        t.add_column(col, justify="right")
    for e in res.edges:
        if e["accepted"]:
            t.add_row(e["source"], e["target"], e["method"], f"{e['fitness']:.3f}", f"{e['inlier_rmse_mm']:.2f}",
                      f"{e.get('see_through', 0.0):.1%}", "yes" if e["kept"] else "pruned",
                      _figure(e.get("residual_rot_deg"), 3), _figure(e.get("residual_trans_mm"), 2), e.get("verdict", ""))
    console.print(t)
    rel = res.diagnostics.get("reliability") or {}
    for e in res.edges:
        if not e["accepted"]:
            console.print(f"edge {e['source']}->{e['target']}: {e.get('verdict', 'rejected')}: {e.get('reason', '')}")
    _print_mat(res.diagnostics.get("mat"), rel.get("views") or {}, (res.diagnostics.get("scale") or {}).get("mat_pattern"),
               res.diagnostics.get("mat_depth_tilt"), res.diagnostics.get("mat_scale_hold"),
               res.diagnostics.get("mat_range_offset"))
    tt = res.diagnostics.get("turntable")
    if tt:
        stepped = [f"{a}->{b} ({how})" for a, b, how in tt["bridged"]]
        console.print(f"turntable: axis fitted to {tt['n_registrations']} registrations (their turns within "
                      f"{tt['residual_deg']:.2f} deg of the declared steps); linked again from the declared step: "
                      f"{', '.join(stepped) or 'none needed'}")
    sel = (res.diagnostics.get("consistency") or {}).get("selection") or {}
    if sel.get("changed") or sel.get("dropped"):
        console.print(f"multi-view selection: alternative hypothesis taken for {', '.join(sel.get('changed', [])) or 'none'}; "
                      f"dropped (contradict the other views): {', '.join(sel.get('dropped', [])) or 'none'}")
    if sel.get("spread"):
        console.print("the loops close only within the wider bounds: their error is spread over the edges")
    f = res.diagnostics["fusion"]
    console.print(f"TSDF voxel {f['voxel_mm']:.2f} mm, truncation {f['trunc_mm']:.2f} mm; mesh {len(res.mesh_vertices)} "
                  f"vertices / {len(res.mesh_triangles)} triangles; cloud {len(res.points)} points")
    _print_refined(f.get("refined"))
    _print_colour(res.diagnostics.get("color"))
    adj = res.diagnostics.get("adjustment")
    if adj and "failed" in adj:
        console.print(f"[yellow]global adjustment failed ({adj['failed']}); the pose-graph poses are used[/yellow]")
    elif adj:
        console.print(f"global adjustment: {adj['iterations']} iterations, residual RMS {adj['rms_mm'][-1]:.2f} mm, poses "
                      f"moved up to {max(adj['moved_deg'].values()):.3f} deg / {max(adj['moved_mm'].values()):.2f} mm; "
                      f"depth gain {adj['depth_gain'] * 100:+.3f} % of (z - {adj['z_ref_mm']:.0f} mm): {adj.get('gain_note', '')}")
        cp = adj.get("calibration_pose") or {}
        if cp.get("rot_deg"):
            both = cp.get("with_noise")
            gain = (f" (with a depth gain of +-{cp['gain_sigma_pct']:.2f} % between its stations)"
                    if cp.get("gain_sigma_pct") else "")
            what = (f"the depth calibration's residual{gain} and the views' noise" if both else
                    f"the depth calibration's residual{gain}")
            p = both or cp
            console.print(f"predicted pose accuracy from {what}: worst view "
                          f"{p['rot_deg']['p50']:.2f} / {p['rot_deg']['p90']:.2f} deg, {p['object_mm']['p50']:.1f} / "
                          f"{p['object_mm']['p90']:.1f} mm at the object (p50 / p90 over {cp['n_draws']} draws; "
                          f"the calibration alone {cp['rot_deg']['p90']:.2f} deg / {cp['object_mm']['p90']:.1f} mm at p90)")
        if (adj.get("albedo") or {}).get("used"):
            console.print(f"IR albedo: held the rotation about the vertical the geometry leaves free "
                          f"({adj['albedo']['n']} residuals, scale {adj['albedo']['scale']:.3f})")
        sp = adj.get("support_plane") or {}
        if sp.get("used"):
            st, en = sp["start"], sp["end"]
            off = f"; view(s) {', '.join(map(str, en['off_plane']))} off the others' plane, left out" \
                if en.get("off_plane") else ""
            console.print(f"support planes: {en['n_views']} views held to one plane (+-{sp['sigma_deg']:g} deg, "
                          f"+-{sp['sigma_mm']:g} mm each); spread {st.get('spread_deg', 0):.2f} -> "
                          f"{en.get('spread_deg', 0):.2f} deg{off}")
        amp = adj.get("amplitude_bias") or {}
        if amp.get("k_mm_per_ln") is not None:
            console.print(f"amplitude bias: k = {amp['k_mm_per_ln']:.2f} mm per ln unit ({amp['note']})")
    _print_support_curve(res.diagnostics.get("support_curve"))
    sc = res.diagnostics.get("scale") or {}
    if sc.get("predicted_scale_sigma_pct") is not None:
        console.print(f"scale: predicted uncertainty +-{sc['predicted_scale_sigma_pct']:.2f} % (1 sigma), surface offset "
                      f"+-{sc['predicted_offset_sigma_mm']:.2f} mm ({sc['source']})")
        b = sc.get("budget") or {}
        terms = [(k, b[k]["sigma"]) for k in ("offset", "gain", "amplitude", "poses") if isinstance(b.get(k), dict)]
        if terms and all(math.isfinite(v) for _, v in terms):
            console.print("  on the model's geometry: " + ", ".join(f"{k} +-{100 * v:.3f} %" for k, v in terms)
                          + f"; the closed-form rule +-{sc['rule_scale_sigma_pct']:.3f} %")
    console.print(f"world frame: {(res.diagnostics.get('world') or {}).get('frame', '')}")
    pf = res.diagnostics.get("plan")
    if pf:
        console.print(f"plan: {pf.get('summary') or 'not compared: ' + pf.get('skipped', '')}")
    tm = res.diagnostics["timings_s"]
    console.print(f"wrote {output} in {tm['total_s']:.1f} s (views {tm['views_s']:.1f}, registration "
                  f"{tm['registration_s']:.1f}, adjustment {tm['adjustment_s']:.1f}, support curve "
                  f"{tm['support_curve_s']:.1f}, fusion {tm['fusion_s']:.1f}, meshing {tm['meshing_s']:.1f}"
                  + (f", colour {tm['color_s']:.1f})" if res.diagnostics.get("color") else ")"))
    cons = res.diagnostics.get("consistency") or {}
    if cons.get("cycle_closure_mm") is not None:
        console.print(f"consistency: view circle closes to {cons['cycle_closure_deg']:.2f} deg / {cons['cycle_closure_mm']:.1f} mm "
                      f"({cons['cycle_per_edge_deg']:.2f} deg / {cons['cycle_per_edge_mm']:.1f} mm per edge), worst kept edge "
                      f"residual {cons['max_kept_residual_deg']:.2f} deg / {cons['max_kept_residual_mm']:.1f} mm")
    for w in rel.get("warnings", []):
        console.print(f"[yellow]warning:[/yellow] {w}")
    if not res.diagnostics.get("reliable", True):
        console.print("[bold red]WARNING: registration UNRELIABLE[/bold red] (flagged in poses.json): "
                      + "; ".join(rel.get("reasons", []) or cons.get("reasons", [])))
        console.print("The model was written for inspection; do not use it as a measurement. Typical causes: raw "
                      "(uncalibrated) depth, a nearly symmetric object, too little overlap, a depth calibration that "
                      "warns about its own error.")
        if not allow_unreliable:
            raise typer.Exit(3)


def _print_mat(fixes: dict | None, verdicts: dict, pattern: dict | None = None, tilt: dict | None = None,
               hold: dict | None = None, range_offset: dict | None = None) -> None:
    """The views' placements on the dot mat (``diagnostics.mat``), as a table, the depth tilt its dots
    measured (``diagnostics.mat_depth_tilt``), the depth scale they measure (``diagnostics.scale.mat_pattern``),
    the mat's range error they measure (``diagnostics.mat_range_offset``) and the model's scale they hold
    against the joint fit (``diagnostics.mat_scale_hold``)."""
    if not fixes:
        return
    t = Table(title="views placed on the dot mat (each on its own; dots seen whole / matched to the layout)")
    for col in ("view", "how", "dots", "matched", "RMS [mm]", "+- [deg]", "+- [mm]", "tilt +- [deg]", "size [%]",
                "verdict"):
        t.add_column(col, justify="right")
    for name, f in fixes.items():
        how = f["how"] or ("via " + " + ".join(f["through"]["via"]) if f.get("through") else "not placed")
        size = f.get("pattern_scale_pct", float("nan"))
        ts = f.get("tilt_sigma_deg")
        t.add_row(name, how, str(f["n_dots"]), str(f["n_matched"]), f"{f['rms_mm']:.2f}", f"{f['sigma_deg']:.3f}",
                  f"{f['sigma_mm']:.2f}", _figure(ts, 2),
                  "" if size != size else f"{size:+.2f} +- {f['pattern_scale_sigma_pct']:.2f}",
                  (verdicts.get(name) or {}).get("verdict", ""))
    console.print(t)
    if tilt:
        m, ms, a = tilt["measured_mm"], tilt["measured_sigma_mm"], tilt["applied_mm"]
        console.print(f"the dots measure the depth's tilt across the image: ({m[0]:+.1f}, {m[1]:+.1f}) +- ({ms[0]:.1f}, "
                      f"{ms[1]:.1f}) mm per unit of x/z, y/z ({tilt['n_views']} views); against what the calibration "
                      f"may have left (+-{tilt['prior_sigma_mm']:.1f}), ({a[0]:+.1f}, {a[1]:+.1f}) taken off every view")
    if pattern:
        console.print(f"the dots measure the depth scale at the mat: {pattern['scale_pct']:+.3f} % +- "
                      f"{pattern['sigma_pct']:.3f} % against their printed size ({pattern['views']} views; the "
                      f"calibration's predicted range error and the method allow +-{pattern['allowed_pct']:.2f} %): "
                      + ("consistent" if pattern["consistent"] else "[bold red]NOT consistent[/]"))
    if range_offset:
        console.print(f"the dots' size puts the mat's plane {range_offset['delta_mm']:+.2f} mm +- "
                      f"{range_offset['sigma_mm']:.2f} mm off along the rays ({range_offset['views']} views): "
                      + ("beyond 3 sigma, taken out of every placement" if range_offset.get("applied")
                         else "within 3 sigma, the placements left as they were" if not range_offset["significant"]
                         else "beyond 3 sigma, not taken out (registration.mat_range_from_dots is off)"))
    if hold and hold.get("held_sigma_pct") is not None:
        console.print(f"the mat holds the model's scale: the joint fit moved it {hold['fit_scale_pct']:+.3f} % "
                      f"(+-{hold['fit_sigma_pct']:.3f} %) from the placements (+-{hold['mat_sigma_pct']:.3f} %); "
                      f"{hold['applied_pct']:+.3f} % applied, +-{hold['held_sigma_pct']:.3f} % left")


def _reconstruct_rig(scan_dir: Path, rig: Path, sensor_calibration: list[str], output: Path, cfg, force: bool,
                     allow_unreliable: bool) -> None:
    """``reconstruct --rig``: one capture per sensor fused in the rig frame."""
    from tofmetry.pipelines.reconstruct import reconstruct_rig

    cals = {}
    for item in sensor_calibration:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise InputError(f"--sensor-calibration: expected NAME=FILE, found {item!r}")
        cals[name] = Path(path)
    console.print(f"rig scan {scan_dir}; rig {rig}; depth calibration: "
                  + (", ".join(f"{n} {p}" for n, p in cals.items()) or "none (raw depth)"))
    res = reconstruct_rig(scan_dir, rig, output, calibrations=cals, config=cfg, force=force, progress=progress)
    r = res.diagnostics["rig"]
    t = Table(title=f"sensors placed by the rig (rig frame: {r['rig_frame']})")
    for col in ("sensor", "depth calibration", "rig std [mm]", "rig std [deg]", "predicted at the object [mm]"):
        t.add_column(col, justify="right")
    for s in r["sensors"]:
        t.add_row(s["name"], "yes" if s["calibrated"] else "raw", f"{max(s['translation_std_mm']):.2f}",
                  f"{max(s['rotation_std_deg']):.4f}", f"{s['predicted_displacement_mm']:.2f}")
    console.print(t)
    t = Table(title="rig check: how far ICP moves one view onto the other where they overlap")
    for col in ("views", "overlap", "correction [mm]", "correction [deg]", "median |d| at the rig poses [mm]", "verdict"):
        t.add_column(col, justify="right")
    for e in res.edges:
        med = e["overlap"]["median_abs_mm"]
        t.add_row(f"{e['source']}-{e['target']}", f"{e['fitness']:.0%}", f"{e['correction_mm']:.2f}",
                  f"{e['correction_deg']:.3f}", "-" if med is None else f"{med:.2f}", e["verdict"])
    console.print(t)
    for w in res.diagnostics["reliability"]["warnings"]:
        console.print(f"[yellow]warning:[/yellow] {w}")
    f = res.diagnostics["fusion"]
    console.print(f"TSDF voxel {f['voxel_mm']:.2f} mm, truncation {f['trunc_mm']:.2f} mm; mesh {len(res.mesh_vertices)} "
                  f"vertices / {len(res.mesh_triangles)} triangles; cloud {len(res.points)} points")
    _print_colour(res.diagnostics.get("color"))
    console.print(f"world frame: {res.diagnostics['world']['frame']}")
    console.print(f"wrote {output} in {res.diagnostics['timings_s']['total_s']:.1f} s")
    if not res.diagnostics["reliable"]:
        console.print("[bold red]WARNING: the rig's calibration does not fit these captures[/bold red] (flagged in "
                      "poses.json): " + "; ".join(res.diagnostics["reliability"]["reasons"]))
        if not allow_unreliable:
            raise typer.Exit(3)


def _print_support_curve(sc: dict | None) -> None:
    """The range curve the flat support showed (``diagnostics.support_curve``), one or two lines."""
    if not sc:
        return
    if not sc.get("applied"):
        console.print(f"support curve: not applied ({sc.get('why', '')})")
        return
    lo, hi = sc["span_mm"]
    if sc.get("anchored") and not sc.get("levelled", True):
        console.print(f"support curve: the mat, seen over {lo:.0f}-{hi:.0f} mm in {sc['n_views']} views and placed by its "
                      f"dots alone in {sc['n_anchors']}, shows a range error of up to {sc['max_abs_mm']:.2f} mm; removed "
                      f"before the views were placed, it moved the object's depths by {sc['object_offset_mm']:+.2f} mm "
                      f"+- {sc['object_offset_sigma_mm']:.2f} mm and their gain by {sc['object_gain_pct']:+.3f} % "
                      f"+- {sc['object_gain_sigma_pct']:.3f} %")
        return
    console.print(f"support curve: the support, seen over {lo:.0f}-{hi:.0f} mm in {sc['n_views']} views, is not flat by "
                  f"up to {sc['max_abs_mm']:.2f} mm ({sc['flatness_before_mm']:.2f} -> {sc['residual_mm']:.2f} mm RMS with "
                  f"the curve); removed before the fusion, it changed the gain over the object's depths by "
                  f"{sc['object_gain_pct']:+.3f} % +- {sc['object_gain_sigma_pct']:.3f} %"
                  + (f" (its gain and curvature from the planes the mat's dots gave {sc['n_anchors']} views)"
                     if sc.get("anchored") else ""))


def _print_amplitude_slope(slope: dict | None) -> None:
    if not slope:
        return
    per = "; ".join(f"{Path(b['path']).name} at {b['distance_mm'] or float('nan'):.0f} mm: {b['k_mm_per_ln']:.2f} +-{b['se_mm_per_ln']:.2f}"
                    for b in slope["boards"])
    console.print(f"amplitude coefficient measured on {len(slope['boards'])} board(s): k = {slope['k_mm_per_ln']:.2f} "
                  f"+-{slope['sigma_mm_per_ln']:.2f} mm per ln unit ({per})")
    for n in slope["notes"]:
        console.print(f"[yellow]  {n}[/yellow]")


def _print_refined(r: dict | None) -> None:
    """The move of the fused surface onto the views' points (``--onto-views``), when it ran."""
    if r:
        med = "n/a" if r["move_mm_p50"] is None else f"{r['move_mm_p50']:+.3f}"
        p90 = "n/a" if r["move_abs_mm_p90"] is None else f"{r['move_abs_mm_p90']:.3f}"
        console.print(f"surface moved onto the views' points: {100 * r['share_moved']:.0f} % of the vertices, median "
                      f"move {med} mm, p90 |move| {p90} mm (cylinders of {r['radius_mm']:.2f} mm, +-{r['band_mm']:.2f} mm)")


def _print_colour(col: dict | None) -> None:
    """The share of the model coloured (nothing without colour frames)."""
    if not col:
        return
    if "skipped" in col:
        console.print(f"[yellow]colour: not applied ({col['skipped']})[/yellow]")
        return
    for key, what in (("points", "cloud"), ("mesh", "mesh"), ("poisson", "Poisson mesh")):
        if key in col:
            c = col[key]
            console.print(f"colour ({what}): {c['share_colored']:.1%} coloured ({c['colored']} of {c['points']}; "
                          f"{c['uncolored']} seen by no colour camera get no colour), median "
                          f"{c['views_per_colored_point_median']:.0f} views per point")
    console.print(f"colour from {col['views_with_color']} views: " + ", ".join(
        f"{n} {v['share_colored']:.0%}" if "share_colored" in v else f"{n} ({v['skipped']})" for n, v in col["views"].items()))


def _parse_floats(text: str, what: str, n: int | None = None) -> tuple[float, ...]:
    try:
        vals = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise InputError(f"{what}: expected comma-separated numbers, found {text!r}") from None
    if not vals or (n is not None and len(vals) != n):
        raise InputError(f"{what}: expected {n or 'some'} comma-separated numbers, found {text!r}")
    return vals


def evaluate(
    model: Path = typer.Argument(..., help="Model: PLY/OBJ/STL cloud or mesh [m]."),
    reference: Path = typer.Option(..., "--reference", help="Reference: PLY/OBJ/STL mesh (or cloud) [m]."),
    output: Path = typer.Option(..., "-o", "--output", help="Output folder (metrics.json, PNGs, deviation.ply)."),
    align: bool = typer.Option(False, "--align", help="Coarse FPFH/RANSAC alignment before the fine ICP."),
    no_icp: bool = typer.Option(False, "--no-icp", help="Compare as given (no ICP)."),
    init_transform: Path | None = typer.Option(None, "--init-transform", help="JSON 4x4 model->reference initial transform."),
    thresholds_mm: str = typer.Option("1,2,5,10", "--thresholds-mm", help="Thresholds for 'share within', completeness, F-score [mm]."),
    edge_trim_mm: float = typer.Option(3.0, help="Exclude model points within this of a sharp/boundary reference edge [mm] (0 = off)."),
    exclude_normal: str | None = typer.Option(None, help="x,y,z: leave reference surface facing this way (e.g. the face on "
                                                 "the ground: 0,0,-1) out of completeness."),
    color_scale_mm: float = typer.Option(5.0, help="Deviation colour scale +-[mm] (diverging, saturating)."),
    poses: Path | None = typer.Option(None, "--poses", help="The reconstruction's poses.json: also report completeness "
                                         "over the reference surface the registered cameras could see (frustum, working "
                                         "range, incidence, occlusion)."),
    plan: Path | None = typer.Option(None, "--plan", help="A plan.json (tofmetry plan): its predicted completeness "
                                     "for the views as taken beside the completeness achieved (needs --poses); "
                                     "written to plan_check.json."),
    force: bool = typer.Option(False, "--force", help="Replace an existing, non-empty output folder."),
) -> None:
    """Accuracy of a model against a reference: align, signed distances, statistics, completeness, figures."""
    from tofmetry.evaluate import EvaluationConfig
    from tofmetry.pipelines.evaluate import evaluate_files

    cfg = EvaluationConfig(
        align=align, icp=not no_icp, thresholds_mm=_parse_floats(thresholds_mm, "--thresholds-mm"),
        edge_trim_mm=edge_trim_mm, color_scale_mm=color_scale_mm,
        exclude_normal=None if exclude_normal is None else _parse_floats(exclude_normal, "--exclude-normal", 3))
    with progress("evaluating", None):
        run = evaluate_files(model, reference, output, config=cfg, init_transform=init_transform, poses=poses,
                             plan=plan, force=force)
    res = run.result
    s, st = res.stats_all, res.stats_trimmed
    t = Table(title=f"{model.name} vs {reference.name} ({res.comparison})")
    for col in ("", "mean |d|", "std", "RMS", "p95 |d|", "max |d|", "<= 5 mm"):
        t.add_column(col, justify="right")
    for name, x in (("all", s), ("edge-trimmed", st)):
        t.add_row(name, f"{x.mean_abs_mm:.2f}", f"{x.std_signed_mm:.2f}", f"{x.rms_mm:.2f}",
                  f"{x.percentiles_abs_mm['p95']:.2f}", f"{x.max_abs_mm:.2f}", f"{x.share_within.get('5', float('nan')):.1%}")
    console.print(t)
    c5 = res.completeness.get("5")
    if c5:
        console.print(f"completeness at 5 mm {c5['completeness']:.1%}, F-score {c5['fscore']:.3f}")
    if res.completeness_observed is not None and res.completeness_observed.get("5"):
        console.print(f"observed-surface completeness at 5 mm {res.completeness_observed['5']['completeness']:.1%} "
                      f"({res.observed['observed_share']:.1%} of the reference surface seen by a registered camera)")
    _print_scale(res.scale)
    if res.alignment is not None:
        a = res.alignment
        console.print(f"alignment: fitness {a.fitness:.3f}, inlier RMSE {a.inlier_rmse_mm:.2f} mm, mean misfit "
                      f"{a.misfit_mm:.2f} mm")
        if a.ambiguous:
            console.print(f"[yellow]warning: the alignment is ambiguous: {a.runner_up['deg']:.1f} deg / "
                          f"{a.runner_up['mm']:.0f} mm away the model fits about as well (mean misfit "
                          f"{a.runner_up['misfit_mm']:.2f} mm); the deviations above may be the alignment's. "
                          "Give --poses (the support plane then fixes the up axis) or --init-transform[/yellow]")
    if run.plan is not None:
        console.print(f"plan: {run.plan['summary']}")
    console.print(f"wrote {output}")


def _print_scale(sc: dict | None) -> None:
    """One line: the model's scale against the reference (evaluate's ``scale``), or why there is none."""
    from tofmetry.pipelines.evaluate import scale_summary

    if sc:
        line = scale_summary(sc)
        warn = "error" in sc or sc.get("within_2_predicted_sigma") is False
        console.print(f"[yellow]{line}[/yellow]" if warn else line)


def plan(
    output: Path = typer.Option(..., "-o", "--output", help="plan.json to write."),
    size: str | None = typer.Option(None, "--size", help="W,D,H: the object's rough size [m]."),
    mesh: Path | None = typer.Option(None, "--mesh", help="A mesh of the object (PLY/OBJ/STL)."),
    mesh_scale: float = typer.Option(1.0, "--mesh-scale", help="Factor from the mesh's units to metres."),
    mesh_up: str = typer.Option("0,0,1", "--mesh-up", help="x,y,z: the mesh's up axis."),
    first_view: Path | None = typer.Option(None, "--first-view", help="A capture of the object on its support."),
    calibration: Path | None = typer.Option(None, "--calibration", help="Depth calibration (intrinsics, predicted error)."),
    distance: float | None = typer.Option(None, "--distance", help="Distance of the views from the object centre [m]."),
    target: float = typer.Option(0.9, "--target", help="Completeness the scan should reach (0-1); views are proposed "
                                 "that are predicted to reach it plus 2.8 points, the prediction's p95 over-estimate."),
    frames: int = typer.Option(10, "--frames", help="Frames per view."),
    views: str | None = typer.Option(None, "--views", help="Also predict these views: ring:N:ELEV[:M:ELEV2] (N views at "
                                     "ELEV deg, plus M zenithal views at ELEV2)."),
    complete_views: bool = typer.Option(False, "--complete", help="Propose the views to add to --views so that "
                                        "they reach --target (each placed where its azimuth falls in the loop)."),
    force: bool = typer.Option(False, "--force", help="Replace an existing plan.json."),
) -> None:
    """Acquisition planning: predicted completeness and accuracy of views around an object, and the views to take."""
    from tofmetry.pipelines.plan import plan_acquisition

    sz = None if size is None else _parse_floats(size, "--size", 3)
    run = plan_acquisition(size=sz, mesh=mesh, mesh_scale=mesh_scale, mesh_up=_parse_floats(mesh_up, "--mesh-up", 3),
                           first_view=first_view, calibration=calibration, distance_m=distance, target=target,
                           n_frames=frames, views=views, complete_views=complete_views, output=output, force=force)
    ext = run.object.extent_m
    console.print(f"object ({run.object.source}): {ext[0]:.3f} x {ext[1]:.3f} x {ext[2]:.3f} m; views at "
                  f"{run.settings['distance_m']:.2f} m"
                  + (f" ({run.settings['distance_note']})" if run.settings.get("distance_note") else ""))
    t = Table(title="candidate view sets (best first)")
    for col in ("views", "n", "completeness", "range", "min overlap", "mean |d| [mm]", "p95 [mm]"):
        t.add_column(col, justify="right")
    for c in run.candidates[:10]:
        p = c.prediction
        t.add_row(c.name, str(p.n_views), f"{p.completeness:.1%}", _span(p), f"{p.min_overlap:.2f}",
                  f"{p.mean_abs_mm:.2f}", f"{p.p95_mm:.2f}")
    console.print(t)
    if run.asked is not None:
        p = run.asked.prediction
        console.print(f"asked {run.asked.name}: completeness {p.completeness:.1%} ({_span(p)}), smallest overlap {p.min_overlap:.2f}, "
                      f"mean |d| {p.mean_abs_mm:.2f} mm")
    if run.completed is not None:
        p = run.completed.prediction
        added = run.completed.params["added_at"]
        console.print(f"completed: {len(added)} view(s) added (at positions {', '.join(map(str, added)) or '-'} of "
                      f"{p.n_views}): completeness {p.completeness:.1%} ({_span(p)}), smallest overlap {p.min_overlap:.2f}")
    for w in run.settings.get("warnings", []):
        console.print(f"[yellow]{w}[/yellow]")
    if run.proposal is None:
        console.print(f"[yellow]no candidate is predicted to reach {run.settings['aimed_at']:.1%} (the target "
                      f"{target:.0%} plus the prediction's p95 over-estimate) with enough overlap; the best is listed "
                      "first[/yellow]")
    else:
        p = run.proposal.prediction
        console.print(f"proposal: {run.proposal.name}: predicted completeness {p.completeness:.1%} ({_span(p)}; "
                      f"aimed at {run.settings['aimed_at']:.1%} so that the scan reaches {target:.0%} on about 95 % of "
                      f"runs), mean |d| {p.mean_abs_mm:.2f} mm")
    console.print(f"wrote {output}")


def _figure(x, digits: int) -> str:
    """``x`` with ``digits`` decimals; empty where there is none (None or NaN: an edge the mat placed has
    no pose-graph residual)."""
    return "" if x is None or x != x else f"{x:.{digits}f}"


def _span(p) -> str:
    """A prediction's completeness range: every grazing surface lost - every one kept."""
    lo, hi = p.completeness_range
    return f"{lo:.0%}-{hi:.0%}"


_PAPER_M = {"a1": (0.594, 0.841), "a2": (0.42, 0.594), "a3": (0.297, 0.42)}


def mat(
    output: Path = typer.Option(..., "-o", "--output", help="Output folder (mat.png to print, mat.json to reconstruct with)."),
    seed: int = typer.Option(0, "--seed", help="The dot layout's seed (another seed, another mat)."),
    paper: str = typer.Option("a1", "--paper", help="Sheet size: a1 (0.594 x 0.841 m), a2 or a3 (for objects up to "
                              "about a third of the sheet's width)."),
    dpi: float = typer.Option(150.0, "--dpi", help="Resolution of mat.png [dots per inch]."),
    force: bool = typer.Option(False, "--force", help="Replace an existing output folder."),
) -> None:
    """A dot mat to print and lay under the object: `reconstruct --mat mat.json` places every view on it.

    The study registered its views on flat targets around the object (2 cm, picked by hand); the mat is
    such a target, found automatically in the IR amplitude. Print mat.png at 100 % on matt paper (laser
    toner is dark in the near infrared) and keep it flat; the object stands in its middle."""
    from tofmetry._shared.dot_mat import DotMat, dot_mat_image
    from tofmetry.io import atomic_dir
    from tofmetry.io.images import write_png
    from tofmetry.io.mat_json import write_mat
    from tofmetry.pipelines.paths import refuse_existing

    if paper.lower() not in _PAPER_M:
        raise InputError(f"--paper: expected one of {sorted(_PAPER_M)}, found {paper!r}")
    if not 30.0 <= dpi <= 1200.0:
        raise InputError(f"--dpi: expected 30-1200 dots per inch, found {dpi}")
    refuse_existing(output, force)
    m = DotMat(seed=seed, size_m=_PAPER_M[paper.lower()])
    with atomic_dir(output, force=force) as tmp:
        write_png(tmp / "mat.png", dot_mat_image(m, dpi))
        write_mat(tmp / "mat.json", m, "mat.png", dpi)
    n = len(m.dots()[0])
    console.print(f"mat {seed}: {n} dots on {paper.upper()} ({1e3 * m.size_m[0]:.0f} x {1e3 * m.size_m[1]:.0f} mm); "
                  f"print {output / 'mat.png'} at 100 % ({dpi:g} dpi); reconstruct with --mat {output / 'mat.json'}")


def register(app: typer.Typer) -> None:
    """Add this module's commands to the main app."""
    app.command("reconstruct")(reconstruct)
    app.command("mat")(mat)
    app.command("evaluate")(evaluate)
    app.command("plan")(plan)
