"""CLI command: ``tofmetry batch MANIFEST -o OUT [--scheduler ADDRESS] [--workers N]``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape

from tofmetry.cli._common import console


def batch(manifest: Path = typer.Argument(..., help="Manifest of jobs (.toml, .yaml or .yml)."),
          out: Path = typer.Option(..., "-o", "--out", help="Output folder: one sub-folder per job, summary.json, "
                                   "summary.html. A rerun skips the jobs already complete with unchanged inputs."),
          scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Address of a running Dask scheduler "
                                                  "(e.g. tcp://host:8786); default: start a local cluster."),
          workers: Optional[int] = typer.Option(None, "--workers", help="Worker processes of the local cluster "
                                                "(default: one per core)."),
          ) -> None:
    """Run a manifest of jobs on Dask (calibrate-depth, validate, correct, reconstruct, evaluate, assess, study).

    Exit code 0 when every job is done or skipped, 1 when a job failed (the summary names its error),
    2 on a bad manifest."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from tofmetry.batch import run_batch

    icons = {"ok": "[green]done[/]", "skipped": "[dim]skipped[/]", "failed": "[red]failed[/]"}
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console) as prog:
        task = prog.add_task("jobs", total=None)

        def start(dash: str, n: int) -> None:
            prog.update(task, total=n)
            if dash:
                console.print(f"Dask dashboard: {dash}", highlight=False)

        def done(rec: dict) -> None:
            prog.advance(task)
            err = f": {escape(rec.get('error', ''))}" if rec["status"] == "failed" else ""
            console.print(f"{icons[rec['status']]} {escape(rec['name'])} ({rec.get('seconds', 0):.1f} s){err}",
                          highlight=False)

        run = run_batch(manifest, out, scheduler=scheduler, workers=workers, on_start=start, on_done=done)
    c = run.counts
    console.print(f"{c['ok']} done, {c['skipped']} skipped, {c['failed']} failed in {run.seconds:.1f} s on "
                  f"{run.workers} worker(s); summary: {run.summary_html}", highlight=False)
    if c["failed"]:
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Add ``batch``."""
    app.command("batch")(batch)
