"""Shared test configuration."""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("TOFMETRY_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real recordings in ../shared/data (skips when absent)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data folder {SHARED_DATA} not present")
    return SHARED_DATA


# ----------------------------------------------------------------- headless browser (report tests)
CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
    "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
    "--disable-quic",
]


def chromium_path() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        p = shutil.which(name)
        if p:
            return p
    pytest.fail("no chromium on PATH: scripts/setup-env.sh installs Debian's 'chromium' package")


@dataclass
class PageReport:
    sections: dict[str, str]  # id -> status
    images: int
    broken_images: int
    viewer_points: int
    canvas_nonblank: bool
    console_errors: list[str] = field(default_factory=list)


def inspect_report(html_path: Path, screenshot: Path) -> PageReport:
    sync_api = pytest.importorskip("playwright.sync_api")
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(Path(html_path).resolve().as_uri())
            page.wait_for_load_state("load")
            viewer = page.query_selector("#viewer3d")
            points = 0
            nonblank = False
            if viewer is not None:
                page.wait_for_function("document.getElementById('viewer3d').dataset.points !== '0'", timeout=60000)
                points = int(page.evaluate("document.getElementById('viewer3d').dataset.points"))
                viewer.scroll_into_view_if_needed()
                shot = viewer.screenshot()
                # a rendered point cloud differs from a blank (white) area
                from io import BytesIO

                import numpy as np
                from PIL import Image

                img = np.asarray(Image.open(BytesIO(shot)).convert("L"), float)
                nonblank = bool((img < 200).mean() > 0.002)
            sections = page.evaluate(
                "Object.fromEntries([...document.querySelectorAll('section.study-section')]"
                ".map(s => [s.id, s.dataset.status || 'ok']))"
            )
            imgs = page.evaluate("[...document.images].map(i => i.complete && i.naturalWidth > 0)")
            page.evaluate("window.scrollTo(0, 0)")
            page.screenshot(path=str(screenshot), full_page=False)
        finally:
            browser.close()
    return PageReport(sections, len(imgs), sum(1 for ok in imgs if not ok), points, nonblank, errors)


@pytest.fixture
def inspect():
    """The :func:`inspect_report` function, as a fixture (tests import nothing from here)."""
    return inspect_report
