"""CLI command ``calibrate stereo``: IR–colour extrinsics from paired board images."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from tofmetry.cli._common import console, load_intrinsics_option, progress, refuse_existing


def stereo_cmd(
    pairs_dir: Path = typer.Argument(..., help="Folder of paired board images NNNN_ir.<ext> and NNNN_color.<ext>."),
    board: str = typer.Option(..., "--board", help="Inner corners COLSxROWS, e.g. 9x6."),
    square_mm: float = typer.Option(..., "--square-mm", help="Square size [mm]."),
    output: Path = typer.Option(..., "-o", "--output", help="Folder for calib_pose.yaml and stereo.json."),
    ir_intrinsics: Optional[Path] = typer.Option(None, "--ir-intrinsics", help="IR intrinsics.json (default: the "
                                                 "sensor profile's typical values)."),
    color_intrinsics: Optional[Path] = typer.Option(None, "--color-intrinsics", help="Colour intrinsics.json "
                                                    "(default: the sensor profile's typical values)."),
    sensor: str = typer.Option("kinect_v2", "--sensor", help="Sensor profile for intrinsics not given."),
    force: bool = typer.Option(False, "--force", help="Overwrite the outputs."),
) -> None:
    """Estimate the IR -> colour extrinsics (intrinsics held fixed) with uncertainties, validate them
    on held-out pairs (every 4th) and export iai_kinect2's calib_pose.yaml."""
    from tofmetry.io.board_dataset import BoardSpec
    from tofmetry.pipelines.stereo import list_pairs, stereo_from_images, write_stereo_outputs
    from tofmetry.sensor import get_profile

    spec = BoardSpec.parse(board, square_mm)
    refuse_existing([output / "calib_pose.yaml", output / "stereo.json"], force)
    prof = get_profile(sensor)
    ir = load_intrinsics_option(ir_intrinsics) or prof.depth
    color = load_intrinsics_option(color_intrinsics) or prof.color
    with progress("detect corners in pairs, calibrate", len(list_pairs(pairs_dir))) as adv:
        run = stereo_from_images(pairs_dir, spec.size, spec.square_mm, ir, color, advance=adv)
    for stem, why in run.skipped.items():
        console.print(f"[yellow]pair {stem} not used:[/] {why}")
    r = run.result
    e = r.extrinsics
    console.print(f"IR -> colour from {r.n_train} pairs (fit RMS {r.rms_px:.3f} px), validated on {r.n_heldout} held-out "
                  f"pairs: colour reprojection {r.heldout_rms_px:.3f} px RMS (max {r.heldout_max_px:.3f} px)")
    console.print("translation (mm): " + ", ".join(f"{1e3 * v:.2f} ± {s:.2f}" for v, s in zip(e.translation, r.translation_std_mm)))
    console.print("rotation std (deg): " + ", ".join(f"{s:.3f}" for s in r.rotation_std_deg)
                  + f" (angle {r.diagnostics['rotation_deg']:.3f} deg)")
    for p in write_stereo_outputs(run, output):
        console.print(f"wrote {p}")
