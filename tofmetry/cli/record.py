"""CLI: ``tofmetry record {warmup,wall,board,object} -o DIR`` — guided recording with a device;
``tofmetry record recover DIR`` finishes recordings that were cut off.

The command only parses, builds the device and the session, and shows the live status; the
protocols are :mod:`tofmetry.record`. With ``--device virtual`` a simulated operator
(:mod:`tofmetry.record.virtual_operator`) answers the prompts, so every command runs without hardware.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape

from tofmetry.cli._common import console

DEVICE_HELP = "virtual | realsense | azure | orbbec | kinect2 (real devices need their extra, e.g. pip install tofmetry[azure])."
PLAYBACK_HELP = "Play back a recording instead of a live device: a .bag (realsense) or .mkv (azure)."

app = typer.Typer(help="Guided recording with a device: warm-up, wall stations, board poses, object views.",
                  no_args_is_help=True, rich_markup_mode=None)


def _device(name: str, playback: Optional[Path], fps: Optional[float], realtime: bool, scene=None, t0_s: float = 3600.0):
    from tofmetry.devices import make_device

    if name == "virtual":
        return make_device("virtual", scene=scene, fps=fps or 30.0, realtime=realtime, t0_s=t0_s)
    if playback is not None:
        key = {"realsense": "bag", "azure": "mkv"}.get(name)
        if key is None:
            from tofmetry.errors import InputError

            raise InputError(f"--playback: the {name} device plays back no files (realsense: .bag, azure: .mkv)")
        return make_device(name, **{key: playback})
    return make_device(name)


def _run(device, session, distances, board=None, calibration: Optional[Path] = None, max_frames=None) -> None:
    from rich.live import Live
    from rich.panel import Panel

    from tofmetry.record import answers_from, run_recording

    cal = None
    if calibration is not None:
        from tofmetry.pipelines import load_calibration

        cal = load_calibration(calibration)
    live = Live(console=console, refresh_per_second=4, transient=False)
    if device.name == "virtual":
        from tofmetry.record.virtual_operator import VirtualOperator

        prompt = VirtualOperator(device, board=board)
        if distances:
            prompt = _with_distances(prompt, distances)
    else:
        def ask(text: str) -> str:
            live.stop()
            try:
                return console.input(escape(text))
            finally:
                live.start()

        prompt = answers_from(distances, ask)

    def show(st, frame) -> None:
        body = "\n".join([st.message] + st.lines)
        live.update(Panel(escape(body), title=f"tofmetry record {st.protocol}", subtitle=f"recorded: {st.recorded}"))
        if st.request is not None:
            console.print(f"[bold cyan]→[/] {escape(st.request.text)}", highlight=False)

    with live:
        res = run_recording(device, session, prompt, on_status=show, calibration=cal, max_frames=max_frames)
    s = res.summary
    console.print(f"{res.ended}: {res.frames_read} frames read in {res.seconds:.0f} s → {escape(str(session.out))}",
                  highlight=False)
    for n in s.get("notes", []):
        console.print(f"[yellow]note:[/] {escape(n)}", highlight=False)
    if s.get("preview"):
        console.print(f"preview: {escape(s['preview'])}", highlight=False)


def _with_distances(prompt, distances):
    queue = list(distances)

    def p(req):
        if req.kind == "distance" and queue:
            prompt(req)
            return str(queue.pop(0))
        return prompt(req)

    return p


_OUT = typer.Option(..., "-o", "--output", help="Output folder (must not exist or be empty).")
_DEV = typer.Option("virtual", "--device", help=DEVICE_HELP)
_PLAY = typer.Option(None, "--playback", help=PLAYBACK_HELP)
_CAL = typer.Option(None, "--calibration", help="Depth calibration (.npz) for the corrected preview.")
_RT = typer.Option(False, "--realtime/--fast", help="Virtual device: pace frames in real time (default: as fast as computed).")
_MAX = typer.Option(None, "--max-frames", help="Stop after reading this many frames (safety limit).")


@app.command("warmup")
def warmup(output: Path = _OUT, device: str = _DEV, playback: Optional[Path] = _PLAY, calibration: Optional[Path] = _CAL,
           interval_s: float = typer.Option(15.0, "--interval-s", help="Keep one frame every this many seconds [s] (study: 15)."),
           tolerance_mm: float = typer.Option(1.0, "--tolerance-mm", help="Stable: smoothed drift within this band [mm]."),
           confirm_min: float = typer.Option(10.0, "--confirm-min", help="... over this many last minutes [min]."),
           max_minutes: float = typer.Option(120.0, "--max-minutes", help="Stop anyway after this long [min]."),
           realtime: bool = _RT, max_frames: Optional[int] = _MAX) -> None:
    """Record a static wall from power-on until the drift analysis says the sensor is stable; then stop."""
    from tofmetry.record import WarmupSession, check_output
    from tofmetry.simulate import scenes

    check_output(output)
    dev = _device(device, playback, 1.0 / interval_s, realtime, scenes.wall(1.36, (1.5, -2.0)), t0_s=0.0)
    _run(dev, WarmupSession(output, interval_s=interval_s, tolerance_mm=tolerance_mm, confirm_s=60 * confirm_min,
                            max_duration_s=60 * max_minutes), None, calibration=calibration, max_frames=max_frames)


@app.command("wall")
def wall(output: Path = _OUT, device: str = _DEV, playback: Optional[Path] = _PLAY, calibration: Optional[Path] = _CAL,
         stations_mm: list[float] = typer.Option([800.0, 1000.0, 1500.0, 2000.0], "--station-mm",
                                                 help="Planned station distance [mm] (repeat)."),
         distances: Optional[list[float]] = typer.Option(None, "--distance-mm",
                                                         help="Reference distance of each station, in order [mm] "
                                                              "(repeat; otherwise asked for at each station)."),
         frames: int = typer.Option(50, "--frames", help="Frames per station (study: 50)."),
         max_tilt_deg: float = typer.Option(1.0, "--max-tilt-deg", help="Largest yaw / pitch to the wall [deg]."),
         realtime: bool = _RT, max_frames: Optional[int] = _MAX) -> None:
    """Guide from wall station to station; check fill and squareness; ask for each reference distance."""
    from tofmetry.record import WallSession, check_output

    check_output(output)
    dev = _device(device, playback, None, realtime)
    _run(dev, WallSession(output, stations_mm, frames=frames, max_tilt_deg=max_tilt_deg), distances,
         calibration=calibration, max_frames=max_frames)


@app.command("board")
def board(output: Path = _OUT, device: str = _DEV, playback: Optional[Path] = _PLAY, calibration: Optional[Path] = _CAL,
          board_: str = typer.Option("7x5", "--board", help="Inner corners COLSxROWS."),
          square_mm: float = typer.Option(40.0, "--square-mm", help="Square size [mm]."),
          grid: str = typer.Option("3x3", "--grid", help="Image regions ROWSxCOLS to cover."),
          range_mm: list[float] = typer.Option([500.0, 800.0, 1100.0, 1500.0], "--range-edge-mm",
                                               help="Edges of the range bins to cover [mm] (repeat)."),
          frames: int = typer.Option(1, "--frames", help="Frames per pose."),
          realtime: bool = _RT, max_frames: Optional[int] = _MAX) -> None:
    """Record board poses; live coverage of image regions x range bins; asks for the poses still missing."""
    from tofmetry.io.board_dataset import BoardSpec
    from tofmetry.record import BoardSession, check_output

    check_output(output)
    spec = BoardSpec.parse(board_, square_mm)
    g = BoardSpec.parse(grid, 1.0).size
    dev = _device(device, playback, None, realtime)
    _run(dev, BoardSession(output, spec, grid=(g[0], g[1]), range_edges_mm=range_mm, frames=frames), None, board=spec,
         calibration=calibration, max_frames=max_frames)


@app.command("object")
def object_(output: Path = _OUT, device: str = _DEV, playback: Optional[Path] = _PLAY, calibration: Optional[Path] = _CAL,
            size_m: tuple[float, float, float] = typer.Option((0.4, 0.2, 0.2), "--size-m",
                                                              help="Object width, depth, height [m]."),
            views: int = typer.Option(8, "--views", help="Views on the ring (study: 8)."),
            distance_m: float = typer.Option(1.0, "--distance-m", help="Camera to object [m]."),
            frames: int = typer.Option(10, "--frames", help="Frames per view (study: 10)."),
            min_overlap: float = typer.Option(0.3, "--min-overlap", help="Share of a view that must overlap the previous one."),
            realtime: bool = _RT, max_frames: Optional[int] = _MAX) -> None:
    """Guide around an object view by view; check overlap; show the predicted completeness."""
    from tofmetry.record import ObjectSession, check_output
    from tofmetry.simulate import scenes

    check_output(output)
    dev = _device(device, playback, None, realtime, scenes.balustrade() if device == "virtual" else None)
    _run(dev, ObjectSession(output, size_m, n_views=views, distance_m=distance_m, frames=frames,
                            min_overlap=min_overlap), None, calibration=calibration, max_frames=max_frames)


@app.command("recover")
def recover(folder: Path = typer.Argument(..., help="A recording (capture or dataset folder) that was cut off.")) -> None:
    """Finish every cut recording under FOLDER: drop the frame in flight, write the final capture.json."""
    from tofmetry.io.live_capture import recover_recordings

    done = recover_recordings(folder)
    if not done:
        console.print(f"nothing to recover: no cut recording in {escape(str(folder))}", highlight=False)
    for path, r in done:
        console.print(f"recovered {escape(str(path))}: {r['frames']} complete frame(s) kept, "
                      f"{len(r['removed'])} file(s) of the frame in flight removed", highlight=False)


def register(root: typer.Typer) -> None:
    """Add ``record``."""
    root.add_typer(app, name="record")
