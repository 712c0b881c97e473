"""The ``tofmetry`` command line: a thin typer layer over the library.

Each sub-module owns one group of commands and exposes ``register(app)``; heavy imports
happen inside the commands so that ``tofmetry --help`` stays fast.
"""

from __future__ import annotations

import typer

from tofmetry.cli import assess, calibrate, core, interop, model, simulate, study

app = typer.Typer(
    name="tofmetry",
    help="Time-of-flight RGB-D camera metrology: assess, calibrate, model, evaluate (Kinect v2 first).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

for _mod in (core, simulate, assess, calibrate, model, interop, study):
    _mod.register(app)


def main() -> None:
    """Console entry point: turns library input errors into clean messages (exit 2)."""
    from tofmetry.errors import TofmetryError

    try:
        app()
    except TofmetryError as exc:
        from rich.console import Console

        Console(stderr=True).print(f"[bold red]error:[/] {exc}")
        raise SystemExit(2) from None
