"""The HTML report renders offline in a real browser: sections, figures, 3-D viewer, no errors."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from tofmetry.report import ComparisonRow, Report, Section, render_html  # noqa: E402



def _figure(path):
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([0, 1, 2], [1, 0, 2])
    ax.set(title="t", xlabel="x [m]", ylabel="y [mm]")
    fig.savefig(path, dpi=60)
    plt.close(fig)
    return path


def _report(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(2000, 3)) * 0.05 + [0, 0, 1]
    return Report(
        title="tofmetry study", subtitle="unit test",
        sections=[
            Section("warmup", "Warm-up", figures=[("curve", _figure(tmp_path / "a.png"))], tables=[("t", ["a", "b"], [[1, 2.5]])]),
            Section("noise", "Noise", status="skipped", note="no noise/ folder"),
            Section("model", "Object model", status="failed", note="Traceback: boom <script>alert(1)</script>"),
        ],
        comparison=[ComparisonRow("mean |d|", "0.8 mm", "2 mm", "§5.3", "better")],
        viewer_points=pts, viewer_values=rng.normal(size=2000), meta={"machine": "test"},
    )


def test_report_is_self_contained(tmp_path):
    html = render_html(_report(tmp_path))
    assert "data:image/png;base64," in html
    assert "<script>alert(1)</script>" not in html  # error text is escaped
    assert "http://" not in html.split("<script>")[0] and 'src="http' not in html  # nothing fetched from the network


@pytest.mark.browser
def test_report_renders_in_headless_chromium(tmp_path, inspect):
    path = tmp_path / "report.html"
    path.write_text(render_html(_report(tmp_path)))
    page = inspect(path, tmp_path / "report.png")
    assert page.sections == {"warmup": "ok", "noise": "skipped", "model": "failed", "viewer": "ok", "comparison": "ok"}
    assert page.images == 1 and page.broken_images == 0
    assert page.viewer_points == 2000 and page.canvas_nonblank
    assert page.console_errors == []
    assert (tmp_path / "report.png").stat().st_size > 1000
