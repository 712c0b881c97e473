"""CLI commands: demo, study."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from tofmetry.cli._common import console


def demo(
    output: Path = typer.Option(Path("demo-out"), "-o", "--output", help="Output folder."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the virtual sensor."),
) -> None:
    """Simulate a wall and an object on the virtual Kinect v2; write point clouds and a summary."""
    from rich.table import Table

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


def register(app: typer.Typer) -> None:
    """Add demo and study."""
    app.command("demo")(demo)
