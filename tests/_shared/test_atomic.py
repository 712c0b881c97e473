"""Atomic writers: an interrupt at any point leaves no staging entry and no output that looks complete."""

from __future__ import annotations

import os

import numpy as np
import pytest

from tofmetry._shared import atomic
from tofmetry.io import CaptureWriter


def _interrupt_after(monkeypatch, name: str):
    """Make ``os.<name>`` do its work, then raise KeyboardInterrupt (a Ctrl-C landing just after it)."""
    real = getattr(os, name)

    def created_then_interrupted(*args, **kwargs):
        out = real(*args, **kwargs)
        if name == "open":
            os.close(out)
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic.os, name, created_then_interrupted)


def test_interrupt_just_after_the_staging_folder_is_made_leaves_nothing(tmp_path, monkeypatch):
    _interrupt_after(monkeypatch, "mkdir")
    with pytest.raises(KeyboardInterrupt):
        with atomic.atomic_dir(tmp_path / "out"):
            pass
    assert list(tmp_path.iterdir()) == []


def test_interrupt_just_after_the_staging_file_is_made_leaves_nothing(tmp_path, monkeypatch):
    _interrupt_after(monkeypatch, "open")
    with pytest.raises(KeyboardInterrupt):
        atomic.atomic_write_bytes(tmp_path / "a.bin", b"data")
    assert list(tmp_path.iterdir()) == []


def test_a_taken_staging_name_is_not_removed(tmp_path, monkeypatch):
    taken = tmp_path / ".out.taken.tmp"
    taken.mkdir()
    (taken / "theirs").write_text("keep")
    monkeypatch.setattr(atomic, "staging_name", lambda path: taken)
    with pytest.raises(FileExistsError):
        with atomic.atomic_dir(tmp_path / "out"):
            pass
    assert (taken / "theirs").read_text() == "keep"


def test_capture_writer_interrupted_while_it_prepares_its_folder_leaves_nothing(tmp_path, monkeypatch):
    """A ``with`` whose ``__enter__`` raises never calls ``__exit__``: the writer cleans up itself."""
    real = type(tmp_path).mkdir
    calls = []

    def mkdir(self, *args, **kwargs):
        real(self, *args, **kwargs)
        calls.append(self.name)
        if self.name == "ir":
            raise KeyboardInterrupt

    monkeypatch.setattr(type(tmp_path), "mkdir", mkdir)
    with pytest.raises(KeyboardInterrupt) as info:
        with CaptureWriter(tmp_path / "cap") as w:
            w.add(np.ones((4, 4), np.uint16))
    # the traceback kept (as the CLI keeps it until its os._exit) holds the writer: no clean-up by
    # garbage collection may stand in for the writer's own
    assert info.traceback and "ir" in calls
    assert list(tmp_path.iterdir()) == []


def test_written_files_and_folders_get_the_umask_modes(tmp_path):
    atomic.atomic_write_bytes(tmp_path / "a.bin", b"x")
    with atomic.atomic_dir(tmp_path / "d") as t:
        (t / "f").write_text("1")
    assert os.stat(tmp_path / "a.bin").st_mode & 0o777 == atomic.file_mode()
    assert os.stat(tmp_path / "d").st_mode & 0o777 == atomic.dir_mode()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "d"]
