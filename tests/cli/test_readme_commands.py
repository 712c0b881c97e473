"""The README is tested: every command of its workflow blocks runs as written, from another folder.

The commands are taken from the README itself (the ``bash`` blocks of "Two commands" and "Typical
workflows"), so the README cannot drift from the CLI. They run with the set-up's ``.venv/bin`` on the
``PATH``, as the README asks, in a fresh folder that is not the repository.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
README = REPO / "README.md"
BIN = Path(sys.executable).parent


def _section(title: str) -> str:
    text = README.read_text()
    start = text.index(f"## {title}")
    nxt = text.find("\n## ", start + 3)
    return text[start: nxt if nxt > 0 else len(text)]


def _blocks(title: str) -> list[list[str]]:
    """The command lines (comments and blank lines dropped) of each ``bash`` block of a README section."""
    out = []
    for body in re.findall(r"```bash\n(.*?)```", _section(title), re.S):
        lines = [ln.split("  #")[0].rstrip() for ln in body.splitlines()]
        out.append([ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")])
    return out


def _env() -> dict:
    env = dict(os.environ)
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    env.pop("COLUMNS", None)
    return env


def _sh(line: str, cwd: Path, env: dict, timeout: float = 400) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", line], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def test_the_readme_blocks_are_found():
    wf = _blocks("Typical workflows")
    assert len(wf) == 2
    cmds = [c for b in wf for c in b]
    assert sum(c.startswith("tofmetry ") for c in cmds) >= 15
    for needle in ("calibrate validate other-wall", "correct one-wall/capture", "reconstruct scan", "import iai-kinect2"):
        assert any(needle in c for c in cmds), needle
    assert _blocks("Two commands")[0] == ["./scripts/study.sh -o study-out", "./scripts/test.sh"]


@pytest.mark.slow
def test_the_virtual_sensor_workflow_runs_as_written_from_another_folder(tmp_path):
    """Every command of the first workflow block, in order, in an empty folder outside the repository."""
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = _env()
    for line in _blocks("Typical workflows")[0]:
        r = _sh(line, work, env)
        assert r.returncode == 0, f"README command failed: {line}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    for f in ("cal.npz", "intrinsics.json", "calib_ir.yaml", "cloud.ply", "deviation.e57", "model/mesh.ply",
              "accuracy/metrics.json", "validation/validation.json", "capture-corrected/capture.json"):
        assert (work / f).exists(), f
    assert not any(p.name.startswith(".") and p.name.endswith(".tmp") for p in work.rglob("*"))
    # nothing is replaced: the same block again stops at its first command, naming the output and --force
    first = _blocks("Typical workflows")[0][0]
    r = _sh(first, work, env)
    assert r.returncode == 2 and "--force" in r.stderr and "wall" in r.stderr, r.stderr
    # deviation_mm survives the E57 export
    from tofmetry.io.e57 import read_e57
    from tofmetry.io.ply import read_ply

    e57, ply = read_e57(work / "deviation.e57"), read_ply(work / "accuracy" / "deviation.ply")
    np.testing.assert_allclose(e57["deviation_mm"], ply["deviation_mm"], atol=1e-4)


@pytest.mark.slow
@pytest.mark.realdata
def test_the_real_recording_workflow_runs_as_written(tmp_path, shared_data):
    """The iai_kinect2 block; ``DATA`` is the README's one line to adapt (here: this machine's shared/data)."""
    block = _blocks("Typical workflows")[1]
    assert block[0] == "DATA=../shared/data"
    script = "\n".join(["set -e", f"DATA={shlex.quote(str(shared_data))}", *block[1:]])
    r = _sh(script, tmp_path, _env(), timeout=900)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert (tmp_path / "iai-calib" / "calib_ir.yaml").is_file() and (tmp_path / "board-cal.npz").is_file()


def test_study_script_called_from_another_folder_writes_where_it_is_called(tmp_path):
    """``path/to/scripts/study.sh -o out`` writes ``out`` in the caller's folder (it used to cd to the repository)."""
    text = (REPO / "scripts" / "study.sh").read_text()
    assert re.search(r"^\s*cd\b", text, re.M) is None, "study.sh must not change the caller's folder"
    fake = tmp_path / "repo"
    (fake / "scripts").mkdir(parents=True)
    (fake / ".venv" / "bin").mkdir(parents=True)
    (fake / "scripts" / "study.sh").write_text(text)
    (fake / "scripts" / "setup-env.sh").write_text("#!/usr/bin/env bash\ntrue\n")
    # a stand-in CLI that records where it runs and what it was given
    (fake / ".venv" / "bin" / "tofmetry").write_text('#!/usr/bin/env bash\necho "$PWD|$*" > "$PWD/called.txt"\n')
    (fake / ".venv" / "bin" / "tofmetry").chmod(0o755)
    caller = tmp_path / "caller"
    caller.mkdir()
    r = subprocess.run(["bash", str(fake / "scripts" / "study.sh"), "-o", "out"], cwd=caller, capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr
    assert (caller / "called.txt").read_text().strip() == f"{caller}|study -o out"


def test_test_script_runs_from_another_folder():
    text = (REPO / "scripts" / "test.sh").read_text()
    assert 'cd "$ROOT"' in text   # pytest needs the repository's configuration; the caller's paths are not used
