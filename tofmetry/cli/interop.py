"""CLI commands: interop — ``import`` and ``export`` (format registry).

Board datasets (``tofmetry import iai-kinect2``) are calibrated with ``tofmetry calibrate depth``,
which dispatches to board mode when the folder holds ``board.json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from tofmetry.cli._common import console, progress


def _formats(kind: str) -> str:
    from tofmetry.io.registry import EXPORTERS, IMPORTERS

    table = IMPORTERS if kind == "import" else EXPORTERS
    return "; ".join(f"{f.name}: {f.description}" for f in table.values())


def register(app: typer.Typer) -> None:
    """Add this module's commands to the main app."""

    @app.command("import", help="Import a recording from another tool into tofmetry's data contract. "
                 "FORMAT is one of: iai-kinect2, azure-kinect, tum, open3d.")
    def import_cmd(
        fmt: str = typer.Argument(..., metavar="FORMAT", help="iai-kinect2 | azure-kinect | tum | open3d"),
        src: Path = typer.Argument(..., help="Source folder or file (.mkv for azure-kinect)."),
        out: Path = typer.Option(..., "-o", "--out", help="New dataset / capture folder."),
        board: Optional[str] = typer.Option(None, "--board", help="iai-kinect2: inner corners COLSxROWS, e.g. 5x7."),
        square_mm: Optional[float] = typer.Option(None, "--square-mm", help="iai-kinect2: square size [mm]."),
        depth_scale: Optional[float] = typer.Option(None, "--depth-scale",
                                                    help="tum/open3d: depth units per metre (TUM 5000, Open3D 1000)."),
        max_frames: Optional[int] = typer.Option(None, "--max-frames", help="Import at most this many frames."),
        intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="tum/open3d: intrinsics.json of the depth camera."),
        force: bool = typer.Option(False, "--force", help="Replace an existing output."),
    ) -> None:
        from tofmetry.io.registry import get_importer

        fn = get_importer(fmt)
        opts = {"board": board, "square_mm": square_mm, "depth_scale": depth_scale, "max_frames": max_frames,
                "intrinsics": intrinsics}
        with progress(f"import {fmt}", None) as advance:
            summary = fn(src, out, force=force, progress=advance, **{k: v for k, v in opts.items() if v is not None})
        console.print(f"[green]imported[/] {src} -> {out}")
        for k, v in summary.items():
            if k != "calibration" and not isinstance(v, (dict, list)):
                console.print(f"  {k}: {v}")
        for note in summary.get("notes", []):
            console.print(f"  note: {note}")

    @app.command("export", help="Export to another tool's format. FORMAT is one of: iai-kinect2 "
                 "(calibration -> calib_ir.yaml + calib_depth.yaml), e57 (PLY -> E57), ply (E57 -> PLY).")
    def export_cmd(
        fmt: str = typer.Argument(..., metavar="FORMAT", help="iai-kinect2 | e57 | ply"),
        src: Path = typer.Argument(..., help="Calibration (.npz / intrinsics.json / imported folder) or point cloud."),
        out: Path = typer.Option(..., "-o", "--out", help="Output folder (iai-kinect2) or file."),
        depth_shift_mm: Optional[float] = typer.Option(None, "--depth-shift-mm", help="iai-kinect2: depthShift to write [mm]."),
        force: bool = typer.Option(False, "--force", help="Replace existing output."),
    ) -> None:
        from tofmetry.io.registry import get_exporter

        fn = get_exporter(fmt)
        opts = {"depth_shift_mm": depth_shift_mm}
        summary = fn(src, out, force=force, **{k: v for k, v in opts.items() if v is not None})
        console.print(f"[green]exported[/] {src} -> {out}")
        for k, v in summary.items():
            console.print(f"  {k}: {v}")
