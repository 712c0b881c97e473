"""CLI commands ``calibrate stereo`` (IR–colour extrinsics from paired board images) and ``calibrate rig``
(extrinsics of several sensors seeing common board poses)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from tofmetry.cli._common import (
    BOARD_HELP, DICTIONARY_HELP, MARKER_HELP, SQUARES_HELP, console, load_intrinsics_option, parse_board, progress,
    refuse_existing,
)

def stereo_cmd(
    pairs_dir: Path = typer.Argument(..., help="Folder of paired board images NNNN_ir.<ext> and NNNN_color.<ext>."),
    board: str = typer.Option(..., "--board", help=BOARD_HELP),
    square_mm: float = typer.Option(..., "--square-mm", help="Square size [mm]."),
    output: Path = typer.Option(..., "-o", "--output", help="Folder for calib_pose.yaml and stereo.json."),
    squares: str = typer.Option("13x10", "--squares", help=SQUARES_HELP),
    marker_mm: float = typer.Option(56.0, "--marker-mm", help=MARKER_HELP),
    dictionary: str = typer.Option("DICT_4X4_100", "--dictionary", help=DICTIONARY_HELP),
    ir_intrinsics: Optional[Path] = typer.Option(None, "--ir-intrinsics", help="IR intrinsics.json (default: the "
                                                 "sensor profile's typical values)."),
    color_intrinsics: Optional[Path] = typer.Option(None, "--color-intrinsics", help="Colour intrinsics.json "
                                                    "(default: the sensor profile's typical values)."),
    sensor: str = typer.Option("kinect_v2", "--sensor", help="Sensor profile for intrinsics not given."),
    force: bool = typer.Option(False, "--force", help="Overwrite the outputs."),
) -> None:
    """Estimate the IR -> colour extrinsics (intrinsics held fixed) with uncertainties, validate them
    on held-out pairs (every 4th) and export iai_kinect2's calib_pose.yaml. With --board charuco,
    pairs showing part of the board count (the corners both images found)."""
    from tofmetry.pipelines.stereo import list_pairs, stereo_from_images, write_stereo_outputs
    from tofmetry.sensor import get_profile

    spec, charuco = parse_board(board, square_mm, squares, marker_mm, dictionary)
    refuse_existing([output / "calib_pose.yaml", output / "stereo.json"], force)
    prof = get_profile(sensor)
    ir = load_intrinsics_option(ir_intrinsics) or prof.depth
    color = load_intrinsics_option(color_intrinsics) or prof.color
    with progress("detect corners in pairs, calibrate", len(list_pairs(pairs_dir))) as adv:
        run = stereo_from_images(pairs_dir, spec.size, spec.square_mm, ir, color, advance=adv, charuco=charuco)
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


def rig_cmd(
    rig_dir: Path = typer.Argument(..., help="Rig folder: one sub-folder per sensor, each with intrinsics.json and "
                                   "board images; the same image name in two sub-folders = the same board pose. The "
                                   "first sub-folder (by name) is the rig frame."),
    board: str = typer.Option(..., "--board", help=BOARD_HELP),
    square_mm: float = typer.Option(..., "--square-mm", help="Square size [mm]."),
    output: Path = typer.Option(..., "-o", "--output", help="rig.json to write."),
    squares: str = typer.Option("13x10", "--squares", help=SQUARES_HELP),
    marker_mm: float = typer.Option(56.0, "--marker-mm", help=MARKER_HELP),
    dictionary: str = typer.Option("DICT_4X4_100", "--dictionary", help=DICTIONARY_HELP),
    force: bool = typer.Option(False, "--force", help="Overwrite the output."),
) -> None:
    """Estimate the extrinsics of every sensor of a rig relative to the first (intrinsics held fixed),
    with jackknife uncertainties and held-out validation (every 4th shared view); writes rig.json."""
    import numpy as np

    from tofmetry.pipelines.rig import rig_from_folders, write_rig_outputs

    spec, charuco = parse_board(board, square_mm, squares, marker_mm, dictionary)
    refuse_existing([output], force)
    with progress("detect corners in every sensor's images, calibrate", None) as adv:
        run = rig_from_folders(rig_dir, spec.size, spec.square_mm, advance=adv, charuco=charuco)
    for name, why in run.skipped.items():
        console.print(f"[yellow]{name}: views not used:[/] " + ", ".join(f"{k} ({v})" for k, v in why.items()))
    console.print(f"rig frame: {run.sensors[0]} ({run.result.shared_views[0]} views with a board)")
    for k in range(1, len(run.sensors)):
        p = run.result.pairs[k]
        e = run.result.extrinsics[k]
        ang = float(np.degrees(np.arccos(np.clip((np.trace(e.rotation) - 1) / 2, -1, 1))))
        console.print(f"{run.sensors[k]}: {run.result.shared_views[k]} shared views (fit RMS {p.rms_px:.3f} px, held-out "
                      f"{p.heldout_rms_px:.3f} px RMS, max {p.heldout_max_px:.3f} px)")
        console.print("  translation rig -> sensor (mm): " + ", ".join(
            f"{1e3 * v:.2f} ± {s:.2f}" for v, s in zip(e.translation, p.translation_std_mm))
            + f"; rotation {ang:.3f} deg, std " + ", ".join(f"{s:.3f}" for s in p.rotation_std_deg) + " deg")
    console.print(f"wrote {write_rig_outputs(run, output)}")
