"""Board-mode output of ``calibrate depth`` and ``calibrate validate`` (a board dataset: ``board.json`` +
``poses/``): the model selection, blocked validation, prediction and judged poses, printed."""

from __future__ import annotations

from pathlib import Path

from tofmetry.cli._common import console


def _print_board_run(run) -> None:
    """Board mode: model selection, blocked validation, prediction and judged poses (board-specific)."""
    from rich.table import Table

    from tofmetry.pipelines.board import judged_table

    fit = run.fit
    b = fit["board"]
    if b.get("type") == "charuco":
        partial = sum(0 < r.get("n_corners", 0) < b["cols"] * b["rows"] for r in run.rows)
        what = (f"ChArUco board {b['squares_x']}x{b['squares_y']} squares of {b['square_mm']} mm ({b['marker_mm']} mm "
                f"{b['dictionary']} markers), {partial} partial view(s)")
    else:
        what = f"board {b['cols']}x{b['rows']} inner corners, {b['square_mm']} mm"
    console.print(f"{what}; {fit['n_poses']} poses used; {fit['n_dark_only_views']} with saturated white squares "
                  f"({'used through their dark squares' if fit['use_dark_views'] else 'not used'}); "
                  f"intrinsics: {run.intrinsics_source}")
    ifit = fit["intrinsics_fit"]
    if "cv_rms_px" in ifit:
        console.print(f"intrinsics held-out reprojection ({ifit['k']}-fold): {ifit['cv_rms_px']:.3f} px")
    console.print(f"corner grids: noise {ifit['corner_noise_px']:.3f} px, rejected above {ifit['grid_threshold_px']:.2f} px")
    designs = [d for d in ("time", "range", "region") if d in fit["validation"]]
    t = Table(title="model selection on blocked folds: held-out RMS [mm] (time: blocks of poses in recording order, "
                    "range: bins of range, region: image regions left out)")
    for col in ("candidate", *designs, "score", "chosen"):
        t.add_column(col, justify="right")
    for r in fit["selection"]:
        t.add_row(r["name"] + (" + dark-square views" if r["use_dark_views"] else ""),
                  *[f"{r[f'{d}_rms_mm']:.2f}" for d in designs], f"{r.get('score_mm', float('nan')):.2f}",
                  "*" if r.get("chosen") else "")
    console.print(t)
    console.print(f"model: {fit['model_description']}")
    t = Table(title="held-out board-plane error of the chosen model, white squares [mm]")
    for col in ("validation", "mean", "RMS", "P95 |e|", "n"):
        t.add_column(col, justify="right")
    for d, st in fit["validation"].items():
        t.add_row(st.get("label", f"{d} (blocked)"), f"{st['mean_mm']:+.2f}", f"{st['rms_mm']:.2f}",
                  f"{st['p95_abs_mm']:.2f}", str(st["n"]))
    console.print(t)
    p = fit.get("prediction") or {}
    if p:
        console.print(f"predicted error on {p['n_new_views']} new poses (time blocks, 90 % interval): RMS "
                      f"{p['rms_mm']:.2f} [{p['rms_mm_interval'][0]:.2f}, {p['rms_mm_interval'][1]:.2f}], P95 |e| "
                      f"{p['p95_abs_mm']:.2f} [{p['p95_abs_mm_interval'][0]:.2f}, {p['p95_abs_mm_interval'][1]:.2f}], "
                      f"mean {p['mean_mm']:+.2f} [{p['mean_mm_interval'][0]:+.2f}, {p['mean_mm_interval'][1]:+.2f}] mm")
    j = fit.get("judged")
    if j:
        t = Table(title=f"judged poses {j['poses'][0]}..{j['poses'][-1]} ({j['n_views']} poses, never fitted), "
                        "white squares [mm]")
        for col in ("case", "mean", "RMS", "P95 |e|", "n"):
            t.add_column(col, justify="right")
        for label, st in judged_table(fit):
            t.add_row(label, f"{st['mean_mm']:+.2f}", f"{st['rms_mm']:.2f}", f"{st['p95_abs_mm']:.2f}", str(st["n"]))
        console.print(t)
        jp, m = j.get("prediction") or {}, j["cases"].get("tofmetry", {})
        if jp:
            console.print(f"tofmetry predicted for {jp['n_new_views']} new poses vs measured: RMS "
                          f"[{jp['rms_mm_interval'][0]:.2f}, {jp['rms_mm_interval'][1]:.2f}] vs {m['rms_mm']:.2f}, P95 "
                          f"[{jp['p95_abs_mm_interval'][0]:.2f}, {jp['p95_abs_mm_interval'][1]:.2f}] vs "
                          f"{m['p95_abs_mm']:.2f}, mean [{jp['mean_mm_interval'][0]:+.2f}, "
                          f"{jp['mean_mm_interval'][1]:+.2f}] vs {m['mean_mm']:+.2f} mm")
        o = j["outside"]
        console.print(f"judged pixels outside the training support: {o['range']} beyond the range fitted (clamped), "
                      f"{o['image_cell']} in image cells never covered, {o['cell_and_range_bin']} in cell/100 mm "
                      f"bins without a sample, {o['uncorrected']} outside the calibration's valid range "
                      f"(left uncorrected), of {j['n_samples']}")


def _validate_board(path: Path, cal, poses, intrinsics, output) -> None:
    """``calibrate validate`` on a board dataset (board-specific)."""
    from rich.table import Table

    from tofmetry.io import atomic_write_json
    from tofmetry.pipelines.board import validate_board

    v = validate_board(path, cal, poses=poses, intrinsics=intrinsics)
    for n, why in v["skipped"]:
        console.print(f"[yellow]note:[/] pose {n} not judged: {why}")
    t = Table(title=f"board poses {v['poses'][0]}..{v['poses'][-1]} ({v['n_views']} judged), white squares [mm]")
    for col in ("case", "mean", "RMS", "P95 |e|", "n"):
        t.add_column(col, justify="right")
    for k, st in v["cases"].items():
        t.add_row(k, f"{st['mean_mm']:+.2f}", f"{st['rms_mm']:.2f}", f"{st['p95_abs_mm']:.2f}", str(st["n"]))
    console.print(t)
    if "measured_within_prediction" in v:
        console.print(f"measured within the calibration's predicted 90 % intervals: {v['measured_within_prediction']}")
    if output is not None:
        atomic_write_json(output / "validation.json", v)
        console.print(f"validation written to {output}")
