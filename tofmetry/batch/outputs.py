"""A job's output folder: built in a hidden staging folder, published whole with a completion marker.

``OUT/<name>/`` appears only when the job is complete: the job writes into ``OUT/.<name>.batch-tmp/``
(emptied at the start of every attempt, so a retry after a killed worker starts clean), writes the
marker ``batch-job.json`` last, then renames the folder into place. The marker records the content
hash of every input and a hash of the job's settings: a rerun skips a job whose marker matches both,
and redoes one whose inputs or options changed. A folder without a matching marker never counts as
complete.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

from tofmetry._shared.atomic import replace_dir
from tofmetry.errors import InputError
from tofmetry.io import atomic_write_json, read_json

MARKER = "batch-job.json"
_BLOCK = 1 << 20


def _hash_file(h, path: Path) -> None:
    with open(path, "rb") as fh:
        while block := fh.read(_BLOCK):
            h.update(block)


def content_hash(path: str | os.PathLike) -> str:
    """BLAKE2b of a file's bytes, or of a folder's files (relative names and bytes, in sorted order;
    hidden entries and batch markers left out). Raises InputError naming a missing path."""
    p = Path(path)
    h = hashlib.blake2b(digest_size=20)
    if p.is_file():
        _hash_file(h, p)
    elif p.is_dir():
        for root, dirs, files in os.walk(p):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            for name in sorted(files):
                if name.startswith(".") or name == MARKER:
                    continue
                f = Path(root) / name
                h.update(str(f.relative_to(p)).encode() + b"\0")
                _hash_file(h, f)
    else:
        raise InputError(f"input not found: {p} (expected a file or a folder)")
    return h.hexdigest()


def input_hashes(inputs: dict[str, str]) -> dict[str, str]:
    """Content hash per input role."""
    return {role: content_hash(p) for role, p in sorted(inputs.items())}


def settings_hash(spec: dict) -> str:
    """Hash of what defines a job besides its inputs' content: kind, options and input paths."""
    key = json.dumps({k: spec.get(k) for k in ("kind", "options", "inputs")}, sort_keys=True, default=str)
    return hashlib.blake2b(key.encode(), digest_size=12).hexdigest()


def final_dir(out: str | os.PathLike, name: str) -> Path:
    return Path(out) / name


def staging_dir(out: str | os.PathLike, name: str) -> Path:
    return Path(out) / f".{name}.batch-tmp"


def completed(out: str | os.PathLike, spec: dict, hashes: dict[str, str]) -> dict | None:
    """The marker of a finished job whose inputs and settings are unchanged, else None."""
    marker = final_dir(out, spec["name"]) / MARKER
    if not marker.is_file():
        return None
    try:
        rec = read_json(marker, "batch marker")
    except InputError:
        return None
    if rec.get("status") == "ok" and rec.get("input_hashes") == hashes and rec.get("settings") == settings_hash(spec):
        return rec
    return None


def fresh_staging(out: str | os.PathLike, name: str) -> Path:
    """An empty staging folder for the job (what an earlier, interrupted attempt left is removed)."""
    st = staging_dir(out, name)
    if st.exists():
        shutil.rmtree(st)
    st.mkdir(parents=True)
    return st


def publish(out: str | os.PathLike, spec: dict, record: dict) -> Path:
    """Write the marker into the staging folder, then move the folder to ``OUT/<name>`` (an older
    output of the job is replaced only once the new one is in place)."""
    st, final = staging_dir(out, spec["name"]), final_dir(out, spec["name"])
    atomic_write_json(st / MARKER, record)
    return replace_dir(st, final)
