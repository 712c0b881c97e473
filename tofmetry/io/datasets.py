"""Dataset folders built from captures: wall datasets (depth calibration) and scans.

::

    wall dataset/
      stations.csv      header "capture,distance_mm"; capture = sub-folder (a capture),
                        distance_mm = reference distance sensor->wall along the optical axis
    scan dataset/
      views/<name>/     one capture per viewpoint, processed in name order

Both are plug-in datasets with ``__len__`` / ``__getitem__`` (kiss-icp style).
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path, PureWindowsPath

from tofmetry.errors import InputError
from tofmetry.io._atomic import atomic_write_bytes
from tofmetry.io.capture import Capture


def safe_relative(name: str, what: str) -> Path:
    """``name`` (a path read from inside a data file) as a relative path that stays in its folder.

    Raises
    ------
    InputError
        ``name`` is empty, absolute (``/x``, ``C:\\x``) or climbs out of the folder (a ``..`` part).
    """
    text = str(name).strip()
    p = Path(text)
    win = PureWindowsPath(text)
    if not text:
        raise InputError(f"{what}: empty path")
    if p.is_absolute() or win.is_absolute() or win.drive or text.startswith(("/", "\\")):
        raise InputError(f"{what} {text!r} is an absolute path; paths inside a dataset must be relative to its folder")
    if ".." in p.parts or ".." in win.parts:
        raise InputError(f"{what} {text!r} points outside the dataset's folder ('..'); datasets may only name "
                         "files and folders inside themselves")
    return p


@dataclass(frozen=True)
class Station:
    """One wall station: a capture at a reference distance [mm]."""

    name: str
    distance_mm: float
    path: Path

    def open(self) -> Capture:
        return Capture(self.path)


class WallDataset:
    """A wall dataset (``stations.csv`` + one capture per station).

    Raises
    ------
    InputError
        Missing ``stations.csv``, a wrong header, a station listed twice, a missing capture
        folder, a non-numeric or non-positive distance, distances not strictly increasing,
        fewer than ``min_stations`` stations.
    """

    def __init__(self, path: str | os.PathLike, min_stations: int = 1):
        self.path = Path(path)
        csv_path = self.path / "stations.csv"
        if not csv_path.is_file():
            raise InputError(f"{self.path}: not a wall dataset (no stations.csv with header 'capture,distance_mm')")
        with open(csv_path, newline="") as fh:
            rows = list(csv.reader(fh))
        rows = [r for r in rows if r and any(c.strip() for c in r)]
        if not rows or [c.strip() for c in rows[0]] != ["capture", "distance_mm"]:
            raise InputError(f"{csv_path}: header must be 'capture,distance_mm', found {rows[0] if rows else 'nothing'}")
        stations: list[Station] = []
        seen: dict[str, int] = {}
        for lineno, r in enumerate(rows[1:], start=2):
            if len(r) != 2:
                raise InputError(f"{csv_path}:{lineno}: expected 2 columns (capture,distance_mm), found {r}")
            name, dist = r[0].strip(), r[1].strip()
            try:
                d = float(dist)
            except ValueError:
                raise InputError(f"{csv_path}:{lineno}: distance_mm {dist!r} is not a number") from None
            if not d > 0:
                raise InputError(f"{csv_path}:{lineno}: distance_mm must be > 0, found {d}")
            if name in seen:
                raise InputError(f"{csv_path}:{lineno}: station {name!r} listed twice (first on line {seen[name]})")
            seen[name] = lineno
            sp = self.path / safe_relative(name, f"{csv_path}:{lineno}: station capture")
            if not sp.is_dir():
                raise InputError(f"{csv_path}:{lineno}: station capture folder {sp} is missing")
            stations.append(Station(name, d, sp))
        for a, b in zip(stations, stations[1:]):
            if not b.distance_mm > a.distance_mm:
                raise InputError(
                    f"{csv_path}: distances must be strictly increasing; {b.name!r} ({b.distance_mm} mm) "
                    f"follows {a.name!r} ({a.distance_mm} mm)"
                )
        if len(stations) < min_stations:
            raise InputError(f"{csv_path}: {len(stations)} station(s) found, at least {min_stations} needed")
        self.stations = stations

    def __len__(self) -> int:
        return len(self.stations)

    def __getitem__(self, i: int) -> Station:
        return self.stations[i]

    @property
    def distances_mm(self) -> list[float]:
        return [s.distance_mm for s in self.stations]


def write_stations_csv(path: str | os.PathLike, stations: list[tuple[str, float]]) -> Path:
    """Write ``stations.csv`` (``capture,distance_mm``) atomically."""
    lines = ["capture,distance_mm"] + [f"{n},{d:.3f}" for n, d in stations]
    return atomic_write_bytes(Path(path), ("\n".join(lines) + "\n").encode())


class ScanDataset:
    """A scan dataset: ``views/<name>/`` captures in name order."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        vdir = self.path / "views"
        if not vdir.is_dir():
            raise InputError(f"{self.path}: not a scan dataset (no views/ folder with one capture per viewpoint)")
        self.view_paths = sorted(p for p in vdir.iterdir() if p.is_dir() and not p.name.startswith("."))
        if not self.view_paths:
            raise InputError(f"{vdir}: no view captures found")

    def __len__(self) -> int:
        return len(self.view_paths)

    def __getitem__(self, i: int) -> Capture:
        return Capture(self.view_paths[i])

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.view_paths]
