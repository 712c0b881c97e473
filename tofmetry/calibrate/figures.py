"""Calibration figures: return matplotlib Figure objects, the caller saves them.

Made without pyplot (:func:`tofmetry._shared.figures.subplots`): nothing switches the backend of
the caller's session and nothing has to be closed.
"""

from __future__ import annotations

import numpy as np
from matplotlib.colors import PowerNorm
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from tofmetry._shared.figures import subplots
from tofmetry.calibrate._model import DepthCalibration


def _range_label(cal) -> str:
    model = cal.diagnostics.get("model")
    if model:
        return model if len(model) < 60 else model[:57] + "..."
    return "smoothing B-spline (the study's)"


def fig_range_curve(cal: DepthCalibration, points_mm: np.ndarray, frame_points: list | None = None,
                    held_out: list | None = None):
    """Study Fig. 7a: central deviation [mm] against measured range [m], with the fitted correction
    on the optical axis (``R + W``) and, for a calibration with a ray term, ``W`` over every ray
    length the off-axis pixels sampled.

    Parameters
    ----------
    points_mm : (M, 2) (measured central distance, deviation) of the fitted stations [mm]
    frame_points : optional list of (distance_mm, (T,) per-frame deviations) to scatter
    held_out : optional list of (distance_mm, deviation_mm) of validation stations (before)
    """
    fig, ax = subplots(figsize=(7, 4.2))
    off = cal.offset_mm
    if frame_points:
        for d, devs in frame_points:
            ax.plot(np.full(len(devs), d / 1000.0), np.asarray(devs) - off, ".", color="0.75", ms=2)
    ax.plot(points_mm[:, 0] / 1000.0, points_mm[:, 1] - off, "o", color="C0", label="stations (central patch)")
    lo, hi = cal.range_data_mm
    x = np.linspace(lo, hi, 400)
    ax.plot(x / 1000.0, cal.range_error(x) + cal.ray_error(x) - off, "-", color="C1", label=_range_label(cal))
    if cal.ray_knots is not None:
        q = np.linspace(*cal.ray_data_mm, 600)
        ax.plot(q / 1000.0, cal.range_error(np.clip(q, lo, hi)) + cal.ray_error(q) - off, ":", color="C1", lw=1,
                label="range error along the ray (off-axis pixels sample it up to "
                      f"{cal.ray_data_mm[1] / 1000:.1f} m)")
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
    fig, ax = subplots(figsize=(7, 4.2))
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
    fig, axes = subplots(1, 2, figsize=(11, 4.2))
    for ax, m, t in zip(axes, (before, after), ("before correction", "after correction")):
        im = ax.imshow(m, cmap="RdBu_r", vmin=-lim, vmax=lim)
        ax.set_title(f"{t}: std {np.nanstd(m):.2f} mm")
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
        fig.colorbar(im, ax=ax, label="residual to fitted plane [mm]")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def fig_validation(reports) -> "Figure":
    """Before/after per station: central deviation, plane std, per-pixel RMS against range."""
    d = np.array([r.distance_mm for r in reports]) / 1000.0
    fig, axes = subplots(1, 3, figsize=(13, 3.8))
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


def fig_coverage(corners_px: list, shape: tuple[int, int], title: str = "Checkerboard corner coverage", *,
                 corner_regions: dict | None = None, predicted_ray=None, corner_frac: float = 0.1,
                 uncovered: list | None = None, region_corners: dict | None = None):
    """Coverage map of detected corners over the image (count per cell) with the corners.

    Parameters
    ----------
    corners_px : list of (N, 2) [px]; shape : (H, W)
    corner_regions : optional dict region name (``top-left`` ...) -> covered fraction: the four
        image-corner regions (``corner_frac`` of width and height) are outlined, red where no
        board reached them (the regions in ``uncovered``; without it, fraction < 0.1), green otherwise
    uncovered : optional list of the regions no board reached (``IntrinsicsResult.uncovered_corners``)
    region_corners : optional dict region -> detected corners in it, written in the region
    predicted_ray : optional ``RayError`` (``IntrinsicsResult.predicted_ray``): adds a panel with
        the predicted ray-error map [px] from the parameter covariance
    """
    h, w = shape
    cell = 32
    grid = np.zeros((-(-h // cell), -(-w // cell)))
    panels = 2 if predicted_ray is not None else 1
    fig, axes = subplots(1, panels, figsize=(7 * panels, 5.2), squeeze=False)
    ax = axes[0, 0]
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
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, label=f"corners per {cell}x{cell} px cell")
    rw, rh = corner_frac * w, corner_frac * h
    origins = {"top-left": (-0.5, -0.5), "top-right": (w - 0.5 - rw, -0.5), "bottom-left": (-0.5, h - 0.5 - rh),
               "bottom-right": (w - 0.5 - rw, h - 0.5 - rh)}

    def outline(a, label_values=None):
        for name, frac in (corner_regions or {}).items():
            x0, y0 = origins[name]
            bad = name in uncovered if uncovered is not None else frac < 0.1
            a.add_patch(Rectangle((x0, y0), rw, rh, fill=False, lw=2, ec="red" if bad else "lime"))
            txt = "no board" if bad else f"{100 * frac:.0f} % covered"
            if region_corners is not None and not bad:
                txt += f"\n{region_corners.get(name, 0)} corners"
            if label_values is not None:
                txt += f"\n{label_values[name]:.2f} px"
            a.text(x0 + rw / 2, y0 + rh / 2, txt, color="red" if bad else "green", ha="center", va="center",
                   fontsize=7, fontweight="bold", bbox={"facecolor": "white", "alpha": 0.75, "lw": 0, "pad": 1})

    outline(ax)
    if predicted_ray is not None:
        pr = predicted_ray
        ax2 = axes[0, 1]
        m = pr.map_px
        im2 = ax2.pcolormesh(pr.u_px, pr.v_px, m, cmap="magma", shading="gouraud",
                             norm=PowerNorm(0.5, vmin=0.0, vmax=float(np.nanmax(m))))
        nice = np.array([0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0])
        levels = nice[(nice > np.nanmin(m)) & (nice < np.nanmax(m))]
        if levels.size:
            cs = ax2.contour(pr.u_px, pr.v_px, m, levels=levels, colors="w", linewidths=0.6)
            ax2.clabel(cs, fontsize=6, fmt="%g px")
        outline(ax2, pr.per_corner_max_px)
        ax2.set_xlim(-0.5, w - 0.5)
        ax2.set_ylim(h - 0.5, -0.5)
        ax2.set_xlabel("u [px]")
        ax2.set_ylabel("v [px]")
        ax2.set_title(f"Predicted ray error (from the parameter covariance): RMS {pr.rms_px:.2f} px, "
                      f"corners up to {pr.corners_max_px:.2f} px", fontsize=9)
        fig.colorbar(im2, ax=ax2, label="predicted ray error, 1 sigma [px]")
    fig.tight_layout()
    return fig


def fig_intrinsics_per_image(run):
    """Per-image reprojection RMS [px] (outlier views and the rejection threshold marked) and
    leave-one-out influence (parameter change on removal / its standard uncertainty)."""
    res = run.result
    names = list(run.names)
    rms = [res.per_image_rms_px.get(n, res.rejected_rms_px.get(n, np.nan)) for n in names]
    colours = ["C3" if n in res.rejected_views else ("C1" if n in res.flagged else "C0") for n in names]
    fig, ax = subplots(2, 1, figsize=(max(7, 0.18 * len(names) + 3), 6.5), sharex=True)
    x = np.arange(len(names))
    ax[0].bar(x, rms, color=colours)
    if np.isfinite(res.reject_threshold_px):
        ax[0].axhline(res.reject_threshold_px, color="C3", ls="--", lw=1,
                      label=f"rejection threshold {res.reject_threshold_px:.2f} px")
    ax[0].axhline(res.rms_px, color="k", lw=0.8, label=f"overall RMS {res.rms_px:.3f} px (kept views)")
    cv = run.cv or {}
    if np.isfinite(cv.get("rms_px", np.nan)):  # inf where a fold's fit failed (cv["failed_views"])
        ax[0].axhline(cv["rms_px"], color="C2", lw=0.8, ls=":", label=f"{cv['k']}-fold held-out RMS {cv['rms_px']:.3f} px")
    ax[0].set_ylabel("reprojection RMS [px]")
    ax[0].set_yscale("log")
    ax[0].set_title(f"Per-image reprojection error ({len(res.used)} kept, {len(res.rejected_views)} rejected in red)")
    ax[0].legend(fontsize=7)
    ax[0].grid(alpha=0.3)
    infl = np.array([res.influence.get(n, np.nan) for n in names], float)
    ax[1].bar(x, np.where(np.isinf(infl), np.nan, infl), color=colours)
    for j in np.flatnonzero(np.isinf(infl)):  # the fit without this view failed
        ax[1].text(x[j], 1.0, "fit fails\nwithout it", rotation=90, fontsize=6, ha="center", va="bottom", color="C3")
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
    """Board-based depth calibration (:class:`tofmetry.calibrate.board.BoardCalibrationResult`):
    range term over its training range, surface term (board support outlined), the model
    selection on blocked folds (held-out RMS per candidate and design) and the dark-square
    bias measured against the dark squares' IR amplitude."""
    m = res.model
    fig, ax = subplots(2, 2, figsize=(14, 9.5))
    ax = ax.ravel()
    lo, hi = m.x_support_mm
    x = np.linspace(lo - 0.15 * (hi - lo + 1), hi + 0.15 * (hi - lo + 1), 300)
    ax[0].plot(x, m.range_term(x), "-", label="a(x), constant beyond the training range")
    if len(m.x_knots_mm) > 1:
        ax[0].plot(m.x_knots_mm, m.range_mm, "o", label="knots")
    ax[0].axvspan(lo, hi, color="0.9", label="training range")
    ax[0].set_xlabel(("radial path length" if m.range_variable == "radial" else "measured Z") + " x [mm]")
    ax[0].set_ylabel("range correction a(x) [mm]")
    ax[0].set_title("Range term (added to measured depth)")
    ax[0].legend(fontsize=8)
    ax[0].grid(alpha=0.3)
    img = m.surface_image()
    lim = float(np.max(np.abs(img))) or 1.0
    im = ax[1].imshow(img, cmap="RdBu_r", vmin=-lim, vmax=lim)
    if m.support.size and np.any(m.support > 0) and np.any(m.support == 0):
        ax[1].contour(m.grid_u, m.grid_v, (m.support > 0).astype(float), levels=[0.5], colors="k", linewidths=1)
    ax[1].set_title(f"Surface term s(u, v) [{m.describe()}]\n(black line: limit of board coverage)", fontsize=9)
    ax[1].set_xlabel("u [px]")
    ax[1].set_ylabel("v [px]")
    fig.colorbar(im, ax=ax[1], label="s [mm]")
    sel = res.selection
    designs = [d for d in ("time", "range", "region") if sel and f"{d}_rms_mm" in sel[0]]
    yy = np.arange(len(sel))
    for j, d in enumerate(designs):
        ax[2].barh(yy + (j - 1) * 0.27, [r[f"{d}_rms_mm"] for r in sel], height=0.27, label=d)
    ax[2].set_yticks(yy)
    ax[2].set_yticklabels([r["name"] + (" +dark" if r["use_dark_views"] else "") + (" <- chosen" if r.get("chosen")
                                                                                     else "") for r in sel], fontsize=7)
    ax[2].invert_yaxis()
    ax[2].set_xlabel("held-out RMS [mm] (white squares)")
    ax[2].set_title("Model selection on blocked folds\n(time: pose blocks in recording order; range bins; image regions)",
                    fontsize=9)
    ax[2].legend(fontsize=8)
    ax[2].grid(alpha=0.3, axis="x")
    db = res.dark_bias
    if len(db.contrast_mm):
        ax[3].plot(np.exp(db.ln_amplitude), db.contrast_mm, "o", ms=4, label="views: median dark - median white")
        if db.known:
            a = np.exp(np.linspace(db.ln_amplitude.min(), db.ln_amplitude.max(), 100))
            ax[3].plot(a, db(a), "-", label=f"fitted b(A) (residual {db.residual_mm:.1f} mm)")
        ax[3].set_xscale("log")
    ax[3].set_xlabel("dark-square IR amplitude")
    ax[3].set_ylabel("dark - white depth bias [mm]")
    ax[3].set_title("Board pattern: dark squares read longer", fontsize=9)
    ax[3].legend(fontsize=8)
    ax[3].grid(alpha=0.3)
    p = res.prediction or {}
    sub = (f"; predicted RMS on new poses {p['rms_mm']:.1f} mm [{p['rms_mm_interval'][0]:.1f}, "
           f"{p['rms_mm_interval'][1]:.1f}]") if p else ""
    fig.suptitle(f"Board-based depth calibration ({len(res.pose_index)} poses, intrinsics: "
                 f"{res.intrinsics_source.split(' (')[0]}){sub}", fontsize=10)
    fig.tight_layout()
    return fig
