"""What a new user meets first: --version, units in every --help, wide tables, readable files, clear errors."""

from __future__ import annotations

import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

import tofmetry
from tofmetry.cli import app

runner = CliRunner()
TOFMETRY = [sys.executable, "-m", "tofmetry.cli"]


def _commands():
    """(name path, click command) of every leaf command of the CLI."""
    root = typer.main.get_command(app)
    out = []

    def walk(cmd, path):
        if hasattr(cmd, "commands"):
            for name, sub in cmd.commands.items():
                walk(sub, [*path, name])
        else:
            out.append((path, cmd))

    walk(root, [])
    return out


def _flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def test_version():
    r = runner.invoke(app, ["--version"])
    assert r.exit_code == 0, r.output
    assert tofmetry.__version__ in r.output and "tofmetry" in r.output


@pytest.mark.parametrize("path,cmd", _commands(), ids=lambda x: " ".join(x) if isinstance(x, list) else "")
def test_every_help_keeps_its_units(path, cmd):
    """Every bracketed unit of an option's or argument's help ([mm], [px], [m], [deg] ...) reaches --help."""
    r = runner.invoke(app, [*path, "--help"], env={"COLUMNS": "100"})
    assert r.exit_code == 0, r.output
    shown = _flat(r.output)
    texts = [cmd.help or ""] + [getattr(p, "help", None) or "" for p in cmd.params]
    units = [u for t in texts for u in re.findall(r"\[[^\]\[]{1,40}\]", t)]
    for u in units:
        assert _flat(u) in shown, f"{' '.join(path)} --help lost {u!r}"
    if path in (["calibrate", "intrinsics"],):
        assert "[mm]" in shown


def test_help_units_are_there_at_all():
    """The check above is not vacuous: the CLI documents units in brackets, and the count is sizeable."""
    n = sum(len(re.findall(r"\[(?:mm|px|m|deg|s)\]", (p.help or ""))) for _, c in _commands() for p in c.params
            if getattr(p, "help", None))
    assert n >= 30


def _run(args, cwd=None, **kw):
    env = {**os.environ, "COLUMNS": ""}
    env.pop("COLUMNS")
    return subprocess.run([*TOFMETRY, *map(str, args)], capture_output=True, text=True, cwd=cwd, env=env, **kw)


def test_console_tables_are_not_cut_in_a_pipe(tmp_path):
    """Not a terminal (a pipe, a CI log): the tables keep their columns instead of cutting at 80."""
    from tofmetry.cli._common import console

    assert console.width >= 160 or console.is_terminal
    r = _run(["simulate", "checkerboard", "-o", tmp_path / "b", "--images", "4"])
    assert r.returncode == 0, r.stderr
    r = _run(["calibrate", "intrinsics", tmp_path / "b", "--board", "9x6", "--square-mm", "50", "-o",
              tmp_path / "i.json", "--no-loo"])
    text = r.stderr + r.stdout
    assert "leave-one-out range" in text, text  # the header of the last column, on one line
    assert not any("…" in line for line in text.splitlines()), text


def test_written_files_honour_the_umask(tmp_path):
    """Files are 0644 and folders 0755 under umask 022 (a colleague can read the report)."""
    from tofmetry.io import atomic_dir, atomic_write_bytes, write_capture

    old = os.umask(0o022)
    try:
        f = atomic_write_bytes(tmp_path / "a.json", b"{}")
        with atomic_dir(tmp_path / "d") as d:
            (d / "x").write_bytes(b"1")
        write_capture(tmp_path / "cap", [np.ones((424, 512), np.uint16)])
    finally:
        os.umask(old)
    assert stat.S_IMODE(f.stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o755
    assert stat.S_IMODE((tmp_path / "cap").stat().st_mode) == 0o755
    assert stat.S_IMODE((tmp_path / "cap" / "capture.json").stat().st_mode) == 0o644


def test_cli_outputs_are_readable_by_others(tmp_path):
    r = _run(["simulate", "wall", "-o", tmp_path / "w", "--frames", "2"])
    assert r.returncode == 0, r.stderr
    for p in [tmp_path / "w", *(tmp_path / "w").rglob("*")]:
        mode = stat.S_IMODE(p.stat().st_mode)
        assert mode & 0o044 == 0o044, (p, oct(mode))


def test_error_messages_keep_brackets(tmp_path):
    """An error naming a path or a unit in brackets is printed as is (not eaten as markup)."""
    bad = tmp_path / "[mm] folder"
    r = _run(["info", bad])
    assert r.returncode == 2
    assert "[mm] folder" in r.stderr, r.stderr
