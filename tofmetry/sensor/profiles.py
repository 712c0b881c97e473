"""Sensor profiles: typical, published parameters of a sensor model.

These are *typical* values of the model, not of one device. A real device differs by a
few pixels in focal length and principal point (see ``../shared/data/kinect2-device-calibrations``):
calibrate yours (``tofmetry calibrate intrinsics``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics


@dataclass(frozen=True)
class SensorProfile:
    """Published characteristics of a sensor model.

    Attributes
    ----------
    name : str
        Sensor identity written into captures and calibrations (e.g. ``"kinect_v2"``).
    depth : CameraIntrinsics
        Typical IR/depth camera intrinsics.
    color : CameraIntrinsics
        Typical colour camera intrinsics.
    ir_to_color : Extrinsics
        Typical IR -> colour transform [m].
    min_range_mm, max_range_mm : float
        Operative measuring range [mm] (Z).
    fps : float
        Frame rate [1/s].
    modulation_mhz : tuple of float
        Modulation frequencies of the continuous-wave ToF illumination [MHz] (empty when
        unknown). The depth calibration uses them as candidate wiggling periods ``c / (2 f)``.
    """

    name: str
    depth: CameraIntrinsics
    color: CameraIntrinsics
    ir_to_color: Extrinsics
    min_range_mm: float
    max_range_mm: float
    fps: float
    modulation_mhz: tuple = ()

    @property
    def n_pixels(self) -> int:
        return self.depth.width * self.depth.height


def _from_fov(width: int, height: int, hfov_deg: float, vfov_deg: float, dist=(0, 0, 0, 0, 0)) -> CameraIntrinsics:
    fx = width / (2 * math.tan(math.radians(hfov_deg) / 2))
    fy = height / (2 * math.tan(math.radians(vfov_deg) / 2))
    return CameraIntrinsics(width, height, fx, fy, (width - 1) / 2, (height - 1) / 2, dist)


#: Kinect v2 (Microsoft, 2014). Typical values: 512x424 depth/IR (70.6 x 60 deg),
#: 1920x1080 colour (84.1 x 53.8 deg), 0.5-4.5 m, 30 fps (paper Table 1). The depth
#: intrinsics below are the median of the 9 real devices in
#: ``shared/data/kinect2-device-calibrations`` rounded (fx ~ 365 px, k1 ~ 0.09, k2 ~ -0.27,
#: k3 ~ 0.09), which gives the published ~70 x 60 deg field of view.
KINECT_V2 = SensorProfile(
    name="kinect_v2",
    depth=CameraIntrinsics(512, 424, 365.0, 365.0, 256.5, 207.0, (0.09, -0.27, 0.0, 0.0, 0.09)),
    color=CameraIntrinsics(1920, 1080, 1060.0, 1060.0, 959.5, 539.5, (0.02, -0.03, 0.0, 0.0, 0.0)),
    ir_to_color=Extrinsics(np.eye(3), np.array([0.052, 0.0, 0.0])),
    min_range_mm=500.0,
    max_range_mm=4500.0,
    fps=30.0,
    modulation_mhz=(80.0, 16.0, 120.0),  # the three frequencies libfreenect2 decodes (half wavelengths 1.87, 9.37, 1.25 m)
)

#: Azure Kinect DK, NFOV unbinned depth mode (640x576, 75 x 65 deg, 0.5-3.86 m) and 1280x720 colour.
#: Typical values; each device carries its factory calibration (``tofmetry import azure-kinect``).
AZURE_KINECT = SensorProfile(
    name="azure_kinect",
    depth=CameraIntrinsics(640, 576, 504.0, 504.0, 319.5, 287.5, (0.0, 0.0, 0.0, 0.0, 0.0)),
    color=CameraIntrinsics(1280, 720, 612.0, 612.0, 639.5, 359.5, (0.0, 0.0, 0.0, 0.0, 0.0)),
    ir_to_color=Extrinsics(np.eye(3), np.array([-0.032, -0.002, 0.004]), "ir", "color"),
    min_range_mm=500.0, max_range_mm=3860.0, fps=30.0,
)

PROFILES: dict[str, SensorProfile] = {KINECT_V2.name: KINECT_V2, AZURE_KINECT.name: AZURE_KINECT}


def get_profile(name: str) -> SensorProfile:
    """Look up a sensor profile by name; error lists the known ones."""
    try:
        return PROFILES[name]
    except KeyError:
        raise InputError(f"unknown sensor {name!r}; known profiles: {sorted(PROFILES)}") from None


def register_profile(profile: SensorProfile) -> None:
    """Add a profile (e.g. ``azure_kinect`` from an importer)."""
    PROFILES[profile.name] = profile
