"""The manifest: validated with pydantic, globs expanded, errors naming the file and the line."""

from __future__ import annotations

from pathlib import Path

import pytest

from tofmetry.batch import load_manifest
from tofmetry.errors import InputError


def _write(tmp_path: Path, text: str, name: str = "m.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_globs_expand_and_references_resolve(tmp_path):
    for s in ("a", "b", "c"):
        (tmp_path / "rec" / s / "capture").mkdir(parents=True)
    m = _write(tmp_path, """
[defaults]
chunk_frames = 500

[[job]]
kind = "calibrate-depth"
name = "cal"
inputs = { dataset = "wall" }

[[job]]
kind = "correct"
name = "fix"
inputs = { capture = "rec/*/capture", calibration = "@cal/calibration.npz" }
""")
    jobs = load_manifest(m, tmp_path / "out")
    assert [j.name for j in jobs] == ["cal", "fix-a_capture", "fix-b_capture", "fix-c_capture"]
    fix = jobs[1]
    assert fix.needs == ["cal"] and fix.chunk_frames == 500 and fix.line == 10
    assert fix.inputs["calibration"] == str((tmp_path / "out" / "cal" / "calibration.npz").resolve())
    assert fix.inputs["capture"] == str(tmp_path / "rec" / "a" / "capture")


@pytest.mark.parametrize("body, line, words", [
    ('[[job]]\nkind = "corect"\ninputs = { capture = "x" }\n', 2, "kind"),
    ('[[job]]\nkind = "correct"\ninputs = { capture = "x", calibration = "c" }\n\n[[job]]\nkind = "assess"\n'
     'inputs = { capture = "x" }\nspeed = 3\n', 8, "speed"),
    ('[[job]]\nkind = "correct"\n\ninputs = { capture = "x" }\n', 4, "missing ['calibration']"),
    ('[[job]]\nkind = "assess"\ninputs = { capture = "none/*/capture" }\n', 3, "matches nothing"),
    ('[[job]]\nkind = "assess"\nname = "a"\ninputs = { capture = "x" }\n[[job]]\nkind = "assess"\nname = "a"\n'
     'inputs = { capture = "y" }\n', 5, "used twice"),
    ('[[job]]\nkind = "validate"\ninputs = { dataset = "w", calibration = "@cal/c.npz" }\n', 3, "no job is named 'cal'"),
    ('[defaults]\nchunk_frames = 0\n[[job]]\nkind = "study"\n', 2, "chunk_frames"),
])
def test_errors_name_the_line(tmp_path, body, line, words):
    m = _write(tmp_path, body)
    with pytest.raises(InputError) as err:
        load_manifest(m, tmp_path / "out")
    assert f"{m} line {line}" in str(err.value) and words in str(err.value)


def test_yaml_errors_name_the_line(tmp_path):
    m = _write(tmp_path, "job:\n  - kind: assess\n    inputs: {capture: x}\n  - kind: correct\n    inputs: {capture: x}\n",
               "m.yaml")
    with pytest.raises(InputError, match=r"m.yaml line 5 .*missing \['calibration'\]"):
        load_manifest(m, tmp_path / "out")
    bad = _write(tmp_path, "job: [\n  kind: a\n", "bad.yml")
    with pytest.raises(InputError, match="bad.yml line .*not valid YAML"):
        load_manifest(bad, tmp_path / "out")
    with pytest.raises(InputError, match="not valid TOML"):
        load_manifest(_write(tmp_path, "[[job]\n"), tmp_path / "out")
    with pytest.raises(InputError, match="manifest not found"):
        load_manifest(tmp_path / "nope.toml", tmp_path / "out")
