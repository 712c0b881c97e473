"""Figures of the assessment results (matplotlib; one PNG per figure).

Each ``*_figures(result, out_dir)`` writes its PNGs and returns their paths;
:func:`save_figures` dispatches on the result type.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.patches import Rectangle
from matplotlib.ticker import NullFormatter, ScalarFormatter

from tofmetry._shared.figures import save_png, subplots
from tofmetry.assess.materials import MaterialsResult
from tofmetry.assess.noise import NoiseResult
from tofmetry.assess.outdoor import OutdoorResult
from tofmetry.assess.warmup import WarmupResult


def _save(fig, path: Path) -> Path:
    return save_png(fig, path, dpi=110, tight=True)


def warmup_figures(res, out_dir) -> list[Path]:
    """``warmup.png``: patch distance vs operating time, smoothed curve, stabilisation time.

    Where the recording holds temperatures (``res.temperature_c``), the temperature is drawn
    against time on a second axis, and a second panel plots the distance against the temperature
    with the fitted drift per degree (``res.temperature_fit``)."""
    out = Path(out_dir)
    temp = res.temperature_c
    has_temp = temp is not None and np.isfinite(temp).any()
    if has_temp:
        fig, (ax, axt) = subplots(1, 2, figsize=(13, 4.8), gridspec_kw={"width_ratios": [1.45, 1], "wspace": 0.38})
    else:
        fig, ax = subplots(figsize=(8, 4.5))
    t = res.time_s / 60.0
    ax.plot(t, res.distance_mm, ".", ms=3, color="0.6", label="patch mean (per frame)")
    ax.plot(t, res.smoothed_mm, "-", color="C0", lw=2, label=f"smoothed ({res.smooth_window_s:.0f} s window)")
    ax.axhline(res.final_level_mm, color="k", lw=0.8, ls="--", label=f"final level {res.final_level_mm:.1f} mm")
    ax.axhspan(res.final_level_mm - res.tolerance_mm, res.final_level_mm + res.tolerance_mm, color="C2", alpha=0.15,
               label=f"±{res.tolerance_mm:g} mm tolerance")
    if res.stabilisation_time_s is not None:
        ts = res.stabilisation_time_s / 60.0
        ax.axvline(ts, color="C3", lw=1.5, label=f"stable after {ts:.1f} min")
    ax.set_xlabel("operating time since first frame [min]")
    ax.set_ylabel("mean distance of the patch [mm]")
    u0, v0, s = res.patch
    ax.set_title(f"Warm-up drift (patch {s}x{s} px at u={u0}, v={v0}; total drift {res.total_drift_mm:+.1f} mm)",
                 fontsize=10 if has_temp else None)
    ax.grid(alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    if has_temp:
        name = res.temperature_name or "sensor"
        tw = ax.twinx()
        (line,) = tw.plot(t, temp, "-", color="C1", lw=1.2, label=f"{name} temperature")
        tw.set_ylabel(f"{name} temperature [°C]", color="C1")
        tw.tick_params(axis="y", colors="C1")
        handles.append(line)
        labels.append(line.get_label())
        sc = axt.scatter(temp, res.distance_mm, c=t, s=10, cmap="viridis", label="patch mean (per frame)")
        fit = res.temperature_fit
        if fit is not None:
            lo, hi = fit["temperature_range_c"]
            xx = np.array([lo, hi])
            yy = fit["intercept_mm"] + fit["slope_mm_per_c"] * (xx - fit["mean_temperature_c"])
            axt.plot(xx, yy, "-", color="C3", lw=1.5,
                     label=f"{fit['slope_mm_per_c']:+.3f} ± {fit['slope_se_mm_per_c']:.3f} mm/°C (1 s.e., n={fit['n']})")
            axt.set_title(f"Drift against temperature (R² {fit['r2']:.3f})", fontsize=10)
        else:
            axt.set_title("Drift against temperature (too little temperature change for a slope)", fontsize=10)
        axt.set_xlabel(f"{name} temperature [°C]")
        axt.set_ylabel("mean distance of the patch [mm]")
        axt.grid(alpha=0.3)
        axt.legend(fontsize=8, loc="lower right")
        fig.colorbar(sc, ax=axt, label="operating time [min]", shrink=0.9)
    ax.legend(handles, labels, fontsize=8, loc="lower right")
    return [_save(fig, out / "warmup.png")]


def noise_figures(res, out_dir) -> list[Path]:
    """``noise_std_maps.png`` (one map per n, shared colour bar), ``noise_profile.png`` (row profile)
    and ``noise_averaging.png`` (precision of the n-frame mean)."""
    out = Path(out_dir)
    ns = sorted(res.std_maps)
    allv = np.concatenate([m[np.isfinite(m)] for m in res.std_maps.values()])
    vmax = float(np.percentile(allv, 99)) if allv.size else 1.0
    ncol = min(len(ns), 2)
    nrow = int(np.ceil(len(ns) / ncol))
    fig, axes = subplots(nrow, ncol, figsize=(5.2 * ncol, 3.9 * nrow), squeeze=False)
    im = None
    for ax, n in zip(axes.ravel(), ns):
        im = ax.imshow(res.std_maps[n], cmap="viridis", vmin=0, vmax=vmax)
        ax.axhline(res.row, color="r", lw=0.8)
        s = next(x for x in res.summaries if x.n == n)
        ax.set_title(f"n = {n} frames: median {s.median_mm:.2f} mm, spread {s.spread_mm:.2f} mm", fontsize=9)
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
    for ax in axes.ravel()[len(ns):]:
        ax.axis("off")
    fig.suptitle("Per-pixel temporal standard deviation (red line: profile row)")
    fig.colorbar(im, ax=axes.ravel().tolist(), label="temporal std [mm]", shrink=0.85)
    paths = [_save(fig, out / "noise_std_maps.png")]
    fig, ax = subplots(figsize=(8, 4))
    for n in ns:
        ax.plot(res.profiles[n], lw=1, label=f"n = {n}")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("temporal std [mm]")
    ax.set_title(f"Std along image row v = {res.row} (cf. study Fig. 3c)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    paths.append(_save(fig, out / "noise_profile.png"))
    if res.block_precision:
        fig, ax = subplots(figsize=(6, 4))
        n = np.array([b["n"] for b in res.block_precision])
        ax.loglog(n, [b["std_of_mean_mm"] for b in res.block_precision], "o-", label="measured (disjoint blocks)")
        ax.loglog(n, [b["expected_mm"] for b in res.block_precision], "k--", label="σ / √n")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_formatter(ScalarFormatter())
            axis.set_minor_formatter(NullFormatter())
        ax.set_xticks(n)
        lo, hi = ax.get_ylim()
        ax.set_yticks([v for v in (0.05, 0.1, 0.2, 0.3, 0.5, 1, 2, 3, 5, 10, 20) if lo <= v <= hi])
        ax.set_xlabel("frames averaged n")
        ax.set_ylabel("std of the n-frame mean depth [mm]")
        ax.set_title("Precision of the averaged depth")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
        paths.append(_save(fig, out / "noise_averaging.png"))
    return paths


def materials_figures(res, out_dir) -> list[Path]:
    """``materials_samples.png`` (amplitude and bias per sample, bias vs ln amplitude ratio) and
    ``materials_deviation.png`` (map of depth minus reference plane, colour bar, regions outlined)."""
    out = Path(out_dir)
    regs = res.regions
    names = [r.name for r in regs]
    x = np.arange(len(regs))
    colors = ["C3" if r.erratic else ("C2" if r.reference else "C0") for r in regs]
    fig, axes = subplots(1, 3, figsize=(16, 4.5))
    axes[0].bar(x, [r.amplitude for r in regs], color=colors)
    axes[0].set_ylabel("mean IR amplitude [sensor units]")
    axes[0].set_title("Intensity per sample")
    axes[1].bar(x, [r.bias_mm for r in regs], yerr=[r.spatial_std_mm for r in regs], color=colors, capsize=2)
    axes[1].set_ylabel("depth bias vs reference plane [mm]")
    axes[1].set_title("Bias per sample (green: reference, red: erratic)")
    for ax in axes[:2]:
        ax.set_xticks(x)
        ax.set_xticklabels(names, rotation=70, fontsize=7)
        ax.set_xlabel("sample")
        ax.grid(alpha=0.3, axis="y")
    ax = axes[2]
    lr = np.array([r.ln_amp_ratio for r in regs])
    ax.scatter(lr, [r.bias_mm for r in regs], c=colors)
    if np.isfinite(res.slope_mm_per_ln):
        xx = np.linspace(min(0.0, lr.min()), lr.max(), 50)
        ax.plot(xx, res.slope_mm_per_ln * xx + res.intercept_mm, "k-",
                label=f"{res.slope_mm_per_ln:.2f} ± {res.slope_se_mm_per_ln:.2f} mm per ln unit")
        ax.legend(fontsize=8)
    ax.set_xlabel("ln(A_ref / A)  [-]")
    ax.set_ylabel("depth bias [mm]")
    ax.set_title("Amplitude-related bias")
    ax.grid(alpha=0.3)
    paths = [_save(fig, out / "materials_samples.png")]
    fig, ax = subplots(figsize=(8, 6))
    dev = res.deviation_mm
    rr = [r.rect for r in regs]
    u0, v0 = min(r[0] for r in rr), min(r[1] for r in rr)
    u1, v1 = max(r[2] for r in rr), max(r[3] for r in rr)
    pad = 20
    # colour range from the regions themselves (edges with mixed pixels would dominate otherwise)
    fin = np.concatenate([dev[r[1]:r[3], r[0]:r[2]].ravel() for r in rr])
    fin = fin[np.isfinite(fin)]
    lim = max(float(np.percentile(np.abs(fin), 99)), 1.0) if fin.size else 1.0
    im = ax.imshow(dev, cmap="RdBu_r", vmin=-lim, vmax=lim)
    for r, reg in zip(rr, regs):
        ax.add_patch(Rectangle((r[0] - 0.5, r[1] - 0.5), r[2] - r[0], r[3] - r[1], fill=False,
                               ec="k" if not reg.erratic else "m", lw=0.8))
    ax.set_xlim(max(u0 - pad, 0) - 0.5, min(u1 + pad, dev.shape[1]) - 0.5)
    ax.set_ylim(min(v1 + pad, dev.shape[0]) - 0.5, max(v0 - pad, 0) - 0.5)
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    ax.set_title("Depth deviation from the reference (white) plane")
    fig.colorbar(im, ax=ax, label="mean depth − plane [mm]")
    paths.append(_save(fig, out / "materials_deviation.png"))
    return paths


def outdoor_figures(res, out_dir, cloud) -> list[Path]:
    """``outdoor_profile.png``: side view of the cloud (flying pixels red) and the validity map.

    ``cloud``: the :func:`~tofmetry.assess.flying_cloud` of ``res`` (points [m], colours, is_flying).
    """
    out = Path(out_dir)
    pts, _, fly = cloud
    fig, axes = subplots(1, 2, figsize=(14, 5), gridspec_kw={"width_ratios": [1.4, 1]})
    ax = axes[0]
    ax.scatter(pts[~fly, 2], -pts[~fly, 1], s=0.3, c="0.35", rasterized=True, label="valid points")
    ax.scatter(pts[fly, 2], -pts[fly, 1], s=1.5, c="red", rasterized=True, label="flying pixels")
    ax.set_xlabel("depth Z along the optical axis [m]")
    ax.set_ylabel("height −Y (camera frame, up) [m]")
    ax.set_title(f"Profile view of frame {res.frame}: {len(pts)} points, {fly.sum()} flying ({fly.mean() * 100 if len(fly) else 0:.1f} %)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, markerscale=6)
    ax = axes[1]
    img = np.where(res.depth > 0, res.depth / 1000.0, np.nan)
    im = ax.imshow(img, cmap="turbo")
    yy, xx = np.nonzero(res.flying_mask)
    ax.scatter(xx, yy, s=0.5, c="red")
    ax.set_title(f"Depth (valid {res.valid[res.frame] / res.n_max * 100:.1f} % of {res.n_max}); flying in red")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    fig.colorbar(im, ax=ax, label="depth Z [m]", shrink=0.8)
    return [_save(fig, out / "outdoor_profile.png")]


def save_figures(result, out_dir, **kwargs) -> list[Path]:
    """Write the figures of any assessment result into ``out_dir``.

    An :class:`OutdoorResult` needs ``cloud=`` (see :func:`outdoor_figures`)."""
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    if isinstance(result, WarmupResult):
        return warmup_figures(result, out_dir)
    if isinstance(result, NoiseResult):
        return noise_figures(result, out_dir)
    if isinstance(result, MaterialsResult):
        return materials_figures(result, out_dir)
    if isinstance(result, OutdoorResult):
        return outdoor_figures(result, out_dir, **kwargs)
    raise TypeError(f"save_figures: unknown result type {type(result).__name__}")
