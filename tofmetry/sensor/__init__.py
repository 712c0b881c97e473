"""Sensor models: intrinsics (pinhole + Brown, rational or fisheye lens), extrinsics, sensor profiles."""

from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics
from tofmetry.sensor.lens import LENS_MODELS
from tofmetry.sensor.profiles import AZURE_KINECT, KINECT_V2, PROFILES, SensorProfile, get_profile, register_profile

__all__ = ["CameraIntrinsics", "LENS_MODELS", "Extrinsics", "SensorProfile", "KINECT_V2", "AZURE_KINECT", "PROFILES", "get_profile", "register_profile"]
