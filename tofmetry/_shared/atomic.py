"""Atomic file and folder writing: write to a temporary sibling, then rename into place.

A reader never sees a half-written file or folder under its final name: an interrupted run
leaves at most a hidden ``.NAME.*.tmp`` sibling, never an output that looks complete.

The temporary file / folder is created private (0600 / 0700); before it is
renamed into place it gets the mode an ordinary ``open`` / ``mkdir`` would have given it under the
process's umask (0644 / 0755 under the usual 022), so that colleagues can read the results.
"""

from __future__ import annotations

import os
import secrets
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from tofmetry.errors import InputError


def _umask() -> int:
    """The process's umask, read without changing it where the system tells it (Linux
    ``/proc/self/status``; elsewhere a quick set-and-restore)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of a new file under the current umask (``0o666 & ~umask``)."""
    return 0o666 & ~_umask()


def dir_mode() -> int:
    """Mode of a new folder under the current umask (``0o777 & ~umask``)."""
    return 0o777 & ~_umask()


def staging_name(path: Path) -> Path:
    """A fresh hidden sibling of ``path``: ``.NAME.<random>.tmp`` (not created).

    The writers create it themselves (``os.open`` with ``O_EXCL`` / ``os.mkdir``) *inside* their
    clean-up's ``try``: with ``tempfile.mkstemp`` / ``mkdtemp`` a Ctrl-C landing between the
    creation and the ``try`` (``tofmetry correct`` interrupted as its staging folder appeared, once
    in CI) left the staging entry behind.
    """
    return path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")


def _someone_elses(exc: BaseException, tmp: Path) -> bool:
    """The creation of ``tmp`` itself failed because the name was taken: not ours to remove."""
    return isinstance(exc, FileExistsError) and exc.filename == os.fspath(tmp)


def replace_dir(src: str | os.PathLike, dst: str | os.PathLike) -> Path:
    """Move the finished folder ``src`` to ``dst`` (a sibling). An existing ``dst`` is first moved
    aside to a hidden ``.NAME.old-PID`` and removed only once ``src`` is in place, so ``dst`` is at
    every moment either the old complete folder or the new one."""
    src, dst = Path(src), Path(dst)
    if dst.exists():
        old = dst.with_name(f".{dst.name}.old-{os.getpid()}")
        os.replace(dst, old)
        os.replace(src, dst)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(src, dst)
    return dst


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, mode: int | None = None,
                       fsync: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically (same-folder temporary file + ``os.replace``).

    Parameters
    ----------
    path : the file to write; its folder is created if needed
    data : the bytes
    mode : the file's permission bits (default :func:`file_mode`)
    fsync : flush the data to the disk before the rename (a file that must survive a power cut)

    Returns
    -------
    Path of the written file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = staging_name(path)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as fh:
            os.fchmod(fh.fileno(), file_mode() if mode is None else mode)
            fh.write(data)
            if fsync:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        if os.path.lexists(tmp) and not _someone_elses(exc, tmp):
            os.unlink(tmp)
        raise
    return path


@contextmanager
def atomic_dir(path: str | os.PathLike, force: bool = False) -> Iterator[Path]:
    """Build a folder in a temporary sibling and move it into place on success.

    Refuses to replace an existing non-empty folder (or a file) unless ``force``; the previous
    folder is then removed only after the new one is complete. On any exception (including
    ``KeyboardInterrupt``) the temporary folder is removed and ``path`` is left as it was.

    Yields
    ------
    Path of the temporary folder to fill.
    """
    path = Path(path)
    occupied = (path.is_dir() and any(path.iterdir())) or (path.exists() and not path.is_dir())
    if occupied and not force:
        raise InputError(f"output {path} already exists; refusing to overwrite (pass --force to replace it)")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = staging_name(path)
    try:
        os.mkdir(tmp, 0o700)
        os.chmod(tmp, dir_mode())
        yield tmp
        replace_dir(tmp, path)
    except BaseException as exc:
        if not _someone_elses(exc, tmp):
            shutil.rmtree(tmp, ignore_errors=True)
        raise
