"""CLI commands: demo, study."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape
from rich.table import Table

from tofmetry.cli._common import ACCEPT_IMPLAUSIBLE_HELP, console
from tofmetry.errors import InputError


def demo(
    output: Path = typer.Option(Path("demo-out"), "-o", "--output", help="Output folder."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the virtual sensor."),
    force: bool = typer.Option(False, "--force", help="Replace the files of an existing, non-empty output folder."),
) -> None:
    """Simulate a wall and an object on the virtual Kinect v2; write point clouds and a summary."""
    from tofmetry.cli._common import refuse_existing
    from tofmetry.study import run_demo

    refuse_existing([output], force)
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
    force: bool = typer.Option(False, "--force", help="Reuse a non-empty output folder (its files are replaced)."),
    accept_implausible: bool = typer.Option(False, "--accept-implausible", help=ACCEPT_IMPLAUSIBLE_HELP),
) -> None:
    """Run the whole study (assessment → calibration → validation → model → accuracy) with an HTML report.

    Exit code 0 when every stage that had its input ran; 1 when a stage failed (the report is still
    written and names the failure); 2 on bad input."""
    from tofmetry.io import atomic_write_bytes, atomic_write_json
    from tofmetry.report import render_html
    from tofmetry.study import config_to_toml, load_config
    from tofmetry.study.pipeline import StudyPipeline
    from tofmetry.study.summary import build_report, implausible_accepted, report_json

    from tofmetry.pipelines.paths import refuse_inside_inputs

    cfg = load_config(config)
    if data_dir is not None:
        refuse_inside_inputs(output, data_dir)
    if output.exists() and not output.is_dir():
        raise InputError(f"output {output} is a file; the study writes a folder")
    if output.exists() and any(output.iterdir()) and not force:
        done = "a finished study" if (output / "report.html").is_file() else "an unfinished or interrupted run"
        raise InputError(f"output {output} is not empty ({done}); remove the folder {output.resolve()} or pass "
                         "--force to reuse it")
    output.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(output / "study.toml", config_to_toml(cfg).encode())
    icons = {"start": "[cyan]▶[/]", "done": "[green]✔[/]", "skip": "[yellow]–[/]", "fail": "[red]✘[/]", "info": "  [dim]›[/]"}
    pipe = StudyPipeline(data_dir, output, cfg, on_event=lambda k, t: console.print(f"{icons.get(k, '')} {escape(t)}"),
                         accept_implausible=accept_implausible)
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
        color = "red" if o.status == "failed" else "yellow"
        console.print(f"[{color}]{o.status}[/] {escape(o.title)}: {escape(o.note)}", highlight=False)
    for f in implausible_accepted(ctx):
        console.print(f"[bold red]implausible, accepted with --accept-implausible:[/] {escape(f)}", highlight=False)
    console.print(f"report: {output / 'report.html'} ({ctx.total_seconds:.0f} s)")
    failed = [o.key for o in ctx.outcomes.values() if o.status == "failed"]
    if failed:
        console.print(f"[bold red]{len(failed)} stage(s) failed:[/] {', '.join(failed)} (see the report)")
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Add demo and study."""
    app.command("demo")(demo)
    app.command("study")(study)
