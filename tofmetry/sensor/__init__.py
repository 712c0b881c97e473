"""Sensor models: intrinsics (pinhole + Brown), extrinsics, sensor profiles."""

from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics
from tofmetry.sensor.profiles import AZURE_KINECT, KINECT_V2, PROFILES, SensorProfile, get_profile, register_profile

__all__ = ["CameraIntrinsics", "Extrinsics", "SensorProfile", "KINECT_V2", "AZURE_KINECT", "PROFILES", "get_profile", "register_profile"]
