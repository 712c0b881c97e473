"""The batch manifest: a TOML or YAML list of jobs, validated with pydantic, errors naming the line.

.. code-block:: toml

    [defaults]
    chunk_frames = 2000        # frames per chunk of a long recording (correct, assess warmup/noise)
    retries = 1                # extra attempts of a job that raised an unexpected error

    [[job]]
    kind = "calibrate-depth"
    name = "cal-S01"
    sensor = "S01"             # optional: jobs of one sensor are shown side by side in the summary
    inputs = { dataset = "walls/S01" }
    options = { reference_offset_mm = 20 }

    [[job]]
    kind = "correct"
    name = "corrected"
    inputs = { capture = "recordings/*/capture", calibration = "@cal-S01/calibration.npz" }

Paths are relative to the manifest's folder. One input per job may be a glob pattern: the job is
repeated for every match (sorted), named ``NAME-<match>``. ``@JOB/path`` is a path inside the
output of job ``JOB`` of the same manifest: the job then waits for it. Each job writes into
``OUT/<name>/``. YAML uses the same keys (``defaults:``, ``job:`` as a list).
"""

from __future__ import annotations

import glob
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from tofmetry.errors import InputError

KINDS = ("calibrate-depth", "validate", "correct", "reconstruct", "evaluate", "assess", "study")

#: input roles per kind: (required, optional)
INPUTS: dict[str, tuple[set[str], set[str]]] = {
    "calibrate-depth": ({"dataset"}, {"intrinsics"}),
    "validate": ({"dataset", "calibration"}, {"intrinsics"}),
    "correct": ({"capture", "calibration"}, set()),
    "reconstruct": ({"scan"}, {"calibration", "amplitude_reference"}),
    "evaluate": ({"model", "reference"}, {"poses"}),
    "assess": ({"capture"}, {"regions", "intrinsics"}),
    "study": (set(), {"data", "config"}),
}

_NAME = r"^[A-Za-z0-9][A-Za-z0-9._-]*$"
_GLOB = re.compile(r"[*?\[]")


class Defaults(BaseModel):
    """``[defaults]``: settings of every job unless the job sets them."""

    model_config = ConfigDict(extra="forbid")
    chunk_frames: int = Field(2000, ge=1, description="frames per chunk of a long recording")
    retries: int = Field(1, ge=0, le=10, description="extra attempts after an unexpected error")


class JobModel(BaseModel):
    """One ``[[job]]`` entry."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["calibrate-depth", "validate", "correct", "reconstruct", "evaluate", "assess", "study"]
    name: str | None = Field(None, pattern=_NAME)
    sensor: str | None = None
    inputs: dict[str, str] = Field(default_factory=dict)
    options: dict[str, Any] = Field(default_factory=dict)
    chunk_frames: int | None = Field(None, ge=1)
    retries: int | None = Field(None, ge=0, le=10)


class ManifestModel(BaseModel):
    model_config = ConfigDict(extra="forbid")
    version: Literal[1] = 1
    defaults: Defaults = Field(default_factory=Defaults)
    job: list[JobModel] = Field(min_length=1)


@dataclass
class JobSpec:
    """One job after glob expansion: what a worker needs to run it.

    Attributes
    ----------
    name : unique; the job writes into ``OUT/<name>/``
    kind : one of :data:`KINDS`
    inputs : role -> absolute path (``@JOB/...`` resolved into ``OUT/JOB/...``)
    options : the pipeline's options (validated by the job's runner)
    needs : names of the jobs whose outputs this job reads
    line : line of the job in the manifest (for messages)
    """

    name: str
    kind: str
    inputs: dict[str, str]
    options: dict[str, Any]
    sensor: str | None = None
    chunk_frames: int = 2000
    retries: int = 1
    needs: list[str] = field(default_factory=list)
    line: int = 0

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "inputs": self.inputs, "options": self.options,
                "sensor": self.sensor, "chunk_frames": self.chunk_frames, "retries": self.retries, "needs": self.needs, "line": self.line}


def _job_lines(text: str, is_toml: bool) -> list[int]:
    """Line (1-based) where each job starts."""
    if is_toml:
        return [i + 1 for i, ln in enumerate(text.splitlines()) if re.match(r"^\s*\[\[\s*job\s*\]\]", ln)]
    try:
        root = yaml.compose(text)
    except yaml.YAMLError:
        return []
    for k, v in getattr(root, "value", []) if isinstance(root, yaml.MappingNode) else []:
        if k.value == "job" and isinstance(v, yaml.SequenceNode):
            return [item.start_mark.line + 1 for item in v.value]
    return []


def _key_line(text: str, start: int, key: str) -> int:
    """First line at or after ``start`` naming ``key`` (falls back to ``start``)."""
    lines = text.splitlines()
    for i in range(max(start - 1, 0), len(lines)):
        if i > start - 1 and re.match(r"^\s*\[", lines[i]):
            break
        if re.search(rf"(^|[\s{{,]){re.escape(key)}\s*[=:]", lines[i]):
            return i + 1
    return start


def _parse(path: Path) -> tuple[dict, str, bool]:
    if not path.is_file():
        raise InputError(f"manifest not found: {path}")
    text = path.read_bytes().decode("utf-8", errors="replace")
    is_toml = path.suffix.lower() == ".toml"
    if not is_toml and path.suffix.lower() not in (".yaml", ".yml"):
        raise InputError(f"{path}: a manifest is a .toml, .yaml or .yml file, found {path.suffix or 'no suffix'!r}")
    try:
        data = tomllib.loads(text) if is_toml else yaml.safe_load(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise InputError(f"{path}{where}: not valid YAML ({getattr(exc, 'problem', exc)})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a table with [defaults] and [[job]] entries, found {type(data).__name__}")
    return data, text, is_toml


def _validation_message(path: Path, exc: ValidationError, text: str, starts: list[int]) -> str:
    msgs = []
    for e in exc.errors():
        loc = e["loc"]
        line = 1
        if len(loc) >= 2 and loc[0] == "job" and isinstance(loc[1], int):
            start = starts[loc[1]] if loc[1] < len(starts) else 1
            line = _key_line(text, start, str(loc[2])) if len(loc) > 2 else start
            where = f"job {loc[1] + 1}, " + ".".join(str(x) for x in loc[2:])
        else:
            where = ".".join(str(x) for x in loc)
            if loc:
                line = _key_line(text, 1, str(loc[-1]))
        found = e.get("input")
        msgs.append(f"{path} line {line} ({where}): {e['msg']}"
                    + (f", found {found!r}" if not isinstance(found, (dict, list)) else ""))
    return "; ".join(msgs)


def load_manifest(path: str | os.PathLike, out: str | os.PathLike) -> list[JobSpec]:
    """Read, validate and expand a manifest into jobs.

    Parameters
    ----------
    path : the manifest (``.toml``, ``.yaml`` or ``.yml``)
    out : the batch's output folder (``@JOB/...`` inputs point into it)

    Returns
    -------
    list of JobSpec, in manifest order (globs expanded in sorted order)

    Raises
    ------
    InputError
        Naming the manifest, the line and the entry: bad syntax, unknown key or kind, missing or
        unknown input, a glob matching nothing, a duplicate job name, an unknown ``@JOB``.
    """
    path = Path(path)
    data, text, is_toml = _parse(path)
    starts = _job_lines(text, is_toml)
    try:
        m = ManifestModel.model_validate(data)
    except ValidationError as exc:
        raise InputError(_validation_message(path, exc, text, starts)) from None
    base, out = path.resolve().parent, Path(out).resolve()
    jobs: list[JobSpec] = []
    for k, j in enumerate(m.job):
        line = starts[k] if k < len(starts) else 0
        jobs += _expand(j, k, line, base, out, m.defaults, path, text)
    seen: dict[str, int] = {}
    for j in jobs:
        if j.name in seen:
            raise InputError(f"{path} line {j.line}: job name {j.name!r} is used twice (also line {seen[j.name]}); "
                             "names must be unique (each job writes OUT/<name>/)")
        seen[j.name] = j.line
    for j in jobs:
        for d in j.needs:
            if d not in seen:
                raise InputError(f"{path} line {_key_line(text, j.line, 'inputs')}: job {j.name!r} reads '@{d}/...' "
                                 f"but no job is named {d!r} (known: {', '.join(sorted(seen))})")
    return jobs


def _expand(j: JobModel, k: int, line: int, base: Path, out: Path, d: Defaults, path: Path, text: str) -> list[JobSpec]:
    where = f"{path} line {_key_line(text, line, 'inputs')} (job {k + 1}, kind {j.kind})"
    required, optional = INPUTS[j.kind]
    missing, unknown = required - j.inputs.keys(), j.inputs.keys() - required - optional
    if missing or unknown:
        raise InputError(f"{where}: inputs must hold {sorted(required)} (optional {sorted(optional)}); "
                         + (f"missing {sorted(missing)}" if missing else f"unknown {sorted(unknown)}"))
    name = j.name or j.kind
    globs = [r for r, v in j.inputs.items() if _GLOB.search(v) and not v.startswith("@")]
    if len(globs) > 1:
        raise InputError(f"{where}: at most one input may be a glob pattern, found {globs}")
    variants: list[tuple[str, dict[str, str]]] = [(name, dict(j.inputs))]
    if globs:
        role = globs[0]
        pattern = str(base / j.inputs[role])
        matches = sorted(glob.glob(pattern, recursive=True))
        if not matches:
            raise InputError(f"{where}: the pattern {j.inputs[role]!r} of input '{role}' matches nothing "
                             f"(looked for {pattern})")
        fixed = Path(pattern.split("*")[0].split("?")[0].split("[")[0])
        fixed = fixed if fixed.is_dir() else fixed.parent
        variants = []
        for mt in matches:
            rel = os.path.relpath(mt, fixed)
            tag = re.sub(r"[^A-Za-z0-9._-]+", "_", rel).strip("._") or "match"
            variants.append((f"{name}-{tag}", {**j.inputs, role: mt}))
    specs = []
    for jname, inputs in variants:
        resolved, needs = {}, []
        for role, v in inputs.items():
            if v.startswith("@"):
                dep, _, rest = v[1:].partition("/")
                needs.append(dep)
                resolved[role] = str(out / dep / rest)
            else:
                resolved[role] = str((base / v).resolve())
        specs.append(JobSpec(name=jname, kind=j.kind, inputs=resolved, options=dict(j.options), sensor=j.sensor,
                             chunk_frames=j.chunk_frames or d.chunk_frames,
                             retries=d.retries if j.retries is None else j.retries, needs=sorted(set(needs)), line=line))
    return specs
