"""Write an evaluation's outputs: metrics.json, histogram.png, deviation.ply, deviation_render.png."""

from __future__ import annotations

import os
from pathlib import Path

from tofmetry._shared.figures import save_png
from tofmetry.evaluate._evaluate import EvaluationResult
from tofmetry.evaluate._figures import deviation_colors, histogram_figure, render_figure
from tofmetry.io import atomic_write_json, write_ply


def write_evaluation(out_dir: str | os.PathLike, result: EvaluationResult, title: str = "model vs reference",
                     extra: dict | None = None) -> dict[str, Path]:
    """Write the evaluation outputs into ``out_dir`` (created if needed); returns name -> path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scale = result.config.color_scale_mm
    metrics = result.to_dict()
    if extra:
        metrics.update(extra)
    paths = {"metrics": atomic_write_json(out / "metrics.json", metrics)}
    paths["histogram"] = save_png(
        histogram_figure(result.deviation_m, result.on_edge, result.stats_trimmed.to_dict(),
                         f"{title}: deviation histogram ({result.comparison})"), out / "histogram.png")
    paths["deviation_ply"] = write_ply(out / "deviation.ply", result.points,
                                       colors=deviation_colors(result.deviation_m, scale),
                                       scalars={"deviation_mm": result.deviation_m * 1e3,
                                                "edge_trimmed": result.on_edge.astype(float)})
    paths["render"] = save_png(
        render_figure(result.points, result.deviation_m, scale, f"{title}: signed deviation (RdBu_r, +-{scale:g} mm)"),
        out / "deviation_render.png")
    return paths
