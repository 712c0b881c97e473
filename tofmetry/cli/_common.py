"""Small helpers shared by CLI modules: console, progress, intrinsics option."""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

#: Width of the console when it is not a terminal (a pipe, a file, a CI log) and ``COLUMNS`` is unset:
#: Rich would use 80 and cut the wider tables (the station tables have up to 13 columns).
NON_TERMINAL_WIDTH = 240


def _console() -> Console:
    c = Console(stderr=True)
    if not c.is_terminal and not os.environ.get("COLUMNS"):
        c = Console(stderr=True, width=NON_TERMINAL_WIDTH)
    return c


console = _console()


@contextmanager
def progress(description: str, total: int | None) -> Iterator:
    """A rich progress bar; yields ``advance(n=1)``."""
    with Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
        TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=False,
    ) as prog:
        task = prog.add_task(description, total=total)
        yield lambda n=1: prog.advance(task, n)


def refuse_existing(paths, force: bool) -> None:
    """Refuse to start a command whose outputs exist (a file, or a non-empty folder) unless ``force``.

    Checked before any work, for every file the command would write (side files such as
    ``calib_ir.yaml`` and report folders included), so nothing is replaced without ``--force``.
    """
    from tofmetry.errors import InputError

    found = [Path(p) for p in paths if p is not None and Path(p).exists()
             and (not Path(p).is_dir() or any(Path(p).iterdir()))]
    if found and not force:
        raise InputError(f"output{'s' if len(found) > 1 else ''} {', '.join(str(p) for p in found)} already "
                         f"exist{'' if len(found) > 1 else 's'}; refusing to overwrite (pass --force to replace "
                         f"{'them' if len(found) > 1 else 'it'})")


def print_plausibility(record: dict | None) -> None:
    """Say loudly that implausible results were accepted (``--accept-implausible``)."""
    if record and record.get("accepted"):
        for f in record.get("findings", []):
            console.print(f"[bold red]implausible, accepted with --accept-implausible:[/] {escape(f)}", highlight=False)


ACCEPT_IMPLAUSIBLE_HELP = ("Write the result even when a plausibility gate fails (a value far outside what the sensor "
                           "can be); the outputs and the report record that it was accepted.")


def load_intrinsics_option(path: Path | None):
    """Read ``--intrinsics`` if given (None otherwise)."""
    if path is None:
        return None
    from tofmetry.io import read_intrinsics

    return read_intrinsics(path)


#: Help of the ``--board`` option of the commands that take a checkerboard or a ChArUco board.
BOARD_HELP = "Inner corners COLSxROWS, e.g. 9x6, or 'charuco' (with --squares, --marker-mm, --dictionary)."
SQUARES_HELP = "ChArUco: squares COLSxROWS (not inner corners)."
MARKER_HELP = "ChArUco: marker side [mm]."
DICTIONARY_HELP = "ChArUco: OpenCV ArUco dictionary."


def parse_board(board: str, square_mm: float, squares: str, marker_mm: float, dictionary: str):
    """``(BoardSpec of the inner corners, CharucoBoard or None)`` from the board options of
    ``calibrate intrinsics``, ``calibrate stereo`` and ``calibrate rig``."""
    from tofmetry.io.board_dataset import BoardSpec

    if board.strip().lower() != "charuco":
        return BoardSpec.parse(board, square_mm), None
    from tofmetry.calibrate import CharucoBoard

    sq = BoardSpec.parse(squares, square_mm)
    ch = CharucoBoard(sq.size[0], sq.size[1], sq.square_mm, float(marker_mm), dictionary)
    return BoardSpec.parse(f"{ch.inner[0]}x{ch.inner[1]}", square_mm), ch
