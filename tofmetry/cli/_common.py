"""Small helpers shared by CLI modules: console, progress, intrinsics option."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

console = Console(stderr=True)


@contextmanager
def progress(description: str, total: int | None) -> Iterator:
    """A rich progress bar; yields ``advance(n=1)``."""
    with Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
        TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=False,
    ) as prog:
        task = prog.add_task(description, total=total)
        yield lambda n=1: prog.advance(task, n)


def load_intrinsics_option(path: Path | None):
    """Read ``--intrinsics`` if given (None otherwise)."""
    if path is None:
        return None
    from tofmetry.io import read_intrinsics

    return read_intrinsics(path)
