"""``rig.json``: the extrinsics of a rig of sensors (``tofmetry calibrate rig``).

Format 1::

    {"format": "tofmetry-rig", "version": 1, "rig_frame": "<name of sensor 0>",
     "sensors": [{"name": str, "intrinsics": {...intrinsics.json...},
                  "rig_to_sensor": {"rotation": 3x3, "translation_m": [3]},   # p_sensor = R p_rig + t
                  "rotation_std_deg": [3], "translation_std_mm": [3],          # jackknife, 0 for sensor 0
                  "heldout_rms_px": float|null, ...}, ...],
     ...diagnostics}

Sensor 0 defines the rig frame (its camera frame: x right, y down, z forward, metres).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tofmetry.errors import InputError
from tofmetry.io._atomic import atomic_write_json, read_json
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics

RIG_FORMAT, RIG_VERSION = "tofmetry-rig", 1


@dataclass(frozen=True)
class RigSensor:
    """One sensor of a rig file: name, intrinsics, rig -> sensor extrinsics [m] and their uncertainty."""

    name: str
    intrinsics: CameraIntrinsics
    rig_to_sensor: Extrinsics
    rotation_std_deg: tuple
    translation_std_mm: tuple


def write_rig(path: str | os.PathLike, sensors: list[RigSensor], **extra) -> Path:
    """Write ``rig.json`` atomically; ``extra`` keys (diagnostics) are added at the top level and
    per sensor under ``extra["per_sensor"]`` (a list, one dict per sensor)."""
    per = extra.pop("per_sensor", None) or [{} for _ in sensors]
    if len(per) != len(sensors):
        raise InputError(f"write_rig: {len(per)} per-sensor diagnostics for {len(sensors)} sensors")
    d = {"format": RIG_FORMAT, "version": RIG_VERSION, "rig_frame": sensors[0].name if sensors else None,
         "sensors": [{"name": s.name, "intrinsics": s.intrinsics.to_dict(), "rig_to_sensor": s.rig_to_sensor.to_dict(),
                      "rotation_std_deg": [float(x) for x in s.rotation_std_deg],
                      "translation_std_mm": [float(x) for x in s.translation_std_mm], **p}
                     for s, p in zip(sensors, per)]}
    d.update(extra)
    return atomic_write_json(path, d)


def read_rig(path: str | os.PathLike) -> list[RigSensor]:
    """Read ``rig.json`` (format 1); errors name the file and what is missing."""
    d = read_json(path, "rig file")
    if d.get("format") != RIG_FORMAT or d.get("version") != RIG_VERSION:
        raise InputError(f"{path}: expected format {RIG_FORMAT!r} version {RIG_VERSION}, found "
                         f"{d.get('format')!r} version {d.get('version')!r}")
    out = []
    for k, s in enumerate(d.get("sensors") or []):
        where = f"{path}: sensors[{k}]"
        try:
            out.append(RigSensor(str(s["name"]), CameraIntrinsics.from_dict(s["intrinsics"], source=where),
                                 Extrinsics.from_dict(s["rig_to_sensor"], source_name=where),
                                 tuple(float(x) for x in s["rotation_std_deg"]),
                                 tuple(float(x) for x in s["translation_std_mm"])))
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{where}: expected name, intrinsics, rig_to_sensor, rotation_std_deg, "
                             f"translation_std_mm ({e})") from None
        if len(out[-1].rotation_std_deg) != 3 or len(out[-1].translation_std_mm) != 3:
            raise InputError(f"{where}: rotation_std_deg and translation_std_mm need 3 values each")
    if len(out) < 2:
        raise InputError(f"{path}: a rig needs at least 2 sensors, found {len(out)}")
    if not np.allclose(out[0].rig_to_sensor.matrix, np.eye(4)):
        raise InputError(f"{path}: sensor 0 ({out[0].name}) defines the rig frame: its rig_to_sensor must be identity")
    return out
