"""CLI commands: interop — ``import``, ``export`` (format registry) and ``board-calibrate``."""

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

    @app.command("board-calibrate", help="Board-based calibration of a board dataset (from 'tofmetry import "
                 "iai-kinect2'): IR intrinsics from the corners and a depth correction from the board planes, "
                 "both cross-validated over poses.")
    def board_calibrate_cmd(
        dataset: Path = typer.Argument(..., help="Board dataset folder (board.json + poses/)."),
        out: Path = typer.Option(..., "-o", "--out", help="Output folder (report.json, intrinsics.json, board_model.json, depth_calibration.npz, board_calibration.png)."),
        intrinsics_source: str = typer.Option("fit", "--intrinsics",
                                              help="'fit' (calibrate from the corners), 'dataset' (intrinsics.json of the "
                                                   "dataset) or a path to an intrinsics.json."),
        squares: str = typer.Option("white", "--squares", help="white (dark squares read longer) | all"),
        folds: int = typer.Option(5, "--folds", help="k-fold cross-validation over poses."),
        force: bool = typer.Option(False, "--force", help="Replace an existing output folder."),
    ) -> None:
        import numpy as np

        from tofmetry.calibrate.board import calibrate_depth_from_board, calibrate_intrinsics, cross_validate_intrinsics
        from tofmetry.calibrate.board import reprojection_rms_with
        from tofmetry.errors import InputError
        from tofmetry.io import atomic_dir, atomic_write_json, read_intrinsics, write_intrinsics
        from tofmetry.io.board_dataset import BoardDataset
        from tofmetry.io.calibration_file import save_calibration

        ds = BoardDataset(dataset)
        if len(ds) == 0:
            raise InputError(f"{dataset}: no poses/ in the board dataset")
        poses = []
        names = list(ds.names)
        with progress("load poses", len(ds)) as advance:
            for i in range(len(ds)):
                poses.append(ds.load_poses([i])[0])
                advance()
        size = (poses[0][0].shape[1], poses[0][0].shape[0])
        corners = [p[2] for p in poses]
        report: dict = {"dataset": str(dataset), "board": ds.meta, "n_poses": len(ds)}
        have_corners = all(c is not None for c in corners)
        fit = None
        if have_corners:
            fit = calibrate_intrinsics(corners, ds.board.size, ds.board.square_mm, size)
            cv = cross_validate_intrinsics(corners, ds.board.size, ds.board.square_mm, size, k=folds,
                                           exclude=fit.rejected_views)
            report["intrinsics_fit"] = {"intrinsics": fit.intrinsics.to_dict(), "rms_px": fit.rms_px,
                                        "rejected_views": [ds.names[i] for i in fit.rejected_views],
                                        "cv_rms_px": cv["rms_px"], "cv_max_px": cv["max_px"]}
            if ds.intrinsics() is not None:
                kept = [corners[i] for i in cv["views"]]
                r = reprojection_rms_with(ds.intrinsics(), kept, ds.board.size, ds.board.square_mm)
                report["intrinsics_dataset"] = {"intrinsics": ds.intrinsics().to_dict(),
                                                "rms_px_same_views": float(np.sqrt(np.mean(r ** 2)))}
            console.print(f"intrinsics from corners: RMS {fit.rms_px:.3f} px, held-out (k={folds}) {cv['rms_px']:.3f} px")
        if fit is not None and fit.rejected_views:
            # views whose corners contradict the board (mis-detections) are left out of the depth fit too
            console.print(f"  leaving out poses with inconsistent corners: {[ds.names[i] for i in fit.rejected_views]}")
            poses = [p for i, p in enumerate(poses) if i not in fit.rejected_views]
            names = [n for i, n in enumerate(names) if i not in fit.rejected_views]
        if intrinsics_source == "fit":
            if fit is None:
                raise InputError(f"{dataset}: --intrinsics fit needs corners.json in every pose")
            intr = fit.intrinsics
        elif intrinsics_source == "dataset":
            intr = ds.intrinsics()
            if intr is None:
                raise InputError(f"{dataset}: no intrinsics.json in the dataset")
        else:
            intr = read_intrinsics(intrinsics_source)
        console.print("depth calibration (cross-validated over poses)...")
        res = calibrate_depth_from_board(poses, ds.board.size, ds.board.square_mm, intr, squares=squares, k_folds=folds,
                                         iai_shift_mm=ds.depth_shift_mm(), sensor=ds.sensor)
        report["depth"] = res.summary()
        report["depth"]["skipped_poses"] = [[names[i], why] for i, why in res.skipped]
        report["depth"]["poses_used"] = [names[i] for i in res.pose_index]
        report["depth"]["intrinsics_used"] = intrinsics_source
        for case, st in res.cv.items():
            console.print(f"  held-out {case:15s} mean {st['mean_mm']:7.2f}  RMS {st['rms_mm']:6.2f}  "
                          f"P95|e| {st['p95_abs_mm']:6.2f} mm  (n={st['n']})")
        with atomic_dir(out, force=force) as tmp:
            atomic_write_json(tmp / "report.json", report)
            write_intrinsics(tmp / "intrinsics.json", intr, sensor=ds.sensor, source=intrinsics_source)
            atomic_write_json(tmp / "board_model.json", {"sensor": ds.sensor, "intrinsics": intr.to_dict(),
                                                        **res.model.to_dict()})
            _board_figure(res, tmp / "board_calibration.png")
            save_calibration(tmp / "depth_calibration.npz",
                             res.depth_calibration(intr, ds.sensor, {"command": "tofmetry board-calibrate",
                                                                     "dataset": str(dataset), "squares": squares}))
        console.print(f"[green]wrote[/] {out}")


def _board_figure(res, path: Path) -> None:
    """Range term, surface term (support outlined) and held-out error histograms of a board calibration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from tofmetry.io import atomic_write_bytes

    m = res.model
    fig, ax = plt.subplots(1, 3, figsize=(16, 4.6))
    z = np.linspace(m.z_knots_mm[0] - 100, m.z_knots_mm[-1] + 100, 200)
    ax[0].plot(z, np.interp(z, m.z_knots_mm, m.range_mm), "-", label="a(Z)")
    ax[0].plot(m.z_knots_mm, m.range_mm, "o", label="knots")
    ax[0].set_xlabel("measured Z [mm]")
    ax[0].set_ylabel("range correction a(Z) [mm]")
    ax[0].set_title("Range term (added to measured depth)")
    ax[0].legend()
    ax[0].grid(alpha=0.3)
    img = m.surface_image()
    lim = float(np.max(np.abs(img))) or 1.0
    im = ax[1].imshow(img, cmap="RdBu_r", vmin=-lim, vmax=lim)
    ax[1].contour(m.grid_u, m.grid_v, (m.support > 0).astype(float), levels=[0.5], colors="k", linewidths=1)
    ax[1].set_title("Surface term s(u, v)\n(black line: limit of board coverage)")
    ax[1].set_xlabel("u [px]")
    ax[1].set_ylabel("v [px]")
    fig.colorbar(im, ax=ax[1], label="s [mm]")
    for case, st in res.cv.items():
        ax[2].plot([], [], " ", label=f"{case}: RMS {st['rms_mm']:.1f}, P95 {st['p95_abs_mm']:.1f} mm")
    per = res.cv_per_pose
    ax[2].hist([v[np.isfinite(v)] for v in per.values()], bins=np.linspace(0, 50, 26), label=list(per), alpha=0.8)
    ax[2].set_xlabel("held-out RMS per pose [mm]")
    ax[2].set_ylabel("poses")
    ax[2].set_title(f"Held-out board-plane error ({res.k_folds}-fold over poses)")
    ax[2].legend(fontsize=7)
    fig.suptitle(f"Board-based depth calibration ({res.squares} squares)")
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
