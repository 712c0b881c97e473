"""Shared helpers of the pipeline layer: progress, provenance, figure saving."""

from __future__ import annotations

import io
import time
from pathlib import Path

import matplotlib.pyplot as plt

import tofmetry
from tofmetry.io import atomic_write_bytes

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".npy", ".jpg", ".jpeg")


def _adv(advance):
    return advance if advance is not None else (lambda n=1: None)


def _provenance(extra: dict | None) -> dict:
    return {"tool": f"tofmetry {tofmetry.__version__}",
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **(extra or {})}


def _save_fig(fig, path: Path) -> Path:
    """Save a matplotlib figure atomically (PNG) and close it."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())
