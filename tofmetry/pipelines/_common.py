"""Shared helpers of the pipeline layer: progress and provenance."""

from __future__ import annotations

import time

import tofmetry


def _adv(advance):
    return advance if advance is not None else (lambda n=1: None)


def _provenance(extra: dict | None) -> dict:
    return {"tool": f"tofmetry {tofmetry.__version__}",
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **(extra or {})}

