"""Where outputs may go: never into an input (the pipelines' and the CLI's shared check)."""

from __future__ import annotations

import os
from pathlib import Path

from tofmetry.errors import InputError


def refuse_inside_inputs(output: str | os.PathLike, *inputs: str | os.PathLike) -> None:
    """Refuse an output that is one of the input folders or lies inside one (inputs are never modified).

    Raises
    ------
    InputError
        Naming the output as given, its absolute path and the input folder it would modify.
    """
    out = Path(output).resolve()
    for inp in inputs:
        if inp is None:
            continue
        src = Path(inp).resolve()
        if out == src or src in out.parents:
            where = "is the input folder" if out == src else "lies inside the input folder"
            raise InputError(f"output {output} ({out}) {where} {src}; write it outside the input "
                             "(tofmetry never modifies its inputs)")


def refuse_existing(output: str | os.PathLike, force: bool, option: str = "--force") -> None:
    """Refuse to write into an output file or non-empty folder that exists, unless ``force``.

    Raises
    ------
    InputError
        Naming the output and the option (``option``) that replaces it.
    """
    out = Path(output)
    if force or not out.exists():
        return
    if out.is_dir() and not any(out.iterdir()):
        return
    raise InputError(f"output {output} already exists; pass {option} to replace it")
