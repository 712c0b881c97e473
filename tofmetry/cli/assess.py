"""CLI commands: ``assess warmup|noise|materials|outdoor`` and ``filter`` (flying pixels).

Each assessment writes ``<analysis>.json`` and its PNG figures into the output folder and
prints a short table. Thin layer over :mod:`tofmetry.assess`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from tofmetry._shared.study_constants import BLACK_AMPLITUDE_RATIO
from tofmetry.cli._common import console, load_intrinsics_option, progress, refuse_existing
from tofmetry.errors import InputError

_FORCE = typer.Option(False, "--force", help="Replace the files of an existing, non-empty output folder.")

assess_app = typer.Typer(help="Sensor assessment (study §3): warm-up, noise, materials, outdoor/flying pixels.",
                         rich_markup_mode=None,
                         no_args_is_help=True)


def _refuse_inside(out: Path, capture: Path) -> None:
    from tofmetry.pipelines.paths import refuse_inside_inputs

    refuse_inside_inputs(out, capture)


def _open(capture: Path):
    from tofmetry.io import Capture

    return Capture(capture)


def _finish(result, out: Path, name: str, rows: list[tuple[str, str]], **kwargs) -> None:
    from tofmetry.pipelines.assess import write_assessment

    files = write_assessment(result, out, f"{name}.json", **kwargs)
    if "cloud" in files:
        rows = [*rows, ("cloud", str(files["cloud"]))]
    table = Table(title=f"{name} assessment")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    for k, v in rows:
        table.add_row(k, v)
    console.print(table)
    for n in getattr(result, "notes", []) or []:
        console.print(f"[yellow]note:[/] {n}")
    console.print(f"wrote {files['json']} and {len(files['figures'])} figure(s) in {out}")


def _fmt(x, spec=".2f", unit="") -> str:
    if x is None or x != x:
        return "—"
    return f"{x:{spec}}{unit}"


@assess_app.command("warmup")
def warmup(capture: Path = typer.Argument(..., help="Capture of a static wall with timestamps_s."),
           out: Path = typer.Option(..., "-o", "--out", help="Output folder (JSON + PNG)."),
           patch: int = typer.Option(10, "--patch", help="Side of the followed patch [px]."),
           tolerance_mm: float = typer.Option(1.0, "--tolerance-mm", help="Stability tolerance around the final level [mm]."),
           smooth_s: Optional[float] = typer.Option(None, "--smooth-s", help="Smoothing window [s] (default max(120, 5 intervals))."),
           final_window_s: float = typer.Option(600.0, "--final-window-s", help="Final level = median over this last stretch [s]."),
           force: bool = _FORCE,
           ) -> None:
    """Warm-up drift: mean distance of the brightest patch against operating time."""
    from tofmetry.assess import assess_warmup

    refuse_existing([out], force)
    _refuse_inside(out, capture)
    cap = _open(capture)
    with progress("warm-up frames", len(cap)) as adv:
        res = assess_warmup(cap, patch=patch, tolerance_mm=tolerance_mm, smooth_window_s=smooth_s,
                            final_window_s=final_window_s, progress=adv)
    ts = res.stabilisation_time_s
    _finish(res, out, "warmup", [
        ("frames / duration", f"{len(res.time_s)} / {res.time_s[-1] / 60:.1f} min"),
        ("patch (u0, v0, size)", f"{res.patch} ({res.patch_source})"),
        ("stabilisation time", "not reached" if ts is None else f"{ts / 60:.1f} min"),
        ("  at 1.1x / 0.9x tolerance", " / ".join("not reached" if x is None else f"{x / 60:.1f} min"
                                                  for x in res.stabilisation_range_s)),
        ("total drift", _fmt(res.total_drift_mm, "+.2f", " mm")),
        ("drift range", _fmt(res.drift_range_mm, ".2f", " mm")),
        ("residual drift after stabilisation (p-p)", _fmt(res.residual_drift_mm, ".2f", " mm")),
        *([("drift per degree of the " + str(res.temperature_name) + " temperature",
            f"{res.temperature_fit['slope_mm_per_c']:+.3f} ± {res.temperature_fit['slope_se_mm_per_c']:.3f} mm/°C")]
          if res.temperature_fit else []),
    ])


@assess_app.command("noise")
def noise(capture: Path = typer.Argument(..., help="Capture of N >= 2 frames of a static scene (100 recommended)."),
          out: Path = typer.Option(..., "-o", "--out", help="Output folder (JSON + PNG)."),
          row: Optional[int] = typer.Option(None, "--row", help="Image row of the std profile (default: middle)."),
          force: bool = _FORCE,
          ) -> None:
    """Temporal noise: std maps for 10/25/50/100 frames, row profile, precision of averaging."""
    from tofmetry.assess import assess_noise

    refuse_existing([out], force)
    _refuse_inside(out, capture)
    cap = _open(capture)
    with progress("noise frames", len(cap)) as adv:
        res = assess_noise(cap, row=row, progress=adv)
    rows = [(f"n = {s.n}", f"median {s.median_mm:.2f} mm, spread {s.spread_mm:.2f} mm, corner/centre {s.corner_centre_ratio:.2f}")
            for s in res.summaries]
    rows.append(("single-frame sigma", _fmt(res.sigma_single_mm, ".2f", " mm")))
    rows += [(f"std of {b['n']}-frame mean", f"{b['std_of_mean_mm']:.3f} mm (σ/√n = {b['expected_mm']:.3f})")
             for b in res.block_precision]
    rows.append(("recommended n", f"{res.recommended_n} ({res.recommendation_reason})"))
    _finish(res, out, "noise", rows)


@assess_app.command("materials")
def materials(capture: Path = typer.Argument(..., help="Capture (depth + IR) of a sample board."),
              out: Path = typer.Option(..., "-o", "--out", help="Output folder (JSON + PNG)."),
              regions: Optional[Path] = typer.Option(None, "--regions", help='regions.json {"regions": [{"name", "rect": [u0, v0, u1, v1], "reference"}]}.'),
              auto_grey_board: bool = typer.Option(False, "--auto-grey-board", help="Find the squares of a grey-level checkerboard from IR."),
              intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="intrinsics.json overriding the capture's."),
              force: bool = _FORCE,
              ) -> None:
    """Materials/intensity: amplitude and depth bias per sample, amplitude-bias fit."""
    from tofmetry.assess import assess_materials, regions_from_dict
    from tofmetry.io import read_json

    if (regions is None) == (not auto_grey_board):
        raise InputError("materials: give exactly one of --regions regions.json or --auto-grey-board")
    refuse_existing([out], force)
    _refuse_inside(out, capture)
    cap = _open(capture)
    intr, _ = cap.intrinsics(load_intrinsics_option(intrinsics))
    regs = None
    if regions is not None:
        regs = regions_from_dict(read_json(regions, "regions"), cap.shape, str(regions))
    with progress("materials frames", len(cap)) as adv:
        res = assess_materials(cap, regs, intr=intr, auto_grey_board=auto_grey_board, progress=adv)
    rows = [(r.name + (" (ref)" if r.reference else "") + (" \\[erratic]" if r.erratic else ""),
             f"A={r.amplitude:.0f}  bias={r.bias_mm:+.1f} mm  std={r.spatial_std_mm:.1f} mm") for r in res.regions]
    rows.append(("fit slope", f"{_fmt(res.slope_mm_per_ln)} ± {_fmt(res.slope_se_mm_per_ln)} mm per ln(A_ref/A)"))
    rows.append(("bias at 1/6 amplitude", _fmt(res.predicted_bias_mm(BLACK_AMPLITUDE_RATIO), "+.1f", " mm")))
    _finish(res, out, "materials", rows)


@assess_app.command("outdoor")
def outdoor(capture: Path = typer.Argument(..., help="Capture (strong light)."),
            out: Path = typer.Option(..., "-o", "--out", help="Output folder (JSON + PNG + PLY)."),
            frame: int = typer.Option(0, "--frame", help="Frame shown in the figure and exported as PLY."),
            intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="intrinsics.json overriding the capture's."),
            force: bool = _FORCE,
            ) -> None:
    """Valid fraction and flying pixels; coloured cloud (flying in red) as PLY, profile view PNG."""
    from tofmetry.assess import assess_outdoor

    refuse_existing([out], force)
    _refuse_inside(out, capture)
    cap = _open(capture)
    intr, _ = cap.intrinsics(load_intrinsics_option(intrinsics))
    if not 0 <= frame < len(cap):
        raise typer.BadParameter(f"--frame {frame} outside 0..{len(cap) - 1}", param_hint="--frame")
    with progress("outdoor frames", len(cap)) as adv:
        res = assess_outdoor(cap, intr=intr, frame=frame, progress=adv)
    _finish(res, out, "outdoor", [
        ("maximal points (H x W)", f"{res.n_max}"),
        ("valid points (mean)", f"{res.valid.mean():.0f} ({res.valid_fraction * 100:.1f} %)"),
        ("flying pixels (mean)", f"{res.flying.mean():.0f} ({res.flying_share * 100:.2f} % of the cloud)"),
    ], intrinsics=intr, cloud_ply="outdoor_cloud.ply")


def filter_cmd(capture: Path = typer.Argument(..., help="Input capture (not modified)."),
               out: Path = typer.Option(..., "-o", "--out", help="New capture folder with flying pixels set to 0."),
               sigma_1m_mm: float = typer.Option(1.5, "--sigma-1m-mm", help="Depth noise at 1 m / at white amplitude [mm]."),
               k_noise: float = typer.Option(3.0, "--k-noise", help="Noise sigmas allowed between neighbours."),
               theta_max_deg: float = typer.Option(60.0, "--theta-max-deg", help="Steepest incidence still one surface [deg]."),
               force: bool = typer.Option(False, "--force", help="Replace an existing output capture."),
               intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="intrinsics.json overriding the capture's."),
               ) -> None:
    """Remove flying pixels: writes a new capture with them set to 0 (IR and colour copied)."""
    from tofmetry.assess import FlyingPixelParams
    from tofmetry.pipelines.flying import filter_capture

    cap = _open(capture)
    p = FlyingPixelParams(sigma_1m_mm=sigma_1m_mm, k_noise=k_noise, theta_max_deg=theta_max_deg)
    with progress("filtering frames", len(cap)) as adv:
        run = filter_capture(cap, out, p, intrinsics=load_intrinsics_option(intrinsics), force=force, advance=adv)
    console.print(f"wrote {out}: {run.n_frames} frames, removed {run.removed} flying pixels "
                  f"({run.removed_share * 100:.2f} % of the valid points)")


def register(app: typer.Typer) -> None:
    """Add ``assess ...`` and ``filter``."""
    app.add_typer(assess_app, name="assess")
    app.command("filter")(filter_cmd)
