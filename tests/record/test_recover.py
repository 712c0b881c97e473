"""A cut recording reads back as its complete frames; ``tofmetry record recover`` finishes it on disk."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.errors import FormatError, InputError
from tofmetry.io import Capture, CutRecordingWarning

REPO = Path(__file__).resolve().parents[2]


def _cut_recording(out: Path, cut_at: int = 5) -> None:
    """Record frames with the live writer in another process; the power goes off while frame ``cut_at``'s depth is written."""
    script = textwrap.dedent(f"""
        import os, numpy as np
        from tofmetry.io import CaptureMeta
        import tofmetry.io.live_capture as lc
        w = lc.LiveCaptureWriter({str(out)!r}, CaptureMeta(sensor="kinect_v2"))
        real = lc.durable_write
        def cut(path, data):
            if path.parent.name == "depth" and path.name == "{cut_at:06d}.png":
                os._exit(9)
            real(path, data)
        lc.durable_write = cut
        for i in range(10):
            d = np.full((424, 512), 1000 + i, np.uint16)
            w.add(d, 0.5 * i, ir=d, temperature_c={{"sensor": 30.0 + i}})
    """)
    p = subprocess.run([sys.executable, "-c", script], env=dict(os.environ, PYTHONPATH=str(REPO)), capture_output=True,
                       text=True)
    assert p.returncode == 9, p.stderr


def _snapshot(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_cut_recording_reads_as_its_complete_frames_then_recover_finishes_it(tmp_path):
    cap_dir = tmp_path / "rec" / "poses" / "0003"          # a pose of a board dataset, cut mid-recording
    _cut_recording(cap_dir)
    before = _snapshot(cap_dir)
    with pytest.warns(CutRecordingWarning, match=r"read as its 5 complete frame\(s\).*tofmetry record recover"):
        cap = Capture(cap_dir)
    assert len(cap) == 5 and list(cap.timestamps_s) == [0.0, 0.5, 1.0, 1.5, 2.0] and cap.has_ir
    assert cap.depth(4)[0, 0] == 1004 and cap.ir(4)[0, 0] == 1004
    assert cap.meta.extra["temperature_c"]["sensor"] == [30.0, 31.0, 32.0, 33.0, 34.0]
    assert _snapshot(cap_dir) == before                       # reading changed nothing

    r = CliRunner().invoke(app, ["record", "recover", str(tmp_path / "rec")])
    assert r.exit_code == 0, r.output
    assert "5 complete frame(s) kept, 1 file(s) of the frame in flight removed" in r.output
    cap = Capture(cap_dir)                                     # no warning any more (warnings are errors)
    assert len(cap) == 5 and json.loads((cap_dir / "capture.json").read_text())["recording"]["recovered"]
    r = CliRunner().invoke(app, ["record", "recover", str(tmp_path / "rec")])
    assert r.exit_code == 0 and "nothing to recover" in r.output


def test_recover_of_a_missing_folder_and_a_recording_without_a_frame(tmp_path):
    r = CliRunner().invoke(app, ["record", "recover", str(tmp_path / "nope")])
    # an InputError: tofmetry's main() prints its message and exits 1, without a traceback
    assert isinstance(r.exception, InputError) and "is not a folder" in str(r.exception)
    cap_dir = tmp_path / "empty"
    _cut_recording(cap_dir, cut_at=0)
    with pytest.raises(FormatError, match="cut off before its first complete frame"):
        Capture(cap_dir)
    np.testing.assert_equal(sorted(p.name for p in (cap_dir / "ir").iterdir()), ["000000.png"])
