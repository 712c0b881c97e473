"""Importer / exporter registry: format name -> function, loaded lazily.

Each format lives in its own module of :mod:`tofmetry.io`; the registry only names it, so
``tofmetry --help`` does not import optional dependencies (PyAV, pye57). A missing optional
package fails when the format is *used*, with the package to install.

Importer signature: ``fn(src: Path, out: Path, *, force: bool, progress, **options) -> dict``
Exporter signature: ``fn(src: Path, out: Path, *, force: bool, **options) -> dict``
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

from tofmetry.errors import InputError


@dataclass(frozen=True)
class Format:
    """A registered importer or exporter.

    Attributes
    ----------
    name : CLI name (e.g. ``"azure-kinect"``).
    target : ``"module:function"`` implementing it.
    description : one line for ``--help``.
    requires : optional third-party packages (import names) it needs.
    """

    name: str
    target: str
    description: str
    requires: tuple[str, ...] = ()

    def load(self) -> Callable:
        for pkg in self.requires:
            try:
                importlib.import_module(pkg)
            except ImportError:
                pip = {"av": "av", "pye57": "pye57"}.get(pkg, pkg)
                raise InputError(
                    f"format {self.name!r} needs the optional package {pkg!r}, which is not installed "
                    f"(pip install {pip})"
                ) from None
        mod, fn = self.target.split(":")
        return getattr(importlib.import_module(mod), fn)


IMPORTERS: dict[str, Format] = {}
EXPORTERS: dict[str, Format] = {}


def register_importer(fmt: Format) -> None:
    IMPORTERS[fmt.name] = fmt


def register_exporter(fmt: Format) -> None:
    EXPORTERS[fmt.name] = fmt


def _get(table: dict[str, Format], name: str, kind: str) -> Format:
    try:
        return table[name]
    except KeyError:
        raise InputError(f"unknown {kind} format {name!r}; known: {', '.join(sorted(table))}") from None


def get_importer(name: str) -> Callable:
    """The import function of format ``name`` (InputError listing the known ones)."""
    return _get(IMPORTERS, name, "import").load()


def get_exporter(name: str) -> Callable:
    """The export function of format ``name`` (InputError listing the known ones)."""
    return _get(EXPORTERS, name, "export").load()


for _f in (
    Format("iai-kinect2", "tofmetry.pipelines.iai_import:import_iai_kinect2_cli",
           "iai_kinect2 kinect_cal_data folder and/or calib_*.yaml -> board dataset"),
    Format("azure-kinect", "tofmetry.io.azure_kinect:import_azure_kinect_cli",
           "Azure Kinect .mkv recording (depth, IR, colour, factory calibration) -> capture", ("av",)),
    Format("tum", "tofmetry.io.tum:import_tum_cli", "TUM RGB-D folder (depth PNG, 5000 per m) -> capture"),
    Format("open3d", "tofmetry.io.open3d_rgbd:import_open3d_cli",
           "Open3D RGB-D folder (depth/ color/, 1000 per m by default) -> capture"),
):
    register_importer(_f)

for _f in (
    Format("iai-kinect2", "tofmetry.io.board_dataset:export_iai_kinect2_cli",
           "calibration (.npz, intrinsics.json or board dataset) -> calib_ir.yaml + calib_depth.yaml"),
    Format("e57", "tofmetry.io.e57:export_e57_cli", "PLY point cloud or mesh vertices -> E57", ("pye57",)),
    Format("ply", "tofmetry.io.e57:export_ply_cli", "E57 point cloud -> PLY", ("pye57",)),
):
    register_exporter(_f)
