"""Calibration figures (matplotlib, Agg): return Figure objects, the caller saves them."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tofmetry.calibrate._model import DepthCalibration  # noqa: E402


def _range_label(cal) -> str:
    name = cal.diagnostics.get("range_model", "spline")
    if name == "spline":
        return "smoothing B-spline"
    cv = cal.diagnostics.get("range_model_cv_rms_mm", {})
    return f"{name} (left-out RMS {cv.get(name, float('nan')):.2f} mm; spline {cv.get('spline', float('nan')):.2f} mm)"


def fig_range_curve(cal: DepthCalibration, points_mm: np.ndarray, frame_points: list | None = None,
                    held_out: list | None = None):
    """Study Fig. 7a: central deviation [mm] against measured range [m], with the fitted spline.

    Parameters
    ----------
    points_mm : (M, 2) (measured central distance, deviation) of the fitted stations [mm]
    frame_points : optional list of (distance_mm, (T,) per-frame deviations) to scatter
    held_out : optional list of (distance_mm, deviation_mm) of validation stations (before)
    """
    fig, ax = plt.subplots(figsize=(7, 4.2))
    off = cal.offset_mm
    if frame_points:
        for d, devs in frame_points:
            ax.plot(np.full(len(devs), d / 1000.0), np.asarray(devs) - off, ".", color="0.75", ms=2)
    ax.plot(points_mm[:, 0] / 1000.0, points_mm[:, 1] - off, "o", color="C0", label="stations (central patch)")
    lo, hi = cal.range_data_mm
    x = np.linspace(lo, hi, 400)
    ax.plot(x / 1000.0, cal.range_error(x) - off, "-", color="C1", label=_range_label(cal))
    if held_out:
        h = np.asarray(held_out, float)
        ax.plot(h[:, 0] / 1000.0, h[:, 1], "s", mfc="none", color="C3", label="held-out stations")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("measured range [m]")
    ax.set_ylabel(f"deviation - offset ({off:+.1f} mm) [mm]")
    ax.set_title("Range error of the central patch (cf. study Fig. 7a)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def fig_std_vs_range(distances_mm, center_std_mm, pixel_std_mm=None, after_std_mm=None):
    """Study Fig. 7b: temporal std [mm] per station against range [m]."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    d = np.asarray(distances_mm, float) / 1000.0
    ax.plot(d, center_std_mm, "o-", label="std of per-frame central-patch means")
    if pixel_std_mm is not None:
        ax.plot(d, pixel_std_mm, "s-", label="mean per-pixel temporal std (central patch)")
    if after_std_mm is not None:
        ax.plot(d, after_std_mm, "^-", label="after correction")
    ax.set_xlabel("range [m]")
    ax.set_ylabel("standard deviation [mm]")
    ax.set_title("Temporal scatter per station (cf. study Fig. 7b)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def fig_residual_maps(before: np.ndarray, after: np.ndarray, title: str, limit_mm: float | None = None):
    """Study Figs. 8/9: plane-fit residual maps [mm] before and after correction."""
    lim = limit_mm or float(np.nanpercentile(np.abs(before), 99)) or 1.0
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, m, t in zip(axes, (before, after), ("before correction", "after correction")):
        im = ax.imshow(m, cmap="RdBu_r", vmin=-lim, vmax=lim)
        ax.set_title(f"{t}: std {np.nanstd(m):.2f} mm")
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
        fig.colorbar(im, ax=ax, label="residual to fitted plane [mm]")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def fig_validation(reports) -> "plt.Figure":
    """Before/after per station: central deviation, plane std, per-pixel RMS against range."""
    d = np.array([r.distance_mm for r in reports]) / 1000.0
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    pairs = [("dev_before_mm", "dev_after_mm", "central deviation [mm]"),
             ("plane_std_before_mm", "plane_std_after_mm", "plane-fit residual std [mm]"),
             ("rms_before_mm", "rms_after_mm", "per-pixel RMS error, central 90 % [mm]\n(before: offset removed)")]
    for ax, (b, a, lab) in zip(axes, pairs):
        ax.plot(d, [getattr(r, b) for r in reports], "o-", label="before")
        ax.plot(d, [getattr(r, a) for r in reports], "s-", label="after")
        noise = [getattr(r, "rms_noise_mm", float("nan")) for r in reports]
        if a == "rms_after_mm" and np.isfinite(noise).any():
            ax.plot(d, noise, "k:", label="noise of the temporal mean (floor)")
            ax.plot(d, [getattr(r, "rms_raw_before_mm", float("nan")) for r in reports], "o--", color="C0", alpha=0.5,
                    label="before, offset not removed")
            ax.set_yscale("log")  # the before/after ratio reads as a distance
        ax.set_xlabel("reference range [m]")
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Depth calibration validation (held-out stations)")
    fig.tight_layout()
    return fig


def fig_coverage(corners_px: list, shape: tuple[int, int], title: str = "Checkerboard corner coverage"):
    """Coverage map of detected corners over the image (count per cell) with the corners."""
    h, w = shape
    cell = 32
    grid = np.zeros((-(-h // cell), -(-w // cell)))
    fig, ax = plt.subplots(figsize=(7, 5.2))
    for c in corners_px:
        c = np.asarray(c).reshape(-1, 2)
        iu = np.clip((c[:, 0] // cell).astype(int), 0, grid.shape[1] - 1)
        iv = np.clip((c[:, 1] // cell).astype(int), 0, grid.shape[0] - 1)
        np.add.at(grid, (iv, iu), 1)
    im = ax.imshow(grid, extent=(-0.5, w - 0.5, h - 0.5, -0.5), cmap="viridis", interpolation="nearest")
    for c in corners_px:
        c = np.asarray(c).reshape(-1, 2)
        ax.plot(c[:, 0], c[:, 1], ".", ms=1.5, color="w")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    ax.set_title(title)
    fig.colorbar(im, ax=ax, label=f"corners per {cell}x{cell} px cell")
    fig.tight_layout()
    return fig


def fig_intrinsics_per_image(run):
    """Per-image reprojection RMS [px] (outlier views and the rejection threshold marked) and
    leave-one-out influence (parameter change on removal / its standard uncertainty)."""
    res = run.result
    names = list(run.names)
    rms = [res.per_image_rms_px.get(n, res.rejected_rms_px.get(n, np.nan)) for n in names]
    colours = ["C3" if n in res.rejected_views else ("C1" if n in res.flagged else "C0") for n in names]
    fig, ax = plt.subplots(2, 1, figsize=(max(7, 0.18 * len(names) + 3), 6.5), sharex=True)
    x = np.arange(len(names))
    ax[0].bar(x, rms, color=colours)
    if np.isfinite(res.reject_threshold_px):
        ax[0].axhline(res.reject_threshold_px, color="C3", ls="--", lw=1,
                      label=f"rejection threshold {res.reject_threshold_px:.2f} px")
    ax[0].axhline(res.rms_px, color="k", lw=0.8, label=f"overall RMS {res.rms_px:.3f} px (kept views)")
    cv = run.cv or {}
    if "rms_px" in cv:
        ax[0].axhline(cv["rms_px"], color="C2", lw=0.8, ls=":", label=f"{cv['k']}-fold held-out RMS {cv['rms_px']:.3f} px")
    ax[0].set_ylabel("reprojection RMS [px]")
    ax[0].set_yscale("log")
    ax[0].set_title(f"Per-image reprojection error ({len(res.used)} kept, {len(res.rejected_views)} rejected in red)")
    ax[0].legend(fontsize=7)
    ax[0].grid(alpha=0.3)
    infl = [res.influence.get(n, np.nan) for n in names]
    ax[1].bar(x, infl, color=colours)
    ax[1].axhline(1.0, color="C1", ls="--", lw=1, label="1 standard uncertainty (flagged above, orange)")
    ax[1].set_ylabel("leave-one-out influence [std]")
    ax[1].set_title("Stability: largest parameter change when the image is removed")
    ax[1].legend(fontsize=7)
    ax[1].grid(alpha=0.3)
    ax[1].set_xticks(x)
    ax[1].set_xticklabels(names, rotation=90, fontsize=6)
    ax[1].set_xlabel("image")
    fig.tight_layout()
    return fig


def fig_board_calibration(res):
    """Board-based depth calibration: range term, surface term (board support outlined) and
    held-out error per pose for each case (none / iai shift / constant refit / model)."""
    m = res.model
    fig, ax = plt.subplots(1, 3, figsize=(16, 4.6))
    if hasattr(m, "z_knots_mm"):
        z = np.linspace(m.z_knots_mm[0] - 100, m.z_knots_mm[-1] + 100, 200)
        ax[0].plot(z, np.interp(z, m.z_knots_mm, m.range_mm), "-", label="a(Z)")
        ax[0].plot(m.z_knots_mm, m.range_mm, "o", label="knots")
        img = m.surface_image()
    else:  # core DepthCalibration: correction = -(R + S)
        lo, hi = m.range_data_mm
        z = np.linspace(lo, hi, 200)
        ax[0].plot(z, -m.range_error(z), "-", label="-R(Z)")
        img = -np.asarray(m.surfaces[0], float)
    ax[0].set_xlabel("measured Z [mm]")
    ax[0].set_ylabel("range correction a(Z) [mm]")
    ax[0].set_title("Range term (added to measured depth)")
    ax[0].legend()
    ax[0].grid(alpha=0.3)
    lim = float(np.max(np.abs(img))) or 1.0
    im = ax[1].imshow(img, cmap="RdBu_r", vmin=-lim, vmax=lim)
    if hasattr(m, "support"):
        ax[1].contour(m.grid_u, m.grid_v, (m.support > 0).astype(float), levels=[0.5], colors="k", linewidths=1)
    ax[1].set_title("Surface term s(u, v)\n(black line: limit of board coverage)")
    ax[1].set_xlabel("u [px]")
    ax[1].set_ylabel("v [px]")
    fig.colorbar(im, ax=ax[1], label="s [mm]")
    for case, st in res.cv.items():
        ax[2].plot([], [], " ", label=f"{case}: RMS {st['rms_mm']:.1f}, P95 {st['p95_abs_mm']:.1f} mm")
    per = res.cv_per_pose
    vals = [v[np.isfinite(v)] for v in per.values()]
    top = max(50.0, float(np.nanmax(np.concatenate(vals)))) if vals and sum(len(v) for v in vals) else 50.0
    ax[2].hist(vals, bins=np.linspace(0, top, 26), label=list(per), alpha=0.8)
    ax[2].set_xlabel("held-out RMS per pose [mm]")
    ax[2].set_ylabel("poses")
    ax[2].set_title(f"Held-out board-plane error ({res.k_folds}-fold over poses)")
    ax[2].legend(fontsize=7)
    fig.suptitle(f"Board-based depth calibration ({res.squares} squares)")
    fig.tight_layout()
    return fig
