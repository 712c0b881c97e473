"""CLI commands: info, cloud, demo."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from tofmetry.cli._common import console, load_intrinsics_option, progress


def info(capture: Path = typer.Argument(..., help="Capture folder (capture.json + depth/).")) -> None:
    """Validate a capture and print a summary: frames, valid fraction, depth range."""
    import numpy as np

    from tofmetry.io import Capture

    cap = Capture(capture)
    intr, src = cap.intrinsics()
    n = len(cap)
    vf, lo, hi = [], np.inf, 0
    step = max(1, n // 20)
    for i in range(0, n, step):
        d = cap.depth(i)
        v = d[d > 0]
        vf.append(v.size / d.size)
        if v.size:
            lo, hi = min(lo, int(v.min())), max(hi, int(v.max()))
    console.print(f"[bold]{cap.path}[/]: valid capture")
    console.print(f"  sensor        {cap.sensor}")
    console.print(f"  frames        {n} of {cap.shape[1]}x{cap.shape[0]} (IR: {'yes' if cap.has_ir else 'no'}, colour: {'yes' if cap.has_color else 'no'})")
    console.print(f"  intrinsics    fx={intr.fx:.2f} fy={intr.fy:.2f} cx={intr.cx:.2f} cy={intr.cy:.2f} ({src})")
    console.print(f"  valid pixels  {np.mean(vf) * 100:.1f} % (mean over {len(vf)} sampled frames)")
    if hi > 0:
        console.print(f"  depth range   {lo} .. {hi} mm")
    ts = cap.timestamps_s
    if ts is not None and len(ts) > 1:
        console.print(f"  timestamps    {ts[0]:.1f} .. {ts[-1]:.1f} s")


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
) -> None:
    """Write the point cloud of a capture as binary PLY (metres, camera frame)."""
    import numpy as np

    from tofmetry.errors import InputError
    from tofmetry.io import Capture, write_ply
    from tofmetry.pointcloud import amplitude_colors, depth_to_points, robust_mean_depth, sample_colors

    if output.exists() and not force:
        raise InputError(f"output {output} exists; pass --force to overwrite it")
    cap = Capture(capture)
    intr, src = cap.intrinsics(load_intrinsics_option(intrinsics))
    if average:
        with progress("loading frames", len(cap)) as adv:
            stack = cap.depth_stack(advance=adv)
        depth = robust_mean_depth(stack)
    else:
        if not 0 <= frame < len(cap):
            raise typer.BadParameter(f"--frame {frame} outside 0..{len(cap) - 1}", param_hint="--frame")
        depth = cap.depth(frame).astype(np.float64)
    if calibration is not None:
        from tofmetry.calibrate import apply_depth_calibration, load_calibration

        cal = load_calibration(calibration)
        cal.check_compatible(sensor=cap.sensor, shape=cap.shape)
        if intrinsics is None:
            intr, src = cal.intrinsics, "calibration"
        depth = apply_depth_calibration(depth, cal)
    pts, idx = depth_to_points(depth, intr, undistort=not no_undistort, return_index=True)
    cols = None
    if color and cap.has_color:
        from tofmetry.sensor import get_profile

        prof = get_profile(cap.sensor)
        cols, _ = sample_colors(pts, cap.color(frame), prof.color, prof.ir_to_color)
    elif cap.has_ir:
        ir = cap.ir_mean() if average else cap.ir(frame)
        cols = amplitude_colors(ir.ravel()[idx])
    write_ply(output, pts, colors=cols)
    console.print(f"wrote {len(pts)} points to {output} (intrinsics: {src})")


def register(app: typer.Typer) -> None:
    """Add info and cloud (demo is added by the study module)."""
    app.command("info")(info)
    app.command("cloud")(cloud)
