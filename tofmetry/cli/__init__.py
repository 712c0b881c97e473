"""The ``tofmetry`` command line: a thin typer layer over the library.

Each sub-module owns one group of commands and exposes ``register(app)``. A command parses its
options, calls one pipeline (:mod:`tofmetry.pipelines`) or library function and prints. The library
layers are imported inside the commands: ``tofmetry --help`` then starts in 0.3 s instead of the
1.7 s (2.8 s with Open3D) that importing every command's pipeline up front costs.

Help texts are plain text (``rich_markup_mode=None`` on every Typer): units are written in
brackets, ``[mm]``, ``[px]``, ``[m]``, which Rich markup would take for tags and drop.
"""

from __future__ import annotations

import typer
from rich.markup import escape

from tofmetry.cli import _interrupt, assess, batch, calibrate, core, interop, model, record, simulate, study
from tofmetry.cli._common import console
from tofmetry.errors import TofmetryError

app = typer.Typer(
    name="tofmetry",
    help="Time-of-flight RGB-D camera metrology: assess, calibrate, model, evaluate (Kinect v2 first).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode=None,
)


def _version(value: bool) -> None:
    if value:
        import tofmetry

        typer.echo(f"tofmetry {tofmetry.__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")) -> None:
    """Time-of-flight RGB-D camera metrology: assess, calibrate, model, evaluate (Kinect v2 first)."""


for _mod in (core, simulate, assess, calibrate, model, interop, study, record, batch):
    _mod.register(app)


def main() -> None:
    """Console entry point: turns library errors into clean messages (exit 2).

    Exit codes: 0 success, 1 a command's own failure (e.g. a study stage failed), 2 bad input or
    an implausible result (:class:`~tofmetry.errors.TofmetryError`), 3 an unreliable registration,
    130 interrupted (Ctrl-C; nothing that looks complete is left behind; it waits for an import
    or a numba compilation under way to finish, :mod:`tofmetry.cli._interrupt`).
    """
    _interrupt.install()
    try:
        app()
    except TofmetryError as exc:
        console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False)
        raise SystemExit(2) from None
    except KeyboardInterrupt:          # typer turns it into exit 130 itself; kept for other entry paths
        _interrupted()
        _interrupt.exit_interrupted(130)
    except SystemExit as exc:
        if exc.code == 130:
            _interrupted()
            _interrupt.exit_interrupted(130)
        raise


def _interrupted() -> None:
    console.print("[yellow]interrupted[/]: no output was completed; partial work, if any, was in hidden "
                  "'.NAME.*.tmp' entries beside the outputs, removed on the way out", highlight=False)
