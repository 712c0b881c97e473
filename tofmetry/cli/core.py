"""CLI commands: info, cloud, demo."""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path
from typing import Optional

import typer

from tofmetry.cli._common import ACCEPT_IMPLAUSIBLE_HELP, console, load_intrinsics_option, print_plausibility, progress


def info(capture: Path = typer.Argument(..., help="Capture folder (capture.json + depth/) or a depth calibration "
                                         "file (.npz).")) -> None:
    """Validate a capture and print a summary (frames, valid fraction, depth range), or describe a
    depth calibration: its model, support and its own predicted error on new data."""
    import warnings

    import numpy as np
    from rich.markup import escape

    from tofmetry.errors import FormatError, TofmetryError
    from tofmetry.io import Capture, EmptyFrameWarning

    if capture.is_file() and capture.suffix.lower() == ".npz":
        _info_calibration(capture)
        return
    cap = Capture(capture)
    intr, src = cap.intrinsics()
    n = len(cap)
    vf, lo, hi, bad = [], np.inf, 0, []
    with warnings.catch_warnings(), progress("reading every frame", n) as adv:
        warnings.simplefilter("ignore", EmptyFrameWarning)   # counted below as 0 % valid
        for i in range(n):                                   # every frame: a validation reads them all
            try:
                d = cap.depth(i)
                if cap.has_ir:
                    cap.ir(i)
            except TofmetryError as exc:
                bad.append(str(exc))
                adv()
                continue
            v = d[d > 0]
            vf.append(v.size / d.size)
            if v.size:
                lo, hi = min(lo, int(v.min())), max(hi, int(v.max()))
            adv()
    if bad:
        raise FormatError(f"{cap.path}: {len(bad)} of {n} frames cannot be read: " + "; ".join(bad[:5])
                          + (" ..." if len(bad) > 5 else ""))
    console.print(f"[bold]{escape(str(cap.path))}[/]: valid capture (all {n} frames read)", highlight=False)
    console.print(f"  sensor        {cap.sensor}")
    console.print(f"  frames        {n} of {cap.shape[1]}x{cap.shape[0]} (IR: {'yes' if cap.has_ir else 'no'}, colour: {'yes' if cap.has_color else 'no'})")
    console.print(f"  intrinsics    fx={intr.fx:.2f} fy={intr.fy:.2f} cx={intr.cx:.2f} cy={intr.cy:.2f} ({src})")
    console.print(f"  valid pixels  {np.mean(vf) * 100:.1f} % (mean over the {len(vf)} frames)")
    if hi > 0:
        console.print(f"  depth range   {lo} .. {hi} mm")
    ts = cap.timestamps_s
    if ts is not None and len(ts) > 1:
        console.print(f"  timestamps    {ts[0]:.1f} .. {ts[-1]:.1f} s")


def _info_calibration(path: Path) -> None:
    from tofmetry.cli.calibrate import print_prediction
    from tofmetry.pipelines import load_calibration

    cal = load_calibration(path)
    i = cal.intrinsics
    console.print(f"[bold]{path}[/]: depth calibration ({cal.provenance.get('method', 'wall')})")
    console.print(f"  sensor        {cal.sensor}, {cal.shape[1]}x{cal.shape[0]}")
    console.print(f"  intrinsics    fx={i.fx:.2f} fy={i.fy:.2f} cx={i.cx:.2f} cy={i.cy:.2f}")
    console.print(f"  model         {cal.diagnostics.get('model', cal.surface_model)}")
    console.print(f"  offset        {cal.offset_mm:+.2f} mm (constant part of the correction on the axis)")
    if cal.provenance.get("created_utc"):
        console.print(f"  created       {cal.provenance['created_utc']} by {cal.provenance.get('tool', '?')}")
    board = (cal.prediction or {}).get("board")
    if board:
        console.print("predicted error on new board poses (blocked validation), [90 % interval]:")
        for key in ("rms_mm", "p95_abs_mm", "mean_mm"):
            if key in board:
                iv = board.get(f"{key}_interval", [float("nan"), float("nan")])
                console.print(f"  {key:>12}: {board[key]:.2f} mm  [{iv[0]:.2f}, {iv[1]:.2f}]")
    print_prediction(cal)
    if not cal.prediction:
        console.print("[yellow]no predicted error stored[/] (a calibration written before tofmetry validated "
                      "its own calibrations, or fitted without validation)")


def cloud(
    capture: Path = typer.Argument(..., help="Capture folder."),
    output: Path = typer.Option(..., "-o", "--output", help="Output PLY (metres)."),
    average: bool = typer.Option(False, "--average", help="Average all frames (robust temporal mean) first."),
    intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="intrinsics.json overriding the capture's."),
    calibration: Optional[Path] = typer.Option(None, "--calibration", help="Depth calibration file to apply."),
    color: bool = typer.Option(False, "--color", help="Colour from colour frames (else IR amplitude)."),
    frame: int = typer.Option(0, "--frame", help="Frame index when not averaging."),
    no_undistort: bool = typer.Option(False, "--no-undistort", help="Plain pinhole back-projection."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing output."),
    accept_implausible: bool = typer.Option(False, "--accept-implausible", help=ACCEPT_IMPLAUSIBLE_HELP),
) -> None:
    """Write the point cloud of a capture as binary PLY (metres, camera frame)."""
    from tofmetry.pipelines.cloud import capture_cloud

    with progress("loading frames", None) if average else nullcontext(None) as adv:
        run = capture_cloud(capture, output, average=average, calibration=calibration,
                            intrinsics=load_intrinsics_option(intrinsics), color=color, frame=frame,
                            undistort=not no_undistort, force=force, advance=adv,
                            accept_implausible=accept_implausible)
    console.print(f"wrote {len(run.points)} points to {output} (intrinsics: {run.intrinsics_source})")
    if run.color_summary:
        c = run.color_summary
        console.print(f"coloured {c['colored']} points ({100 * c['share_colored']:.1f} %): {c['occluded']} hidden from "
                      f"the colour camera and {c['out_of_view']} outside its view have no colour "
                      f"(colour calibration: {c['calibration']})")
    print_plausibility(run.plausibility)
    if run.outside_support:
        from tofmetry.cli.calibrate import _outside_how
        from tofmetry.pipelines import load_calibration

        console.print(f"[yellow]warning:[/] {run.outside_support} points ({100 * run.outside_support / max(1, len(run.points)):.1f} %) "
                      f"lie outside the calibration's support; {_outside_how(load_calibration(calibration))}")


def register(app: typer.Typer) -> None:
    """Add info and cloud (demo is added by the study module)."""
    app.command("info")(info)
    app.command("cloud")(cloud)
