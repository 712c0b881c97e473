"""CLI commands: ``tofmetry simulate {wall,wall-dataset,checkerboard,charuco,board-dataset,scan,warmup,noise,materials,outdoor}``.

Every command writes a simulated dataset folder (contract captures + truth files at the
root) and refuses to overwrite an existing folder without ``--force``. ``--sensor random``
draws a whole Kinect-v2-class sensor (lens and errors) from ``--seed``
(:func:`tofmetry.simulate.family.random_sensor`); ``truth.json`` records the draw.
"""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from tofmetry.cli._common import console, progress

#: Default ``--tilt-jitter-deg`` of ``wall-dataset --sensor random`` [deg] (walls are never exactly frontal).
RANDOM_TILT_JITTER_DEG = 1.5

sim_app = typer.Typer(name="simulate", help="Simulated Kinect v2 datasets (virtual sensor with the paper's errors).",
                      rich_markup_mode=None,
                      no_args_is_help=True)

_OUT = typer.Option(..., "-o", "--output", help="Output folder (refused if it exists, unless --force).")
_SEED = typer.Option(0, "--seed", help="Random seed (same seed = same data).")
_NOERR = typer.Option(False, "--no-errors", help="Ideal sensor: every error term off except mm quantisation.")
_WITHOUT = typer.Option(None, "--without", help="Switch an error term off (repeatable): wiggling, deformation, "
                        "amplitude_bias, noise, flying, invalid, warmup, mounting_offset.")
_FORCE = typer.Option(False, "--force", help="Replace an existing output folder.")
_SENSOR = typer.Option("kinect_v2", "--sensor", help="kinect_v2: the simulator's Kinect v2; random: a whole "
                       "Kinect-v2-class sensor (lens + errors) drawn from --seed (recorded in truth.json).")


def _sensor(sensor: str, seed: int, no_errors: bool = False, without: Optional[List[str]] = None):
    """The SensorDraw of ``--sensor`` / ``--seed`` with ``--no-errors`` / ``--without`` applied."""
    from tofmetry.simulate.family import sensor_by_kind

    draw = sensor_by_kind(sensor, seed)
    em = draw.errors
    if no_errors:
        em = em.without(*(em.enabled - {"quantize"}))
    if without:
        if "quantize" in without:
            from tofmetry.errors import InputError

            raise InputError("--without quantize: dataset files hold whole millimetres (uint16); quantisation cannot be off")
        em = em.without(*without)
    return draw.with_errors(em)


def _done(path: Path, what: str) -> None:
    console.print(f"[green]wrote[/] {what}: {path}  (truth files at the folder root; processing must not read them)")


@sim_app.command("wall")
def wall(output: Path = _OUT, distance_mm: float = typer.Option(1000.0, "--distance-mm", help="Optical centre to wall [mm]."),
         frames: int = typer.Option(50, "--frames", help="Number of frames."),
         tilt_x: float = typer.Option(0.0, "--tilt-x", help="Wall tilt about x [deg]."),
         tilt_y: float = typer.Option(0.0, "--tilt-y", help="Wall tilt about y [deg]."),
         seed: int = _SEED, no_errors: bool = _NOERR, without: Optional[List[str]] = _WITHOUT,
         sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """A single wall capture at one distance: OUTPUT/capture + OUTPUT/truth.json."""
    from tofmetry.simulate import datasets

    draw = _sensor(sensor, seed, no_errors, without)
    with progress("simulating wall frames", frames) as adv:
        p = datasets.wall_capture(output, distance_mm, frames, None, seed, (tilt_x, tilt_y),
                                  force=force, progress=adv, sensor=draw)
    _done(p, "wall capture (capture/ sub-folder)")


@sim_app.command("wall-dataset")
def wall_dataset(output: Path = _OUT,
                 distance_mm: Optional[List[float]] = typer.Option(None, "--distance-mm",
                                                                   help="Station distance [mm] (repeatable); default 800, 1000..4500 every 250."),
                 frames: int = typer.Option(50, "--frames", help="Frames per station."),
                 tilt_x: float = typer.Option(0.0, "--tilt-x", help="Wall tilt about x [deg]."),
                 tilt_y: float = typer.Option(0.0, "--tilt-y", help="Wall tilt about y [deg]."),
                 tilt_jitter_deg: Optional[float] = typer.Option(
                     None, "--tilt-jitter-deg", help="Random extra wall tilt per station, up to this angle [deg] "
                     "(drawn from --seed); default 0 for --sensor kinect_v2, 1.5 for random."),
                 seed: int = _SEED, no_errors: bool = _NOERR, without: Optional[List[str]] = _WITHOUT,
                 sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """Wall dataset for depth calibration: stations.csv + one capture per station (paper §4.2)."""
    from tofmetry.simulate import datasets

    draw = _sensor(sensor, seed, no_errors, without)
    jitter = tilt_jitter_deg if tilt_jitter_deg is not None else (0.0 if sensor == "kinect_v2" else RANDOM_TILT_JITTER_DEG)
    dists = sorted(distance_mm) if distance_mm else list(datasets.DEFAULT_DISTANCES_MM)
    with progress(f"simulating {len(dists)} stations", frames * len(dists)) as adv:
        p = datasets.wall_dataset(output, dists, frames, None, seed, (tilt_x, tilt_y),
                                  force=force, progress=adv, sensor=draw, tilt_jitter_deg=jitter)
    _done(p, f"wall dataset ({len(dists)} stations)")


@sim_app.command("checkerboard")
def checkerboard(output: Path = _OUT, images: int = typer.Option(20, "--images", help="Number of IR images."),
                 cols: int = typer.Option(9, "--cols", help="Inner corners along a row."),
                 rows: int = typer.Option(6, "--rows", help="Inner corners along a column."),
                 square_mm: float = typer.Option(50.0, "--square-mm", help="Square size [mm] (default: the simulated board's 50 mm)."),
                 seed: int = _SEED, sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """IR images of a checkerboard for intrinsic calibration (+ board.json, truth.json)."""
    from tofmetry.simulate import datasets

    draw = _sensor(sensor, seed)
    with progress("rendering checkerboard images", images) as adv:
        p = datasets.checkerboard_images(output, images, (cols, rows), square_mm, seed, force=force, progress=adv,
                                         sensor=draw)
    _done(p, f"{images} checkerboard IR images")


@sim_app.command("charuco")
def charuco(output: Path = _OUT, images: int = typer.Option(10, "--images", help="Number of IR images."),
            seed: int = _SEED, sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """IR images of a ChArUco board (13x10 squares of 80 mm, 56 mm DICT_4X4_100 markers), partial views
    included, for intrinsic calibration (+ board.json, truth.json)."""
    from tofmetry.simulate import datasets

    draw = _sensor(sensor, seed)
    with progress("rendering ChArUco images", images) as adv:
        p = datasets.charuco_images(output, images, None, seed, force=force, progress=adv, sensor=draw)
    _done(p, f"{images} ChArUco IR images")


@sim_app.command("board-dataset")
def board_dataset(output: Path = _OUT, board: str = typer.Option("charuco", "--board", help="charuco (13x10 squares "
                                                                 "of 80 mm, 56 mm DICT_4X4_100 markers; partial views) "
                                                                 "or checkerboard (9x6 inner corners of 50 mm)."),
                  poses: int = typer.Option(20, "--poses", help="Number of board poses (one capture each)."),
                  min_distance_m: float = typer.Option(0.6, "--min-distance-m", help="Nearest board distance [m]."),
                  max_distance_m: float = typer.Option(1.3, "--max-distance-m", help="Farthest board distance [m]."),
                  frames: int = typer.Option(1, "--frames", help="Frames per pose."),
                  seed: int = _SEED, no_errors: bool = _NOERR, without: Optional[List[str]] = _WITHOUT,
                  sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """Board dataset for 'calibrate depth': board.json + poses/NNNN captures (depth + IR) of a ChArUco board or
    a checkerboard; truth.npz holds each pixel's noise-free depth error."""
    from tofmetry.simulate.board_datasets import board_dataset as write

    draw = _sensor(sensor, seed, no_errors, without)
    with progress(f"rendering {poses} board poses", poses) as adv:
        p = write(output, poses, board, seed, sensor=draw, dist_range_m=(min_distance_m, max_distance_m),
                  n_frames=frames, force=force, progress=adv)
    _done(p, f"{board} board dataset ({poses} poses)")


@sim_app.command("scan")
def scan(output: Path = _OUT, views: int = typer.Option(8, "--views", help="Number of viewpoints on the circle."),
         radius_m: float = typer.Option(1.0, "--radius-m", help="Camera to object centre [m]."),
         frames: int = typer.Option(10, "--frames", help="Frames per view."),
         mesh: Optional[Path] = typer.Option(None, "--mesh", help="Object mesh PLY (metres); default: a balustrade."),
         elevation: float = typer.Option(30.0, "--elevation-deg", help="Camera elevation above horizontal [deg]."),
         color: bool = typer.Option(False, "--color", help="Also a colour frame per view from the virtual colour camera "
                                    "(Kinect v2 1920x1080, 2 DN noise; its own viewpoint; calibration beside the frames)."),
         mat: Optional[Path] = typer.Option(None, "--mat", help="The object stands on this printed dot mat "
                                            "(a mat.json of tofmetry mat), turned by --mat-yaw-deg."),
         mat_yaw: float = typer.Option(20.0, "--mat-yaw-deg", help="How the mat lies under the object [deg]."),
         seed: int = _SEED, no_errors: bool = _NOERR, without: Optional[List[str]] = _WITHOUT,
         sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """Scan dataset: views/NN captures around an object, reference.ply, true poses in truth.json."""
    from dataclasses import replace

    from tofmetry.io.mat_json import read_mat
    from tofmetry.simulate import datasets

    draw = _sensor(sensor, seed, no_errors, without)
    dot_mat = None if mat is None else replace(read_mat(mat), yaw_deg=mat_yaw)
    with progress(f"simulating {views} views", views * frames) as adv:
        p = datasets.scan(output, views, radius_m, frames, mesh, None, seed, elevation,
                          force=force, progress=adv, sensor=draw, color=color, mat=dot_mat)
    _done(p, f"scan dataset ({views} views{', with colour' if color else ''})")


@sim_app.command("warmup")
def warmup(output: Path = _OUT, duration_s: float = typer.Option(5400.0, "--duration-s", help="Duration from power-on [s]."),
           interval_s: float = typer.Option(15.0, "--interval-s", help="Time between frames [s]."),
           distance_m: float = typer.Option(1.36, "--distance-m", help="Wall distance [m]."),
           seed: int = _SEED, no_errors: bool = _NOERR, without: Optional[List[str]] = _WITHOUT,
           sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """Warm-up experiment: one frame every 15 s from power-on (paper §3.2)."""
    from tofmetry.simulate import datasets

    draw = _sensor(sensor, seed, no_errors, without)
    n = int(duration_s // interval_s) + 1
    with progress("simulating warm-up frames", n) as adv:
        p = datasets.warmup(output, duration_s, interval_s, distance_m, None, seed,
                            force=force, progress=adv, sensor=draw)
    _done(p, f"warm-up capture ({n} frames)")


@sim_app.command("noise")
def noise(output: Path = _OUT, frames: int = typer.Option(100, "--frames", help="Number of frames."),
          distance_m: float = typer.Option(1.15, "--distance-m", help="Wall distance [m]."),
          seed: int = _SEED, no_errors: bool = _NOERR, without: Optional[List[str]] = _WITHOUT,
          sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """Noise experiment: many frames of a wall (paper §3.2, Fig. 3)."""
    from tofmetry.simulate import datasets

    draw = _sensor(sensor, seed, no_errors, without)
    with progress("simulating frames", frames) as adv:
        p = datasets.noise(output, frames, distance_m, None, seed, force=force, progress=adv, sensor=draw)
    _done(p, "noise capture")


@sim_app.command("materials")
def materials(output: Path = _OUT, board: str = typer.Option("grey", "--board", help="'grey' (grey levels) or 'samples'."),
              frames: int = typer.Option(20, "--frames", help="Number of frames."),
              distance_m: float = typer.Option(1.0, "--distance-m", help="Board distance [m]."),
              seed: int = _SEED, no_errors: bool = _NOERR, without: Optional[List[str]] = _WITHOUT,
              sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """Materials / grey-level board capture + regions.json (paper §3.3.1)."""
    from tofmetry.simulate import datasets

    draw = _sensor(sensor, seed, no_errors, without)
    with progress("simulating frames", frames) as adv:
        p = datasets.materials(output, board, frames, distance_m, None, seed,
                               force=force, progress=adv, sensor=draw)
    _done(p, f"{board} board capture (+ regions.json)")


@sim_app.command("outdoor")
def outdoor(output: Path = _OUT, frames: int = typer.Option(10, "--frames", help="Number of frames."),
            ambient: float = typer.Option(1.0, "--ambient", help="Ambient (sun) light 0..1."),
            seed: int = _SEED, no_errors: bool = _NOERR, without: Optional[List[str]] = _WITHOUT,
            sensor: str = _SENSOR, force: bool = _FORCE) -> None:
    """Sunny outdoor scene: table with a box, far background (paper §3.3.2)."""
    from tofmetry.simulate import datasets

    draw = _sensor(sensor, seed, no_errors, without)
    with progress("simulating frames", frames) as adv:
        p = datasets.outdoor(output, frames, ambient, None, seed, force=force, progress=adv, sensor=draw)
    _done(p, "outdoor capture")


def register(app: typer.Typer) -> None:
    """Add the ``simulate`` command group to the main app."""
    app.add_typer(sim_app, name="simulate")
