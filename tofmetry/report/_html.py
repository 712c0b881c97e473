"""Self-contained HTML report: embedded PNG figures, tables, and an offline 3-D viewer.

The report is a pure function of a :class:`Report` (plain data); nothing here reads result
files except the PNG figures it embeds (base64) — the caller gives their paths.
"""

from __future__ import annotations

import base64
import html
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from plotly.offline import get_plotlyjs

STATUS_BADGE = {"ok": ("#1a7f37", "done"), "skipped": ("#9a6700", "skipped"), "failed": ("#cf222e", "failed")}


@dataclass
class Section:
    """One report section.

    Attributes
    ----------
    key : str  anchor id (e.g. ``"warmup"``)
    title : str
    status : ``"ok"`` | ``"skipped"`` | ``"failed"``
    paragraphs : list of str (plain text; escaped)
    tables : list of (caption, header, rows)
    figures : list of (caption, png path)
    note : str  reason when skipped/failed (error message)
    """

    key: str
    title: str
    status: str = "ok"
    paragraphs: list[str] = field(default_factory=list)
    tables: list[tuple[str, list[str], list[list]]] = field(default_factory=list)
    figures: list[tuple[str, Path]] = field(default_factory=list)
    note: str = ""


@dataclass
class ComparisonRow:
    """A line of the final table: our figure next to the reference study's."""

    quantity: str
    ours: str
    study: str
    study_ref: str
    verdict: str  # "better" | "comparable" | "worse" | "n/a"
    comment: str = ""


@dataclass
class Report:
    title: str
    subtitle: str
    sections: list[Section]
    comparison: list[ComparisonRow]
    viewer_points: np.ndarray | None = None  # (N, 3) float [m]
    viewer_values: np.ndarray | None = None  # (N,) deviation [mm]
    viewer_range_mm: float = 5.0
    meta: dict = field(default_factory=dict)


def _fmt(v) -> str:
    if isinstance(v, float):
        if v != v:
            return "–"
        return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"
    return html.escape(str(v))


def _table(caption: str, header: list[str], rows: list[list]) -> str:
    th = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table><caption>{html.escape(caption)}</caption><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>'


def _figure(caption: str, path: Path) -> str:
    path = Path(path)
    if not path.is_file():
        return f'<p class="missing">figure missing: {html.escape(str(path.name))}</p>'
    data = path.read_bytes()
    b64 = base64.b64encode(data).decode()
    wide = ""
    if data[:8] == b"\x89PNG\r\n\x1a\n":  # PNG IHDR: width, height at bytes 16..24
        w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
        wide = ' class="wide"' if h and w / h > 2.2 else ""
    return (f'<figure{wide}><img alt="{html.escape(caption)}" src="data:image/png;base64,{b64}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _section(s: Section) -> str:
    color, label = STATUS_BADGE.get(s.status, ("#57606a", s.status))
    parts = [f'<section id="{html.escape(s.key)}" class="study-section" data-status="{s.status}">',
             f'<h2>{html.escape(s.title)} <span class="badge" style="background:{color}">{label}</span></h2>']
    if s.note:
        parts.append(f'<p class="note">{html.escape(s.note)}</p>')
    parts += [f"<p>{html.escape(p)}</p>" for p in s.paragraphs]
    parts += [_table(*t) for t in s.tables]
    if s.figures:
        parts.append('<div class="figs">' + "".join(_figure(c, p) for c, p in s.figures) + "</div>")
    parts.append("</section>")
    return "\n".join(parts)


#: stops of the viewer's colour scale (the deviation map sampled this finely; Plotly interpolates
#: linearly in RGB between them, as matplotlib does between the map's own stops)
COLORSCALE_STOPS = 33


def deviation_colorscale(rng: float, n: int = COLORSCALE_STOPS) -> list[list]:
    """The deviation colour map as a Plotly colour scale over ``-rng .. +rng`` [mm].

    Sampled from :func:`tofmetry.evaluate.deviation_colors`, the one definition of the map that the
    evaluation's figures and the coloured ``deviation.ply`` use: negative (model inside the reference)
    blue, zero white, positive red, saturating at ``±rng``.

    Returns
    -------
    ``[[t, "rgb(r,g,b)"], ...]`` with ``t`` from 0 (``-rng``) to 1 (``+rng``).
    """
    from tofmetry.evaluate import deviation_colors

    t = np.linspace(0.0, 1.0, n)
    rgb = deviation_colors((2.0 * t - 1.0) * rng / 1000.0, rng)
    return [[float(x), f"rgb({r},{g},{b})"] for x, (r, g, b) in zip(t, rgb.tolist())]


def _viewer(points: np.ndarray, values: np.ndarray, rng: float, max_points: int = 60000) -> str:
    pts = np.asarray(points, float)
    vals = np.asarray(values, float)
    if len(pts) > max_points:
        sel = np.random.default_rng(0).choice(len(pts), max_points, replace=False)
        pts, vals = pts[sel], vals[sel]
    pts_mm = np.round(pts * 1000.0, 1)
    data = {"x": pts_mm[:, 0].tolist(), "y": pts_mm[:, 1].tolist(), "z": pts_mm[:, 2].tolist(),
            "d": np.round(vals, 2).tolist(), "r": rng, "scale": deviation_colorscale(rng)}
    return f"""
<section id="viewer" class="study-section"><h2>Interactive deviation model</h2>
<p>Drag to rotate, scroll to zoom. Colour: signed deviation from the reference [mm], fixed scale
±{rng:g} mm (saturating), the same colour map as the figures and the coloured deviation.ply (blue: model
inside the reference, red: outside). Coordinates in mm.</p>
<div id="viewer3d" style="width:100%;height:560px" data-points="0"></div>
<script>{get_plotlyjs()}</script>
<script>
(function() {{
  const D = {json.dumps(data)};
  const trace = {{type: 'scatter3d', mode: 'markers', x: D.x, y: D.y, z: D.z,
    marker: {{size: 1.6, color: D.d, cmin: -D.r, cmax: D.r, colorscale: D.scale,
      colorbar: {{title: {{text: 'deviation [mm]'}}, ticksuffix: ' mm'}}}},
    hovertemplate: '%{{marker.color:.2f}} mm<extra></extra>'}};
  const layout = {{margin: {{l: 0, r: 0, t: 0, b: 0}}, scene: {{aspectmode: 'data',
    xaxis: {{title: 'x [mm]'}}, yaxis: {{title: 'y [mm]'}}, zaxis: {{title: 'z [mm]'}},
    camera: {{up: {{x: 0, y: -1, z: 0}}, eye: {{x: 0.2, y: -0.8, z: -1.6}}}}}}}};
  Plotly.newPlot('viewer3d', [trace], layout, {{displaylogo: false, responsive: true}}).then(function() {{
    document.getElementById('viewer3d').dataset.points = String(D.x.length);
  }});
}})();
</script></section>"""


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#1f2328;line-height:1.45}
h1{margin-bottom:0}.subtitle{color:#57606a;margin-top:.2em}
h2{border-bottom:1px solid #d0d7de;padding-bottom:.2em;margin-top:2em}
.badge{font-size:.55em;color:#fff;padding:.15em .5em;border-radius:1em;vertical-align:middle}
table{border-collapse:collapse;margin:1em 0;font-size:.92em}caption{text-align:left;font-weight:600;padding:.3em 0}
th,td{border:1px solid #d0d7de;padding:.3em .6em;text-align:right}th{background:#f6f8fa}td:first-child,th:first-child{text-align:left}
.figs{display:flex;flex-wrap:wrap;gap:1em}figure{margin:0;flex:1 1 480px;max-width:100%}
figure img{max-width:100%;border:1px solid #d0d7de}figure.wide{flex-basis:100%}figcaption{font-size:.85em;color:#57606a}
.note{background:#fff8c5;border:1px solid #d4a72c;padding:.5em;border-radius:4px;white-space:pre-wrap}
.verdict-better{color:#1a7f37;font-weight:600}.verdict-worse{color:#cf222e;font-weight:600}.verdict-comparable{color:#57606a}.verdict-consistent{color:#0969da}.verdict-differs{color:#9a6700;font-weight:600}
nav a{margin-right:1em}
@media print{#viewer{display:none}figure{page-break-inside:avoid}section{page-break-inside:avoid}}
"""


def render_html(report: Report) -> str:
    """Render a :class:`Report` to one self-contained HTML string (works offline)."""
    nav = " ".join(f'<a href="#{html.escape(s.key)}">{html.escape(s.title)}</a>' for s in report.sections)
    comp_rows = "".join(
        f"<tr><td>{html.escape(r.quantity)}</td><td>{html.escape(r.ours)}</td><td>{html.escape(r.study)}</td>"
        f"<td>{html.escape(r.study_ref)}</td><td class=\"verdict-{html.escape(r.verdict)}\">{html.escape(r.verdict)}</td>"
        f"<td>{html.escape(r.comment)}</td></tr>"
        for r in report.comparison
    )
    comparison = (
        '<section id="comparison" class="study-section"><h2>Side by side with the reference study</h2>'
        "<table><thead><tr><th>quantity</th><th>tofmetry (this run)</th><th>reference study</th><th>where</th>"
        f"<th>verdict</th><th>comment</th></tr></thead><tbody>{comp_rows}</tbody></table></section>"
    )
    viewer = ""
    if report.viewer_points is not None and len(report.viewer_points):
        viewer = _viewer(report.viewer_points, report.viewer_values, report.viewer_range_mm)
    meta = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{_fmt(v)}</td></tr>" for k, v in report.meta.items())
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(report.title)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{CSS}</style></head>
<body><h1>{html.escape(report.title)}</h1><p class="subtitle">{html.escape(report.subtitle)}</p>
<nav>{nav} <a href="#comparison">Comparison</a></nav>
<table><caption>Run</caption><tbody>{meta}</tbody></table>
{"".join(_section(s) for s in report.sections)}
{viewer}
{comparison}
<footer><p>Generated by tofmetry. Reference study: Lachat, Macher, Landes, Grussenmeyer, "Assessment and
Calibration of a RGB-D Camera (Kinect v2 Sensor) Towards a Potential Use for Close-Range 3D Modeling",
Remote Sens. 2015, 7, 13070–13097.</p></footer>
</body></html>
"""
