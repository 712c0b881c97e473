"""``intrinsics.json``: the contract format for one camera's intrinsics."""

from __future__ import annotations

import os
from pathlib import Path

from tofmetry.io._atomic import atomic_write_json, read_json
from tofmetry.sensor.intrinsics import CameraIntrinsics


def read_intrinsics(path: str | os.PathLike) -> CameraIntrinsics:
    """Read ``{"width","height","fx","fy","cx","cy","distortion":[k1,k2,p1,p2,k3]}``.

    Extra keys (e.g. ``"sensor"``, uncertainties) are ignored.
    """
    return CameraIntrinsics.from_dict(read_json(path, "intrinsics file"), source=str(path))


def write_intrinsics(path: str | os.PathLike, intr: CameraIntrinsics, **extra) -> Path:
    """Write intrinsics (plus optional extra keys such as ``sensor`` or ``rms_px``) atomically."""
    d = intr.to_dict()
    d.update(extra)
    return atomic_write_json(path, d)
