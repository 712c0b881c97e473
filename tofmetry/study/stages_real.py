"""Study stages for real recordings found in DATA_DIR: board recordings and Azure Kinect MKVs.

* **board**: a board dataset (``board.json`` + ``poses/``, as ``tofmetry record board`` writes it) or an
  iai_kinect2 board recording (imported as a board dataset first); intrinsics and the board depth
  calibration are fitted on the poses recorded first and judged on the last ``judge_fraction`` of them,
  which no fit sees (``tofmetry calibrate depth DS --train-poses ... --judge-poses ...``).
* **mkv**: each ``.mkv`` is imported as a capture (factory calibration included) and turned into a
  point cloud (``tofmetry import azure-kinect`` + ``tofmetry cloud``).

Both look in DATA_DIR itself and in its immediate sub-folders.
"""

from __future__ import annotations

from pathlib import Path

from tofmetry.io import atomic_write_json
from tofmetry.io.azure_kinect import import_azure_kinect
from tofmetry.io.board_dataset import BoardDataset, BoardSpec
from tofmetry.pipelines import save_calibration, write_depth_report
from tofmetry.pipelines.board import calibrate_board
from tofmetry.pipelines.cloud import capture_cloud
from tofmetry.pipelines.iai_import import import_iai_kinect2
from tofmetry.study.stage import Skip, StageOutcome, StudyContext


def _candidates(root: Path) -> list[Path]:
    return [root] + sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))


def find_board_recording(root: Path) -> Path | None:
    """The first folder (DATA_DIR or a sub-folder) holding ``NNNN_depth.png`` with ``NNNN_ir_points.yaml``."""
    for p in _candidates(root):
        if any(p.glob("[0-9][0-9][0-9][0-9]_ir_points.yaml")) and any(p.glob("[0-9][0-9][0-9][0-9]_depth.png")):
            return p
    return None


#: the folder of DATA_DIR whose board captures fit the depth tilt of the wall calibration (depth stage)
TILT_BOARDS = "tilt-boards"


def find_board_dataset(root: Path) -> Path | None:
    """The first folder (DATA_DIR or a sub-folder) holding a board dataset: ``board.json`` and
    ``poses/`` (not :data:`TILT_BOARDS`, which the depth stage uses)."""
    for p in _candidates(root):
        if p.name != TILT_BOARDS and (p / "board.json").is_file() and (p / "poses").is_dir():
            return p
    return None


def find_mkvs(root: Path) -> list[Path]:
    """``.mkv`` files in DATA_DIR and its immediate sub-folders."""
    return [f for p in _candidates(root) for f in sorted(p.glob("*.mkv"))]


def stage_board(ctx: StudyContext, out: StageOutcome) -> None:
    """Intrinsics, board depth calibration and its validation on poses no fit saw (real board recording)."""
    dataset, recording = find_board_dataset(ctx.data_dir), find_board_recording(ctx.data_dir)
    if dataset is None and recording is None:
        raise Skip(f"no board dataset (board.json + poses/, as tofmetry record board writes it) and no board recording "
                   f"(NNNN_depth.png + NNNN_ir_points.yaml, iai_kinect2) in {ctx.data_dir} or its sub-folders; "
                   "stage skipped")
    d = ctx.stage_dir("board")
    imp: dict = {}
    if dataset is not None:                       # recorded by tofmetry: the board is in its board.json
        src, ds_dir = dataset, dataset
        spec = BoardDataset(dataset).board
        if recording is not None:
            out.paragraphs.append(f"The board recording {recording} was not used: the board dataset {dataset} was.")
    else:
        src, ds_dir = recording, d / "dataset"
        c = ctx.config.recording
        spec = BoardSpec.parse(c.board, c.square_mm)
        imp = import_iai_kinect2(src, ds_dir, spec, force=True)
    c = ctx.config.recording
    names = list(BoardDataset(ds_dir).names)
    n_judge = max(1, round(len(names) * c.judge_fraction))
    if len(names) - n_judge < 3:
        raise Skip(f"{src}: only {len(names)} poses, too few to fit on some and judge on the others")
    train, judge = names[:-n_judge], names[-n_judge:]
    run = calibrate_board(ds_dir, ctx.intrinsics, train_poses=",".join(train), judge_poses=",".join(judge),
                          accept_implausible=ctx.accept_implausible)
    save_calibration(d / "calibration.npz", run.calibration)
    if ctx.calibration_path is None:
        ctx.calibration_path = d / "calibration.npz"
    figs = write_depth_report(run, d / "fit")
    out.figures = [(Path(p).stem.replace("_", " "), Path(p)) for p in figs if str(p).endswith(".png")]
    j = run.fit["judged"]
    cases = j["cases"]
    i = run.intrinsics
    out.data = {"source": str(src), "board": {"cols": spec.cols, "rows": spec.rows, "square_mm": spec.square_mm},
                "poses": len(names), "train_poses": [train[0], train[-1]], "judged_poses": [judge[0], judge[-1]],
                "intrinsics_source": run.intrinsics_source, "intrinsics": i.to_dict(),
                "judged": {k: {m: v[m] for m in ("mean_mm", "rms_mm", "p95_abs_mm")} for k, v in cases.items()},
                "prediction": j.get("prediction"), "notes": list(run.notes), "import": {k: v for k, v in imp.items()
                                                                                     if isinstance(v, (int, str))}}
    out.paragraphs.append(
        f"Board {'dataset' if dataset is not None else 'recording'} {src} ({len(names)} poses, {spec.cols}x{spec.rows} inner corners, {spec.square_mm:g} mm "
        f"squares). Fitted on poses {train[0]}–{train[-1]} (intrinsics included: {run.intrinsics_source}); judged on "
        f"poses {judge[0]}–{judge[-1]}, which no fit saw.")
    out.tables.append((f"IR intrinsics ({run.intrinsics_source})", ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"],
                       [[i.fx, i.fy, i.cx, i.cy, *i.distortion]]))
    labels = {"none": "no correction", "constant": "best constant of the training poses",
              "tofmetry": "tofmetry board calibration", "iai_kinect2": "iai_kinect2 depthShift (its intrinsics)",
              "iai_shift_our_intrinsics": "iai_kinect2 depthShift (these intrinsics)",
              "none_iai_intrinsics": "no correction (iai_kinect2's intrinsics)"}
    out.tables.append((f"Depth error on the board planes of the {len(judge)} judged poses [mm]",
                       ["correction", "mean", "RMS", "P95 |error|"],
                       [[labels.get(k, k), v["mean_mm"], v["rms_mm"], v["p95_abs_mm"]] for k, v in cases.items()]))
    p = j.get("prediction") or {}
    if p.get("rms_mm_interval"):
        lo, hi = p["rms_mm_interval"]
        out.paragraphs.append(f"The calibration predicted an RMS of {lo:.1f}–{hi:.1f} mm (90 %) on new poses; measured "
                              f"{cases['tofmetry']['rms_mm']:.2f} mm.")
    out.paragraphs += list(run.notes)
    atomic_write_json(d / "result.json", out.data)


def stage_mkv(ctx: StudyContext, out: StageOutcome) -> None:
    """Each Azure Kinect ``.mkv``: imported as a capture with its factory calibration, then a point cloud."""
    mkvs = find_mkvs(ctx.data_dir)
    if not mkvs:
        raise Skip(f"no .mkv recording in {ctx.data_dir} or its sub-folders; stage skipped")
    d = ctx.stage_dir("mkv")
    rows = []
    for k, f in enumerate(mkvs):
        name = f"{k:02d}-{f.stem}"
        imp = import_azure_kinect(f, d / name / "capture", force=True, max_frames=ctx.config.recording.mkv_max_frames)
        # coloured where the recording has colour: points the colour camera cannot see get no colour
        run = capture_cloud(d / name / "capture", d / name / "cloud.ply", average=True, color=True, force=True)
        z = run.points[:, 2] * 1000.0
        share = run.share_colored
        rows.append([str(f), imp.get("frames", ""), len(run.points), float(z.min()), float(z.max()), run.intrinsics_source,
                     share, f"{name}/cloud.ply"])
    keys = ["file", "frames", "points", "z_min_mm", "z_max_mm", "intrinsics", "share_colored", "cloud"]
    out.data = {"recordings": [dict(zip(keys, r)) for r in rows]}
    for r in rows:
        r[6] = "no colour stream" if r[6] is None else f"{100 * r[6]:.1f} %"
    out.tables.append(("Azure Kinect recordings → point clouds (temporal mean, undistorted, metres; colour from the "
                       "colour camera where it sees the point, none elsewhere)",
                       ["recording", "frames", "points", "Z min [mm]", "Z max [mm]", "intrinsics", "coloured", "cloud"],
                       rows))
    atomic_write_json(d / "result.json", out.data)
