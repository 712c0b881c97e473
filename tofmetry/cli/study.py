"""CLI commands: demo, study."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from tofmetry.cli._common import console
from tofmetry.errors import InputError


def demo(
    output: Path = typer.Option(Path("demo-out"), "-o", "--output", help="Output folder."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the virtual sensor."),
) -> None:
    """Simulate a wall and an object on the virtual Kinect v2; write point clouds and a summary."""
    from tofmetry.study import run_demo

    summary = run_demo(output, seed=seed, on_step=lambda s: console.print(f"[cyan]›[/] {s}"))
    t = Table(title=f"tofmetry demo → {output}")
    for c in ("cloud", "points", "valid %", "depth range [mm]", "note"):
        t.add_column(c)
    for name in ("wall", "object"):
        e = summary[name]
        note = ""
        if name == "wall":
            note = f"centre bias {e['central_bias_mm']:+.1f} mm, plane residual std {e['plane_residual_std_mm']:.1f} mm"
        t.add_row(e["cloud"], str(e["points"]), f"{100 * e['valid_fraction']:.1f}",
                  f"{e['depth_range_mm'][0]:.0f}–{e['depth_range_mm'][1]:.0f}", note)
    console.print(t)
    console.print(f"summary: {output / 'summary.json'}")


def study(
    data_dir: Optional[Path] = typer.Argument(None, help="Folder with warmup/ noise/ materials/ outdoor/ checkerboard/ "
                                              "wall/ scan/ (each optional) and reference.ply; omit to simulate."),
    output: Path = typer.Option(Path("study-out"), "-o", "--output", help="Output folder (report.html, report.json)."),
    config: Optional[Path] = typer.Option(None, "--config", help="study.toml (pydantic-validated; see OUT/study.toml)."),
    force: bool = typer.Option(False, "--force", help="Reuse a non-empty output folder."),
) -> None:
    """Run the whole study (assessment → calibration → validation → model → accuracy) with an HTML report."""
    from tofmetry.io import atomic_write_bytes, atomic_write_json
    from tofmetry.report import render_html
    from tofmetry.study import config_to_toml, load_config
    from tofmetry.study.pipeline import StudyPipeline
    from tofmetry.study.summary import build_report, report_json

    cfg = load_config(config)
    if output.exists() and any(output.iterdir()) and not force:
        raise InputError(f"output {output} is not empty; pass --force to reuse it")
    output.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(output / "study.toml", config_to_toml(cfg).encode())
    icons = {"start": "[cyan]▶[/]", "done": "[green]✔[/]", "skip": "[yellow]–[/]", "fail": "[red]✘[/]", "info": "  [dim]›[/]"}
    pipe = StudyPipeline(data_dir, output, cfg, on_event=lambda k, t: console.print(f"{icons.get(k, '')} {t}"))
    with console.status("running the study…"):
        ctx = pipe.run()
    report = build_report(ctx)
    atomic_write_bytes(output / "report.html", render_html(report).encode())
    atomic_write_json(output / "report.json", report_json(ctx, report))
    t = Table(title="Side by side with the reference study")
    for c in ("quantity", "tofmetry", "study", "where", "verdict"):
        t.add_column(c)
    for r in report.comparison:
        t.add_row(r.quantity, r.ours, r.study, r.study_ref, r.verdict)
    console.print(t)
    skipped = [o for o in ctx.outcomes.values() if o.status != "ok"]
    for o in skipped:
        console.print(f"[yellow]{o.status}[/] {o.title}: {o.note}")
    console.print(f"report: {output / 'report.html'} ({ctx.total_seconds:.0f} s)")


def register(app: typer.Typer) -> None:
    """Add demo and study."""
    app.command("demo")(demo)
    app.command("study")(study)
