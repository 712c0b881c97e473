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


def test_viewer_scale_is_the_evaluation_colour_map():
    """One colour map: the viewer's scale is sampled from the map of the figures and deviation.ply."""
    from tofmetry.evaluate import deviation_colors
    from tofmetry.report._html import deviation_colorscale

    scale = deviation_colorscale(5.0)
    assert scale[0][0] == 0.0 and scale[-1][0] == 1.0
    for t, mm in ((0.0, -5.0), (0.5, 0.0), (1.0, 5.0)):
        rgb = [c for t2, c in scale if t2 == t][0]
        exp = deviation_colors(np.array([mm / 1000.0]), 5.0)[0]
        assert rgb == f"rgb({exp[0]},{exp[1]},{exp[2]})"
    neg = deviation_colors(np.array([-0.004]), 5.0)[0].astype(int)
    assert neg[2] > neg[0]           # negative deviations are blue, as in the figures' RdBu_r


def _browser_pixels(html_path):
    """(viewer screenshot as (H, W, 3) uint8, the colour bar's box in it) from headless Chromium."""
    import shutil
    from io import BytesIO

    from PIL import Image

    sync_api = pytest.importorskip("playwright.sync_api")
    exe = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)
    if exe is None:
        pytest.fail("no chromium on PATH: scripts/setup-env.sh installs Debian's 'chromium' package")
    args = ["--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"]
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=exe, args=args)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(html_path.resolve().as_uri())
            page.wait_for_function("document.getElementById('viewer3d').dataset.points !== '0'", timeout=60000)
            viewer = page.query_selector("#viewer3d")
            viewer.scroll_into_view_if_needed()
            page.wait_for_timeout(500)
            box = viewer.bounding_box()
            bar = page.evaluate("(() => { const r = document.querySelector('#viewer3d .colorbar .cbfills')"
                                ".getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; })()")
            img = np.asarray(Image.open(BytesIO(viewer.screenshot())).convert("RGB"))
        finally:
            browser.close()
    x0, y0, x1, y1 = bar
    return img, (x0 - box["x"], y0 - box["y"], x1 - box["x"], y1 - box["y"])


@pytest.mark.browser
def test_viewer_pixels_match_the_legend(tmp_path):
    """Sampled in the browser: a model whose every point deviates by -0.8 x the scale is drawn in the
    colour the legend shows at -0.8 x the scale (and in the figures' colour), not in the opposite one."""
    from tofmetry.evaluate import deviation_colors

    rng = np.random.default_rng(1)
    pts = rng.normal(size=(20000, 3)) * [0.03, 0.03, 0.002] + [0, 0, 1]
    vals = np.full(len(pts), -4.0)
    rep = Report(title="t", subtitle="", sections=[], comparison=[], viewer_points=pts, viewer_values=vals,
                 viewer_range_mm=5.0)
    path = tmp_path / "r.html"
    path.write_text(render_html(rep))
    img, (bx0, by0, bx1, by1) = _browser_pixels(path)
    expected = deviation_colors(np.array([-0.004]), 5.0)[0].astype(float)
    opposite = deviation_colors(np.array([0.004]), 5.0)[0].astype(float)
    # the legend at -4 mm: 10 % of the bar's height above its bottom (the bar spans -5 .. +5 mm)
    yl = int(round(by1 - 0.1 * (by1 - by0)))
    legend = img[yl - 1:yl + 2, int((bx0 + bx1) / 2) - 1:int((bx0 + bx1) / 2) + 2].reshape(-1, 3).mean(0)
    assert np.abs(legend - expected).max() < 12, (legend, expected)
    # the model: saturated pixels outside the colour bar
    mask = np.ones(img.shape[:2], bool)
    mask[:, int(bx0) - 40:] = False                        # the bar, its ticks and labels
    px = img[mask].astype(float)
    coloured = px[np.abs(px - px.mean(1, keepdims=True)).max(1) > 25]   # not white/grey/black
    assert len(coloured) > 200, len(coloured)
    d_exp = np.linalg.norm(coloured - expected, axis=1)
    d_opp = np.linalg.norm(coloured - opposite, axis=1)
    assert np.mean(d_exp < d_opp) > 0.95
    assert np.median(d_exp) < 40, np.median(coloured, axis=0)
