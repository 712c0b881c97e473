"""Deviation colouring and figures (figures returned, not saved).

Saving: :func:`tofmetry._shared.figures.save_png`.
"""

from __future__ import annotations

import textwrap

import matplotlib
import numpy as np

from tofmetry._shared.figures import subplots
from tofmetry._shared.geometry import principal_axes


COLORMAP = "RdBu_r"


def deviation_colors(deviation_m: np.ndarray, scale_mm: float) -> np.ndarray:
    """(N,) signed deviations [m] -> (N, 3) uint8 RGB, diverging map saturating at +-scale_mm."""
    cmap = matplotlib.colormaps[COLORMAP]
    t = np.clip((np.asarray(deviation_m) * 1e3 / scale_mm + 1.0) / 2.0, 0.0, 1.0)
    return (cmap(t)[:, :3] * 255).round().astype(np.uint8)


def histogram_figure(deviation_m: np.ndarray, on_edge: np.ndarray, stats: dict, title: str):
    """Histogram of signed deviations [mm] (all points and after edge trimming)."""
    d = np.asarray(deviation_m) * 1e3
    lim = max(5.0, float(np.percentile(np.abs(d), 99.5)))
    bins = np.linspace(-lim, lim, 121)
    fig, ax = subplots(figsize=(7, 4.2))
    ax.hist(np.clip(d, -lim, lim), bins=bins, color="0.7", label=f"all ({d.size} points)")
    ax.hist(np.clip(d[~on_edge], -lim, lim), bins=bins, histtype="step", color="C0", lw=1.5,
            label=f"edge-trimmed ({int((~on_edge).sum())})")
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("signed deviation model - reference [mm]")
    ax.set_ylabel("number of points")
    ax.set_title("\n".join(textwrap.wrap(title, 60)), fontsize=10)
    txt = (f"mean |d| {stats['mean_abs_mm']:.2f} mm, std {stats['std_signed_mm']:.2f} mm\n"
           f"p95 |d| {stats['percentiles_abs_mm']['p95']:.2f} mm, max {stats['max_abs_mm']:.2f} mm (trimmed)")
    ax.text(0.02, 0.97, txt, transform=ax.transAxes, va="top", fontsize=8,
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.8"})
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    return fig


def render_figure(points: np.ndarray, deviation_m: np.ndarray, scale_mm: float, title: str, max_points: int = 60_000):
    """Three orthographic views (principal axes) of points coloured by deviation, with colour bar."""
    p = np.asarray(points)
    d = np.asarray(deviation_m) * 1e3
    if len(p) > max_points:
        sel = np.random.default_rng(0).choice(len(p), max_points, replace=False)
        p, d = p[sel], d[sel]
    c, axes = principal_axes(p)
    q = (p - c) @ axes.T * 1e3  # principal frame [mm]
    views = [(0, 1, 2, "view along 3rd axis"), (0, 2, 1, "view along 2nd axis"), (1, 2, 0, "view along 1st axis")]
    fig, axes = subplots(1, 3, figsize=(15, 5))
    fig.subplots_adjust(wspace=0.4)
    sc = None
    for ax, (i, j, k, name) in zip(axes, views):
        order = np.argsort(q[:, k])  # painter's order: far first
        sc = ax.scatter(q[order, i], q[order, j], c=d[order], s=1.5, cmap=COLORMAP, vmin=-scale_mm, vmax=scale_mm,
                        linewidths=0)
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(f"principal axis {i + 1} [mm]")
        ax.set_ylabel(f"principal axis {j + 1} [mm]")
    cb = fig.colorbar(sc, ax=axes, shrink=0.85, extend="both")
    cb.set_label(f"signed deviation [mm] (saturating at +-{scale_mm:g})")
    fig.suptitle(title)
    return fig
