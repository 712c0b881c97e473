"""Depth cameras behind one interface (:class:`Device`): the virtual Kinect v2 and real devices.

========== ===================================== ==================== =====================
name       class                                 extra                package
========== ===================================== ==================== =====================
virtual    :class:`~.virtual.VirtualDevice`      (none)               the simulator
realsense  :class:`~.realsense.RealSenseDevice`  ``tofmetry[realsense]`` ``pyrealsense2``
azure      :class:`~.azure.AzureKinectDevice`    ``tofmetry[azure]``  ``pyk4a-bundle`` (numpy<2)
orbbec     :class:`~.orbbec.OrbbecDevice`        ``tofmetry[orbbec]`` ``pyorbbecsdk``
kinect2    :class:`~.kinect2.Kinect2Device`      ``tofmetry[kinect2]`` ``pylibfreenect2`` + libfreenect2
========== ===================================== ==================== =====================

Importing this package loads none of them; :func:`open_device` imports the one asked for, and a
missing package fails with :class:`MissingExtraError` naming the extra.
"""

from __future__ import annotations

import importlib

from tofmetry.devices.base import Device, DeviceError, DeviceFrame, DeviceInfo, MissingExtraError, require

#: device name -> (module, class)
DEVICES = {
    "virtual": ("tofmetry.devices.virtual", "VirtualDevice"),
    "realsense": ("tofmetry.devices.realsense", "RealSenseDevice"),
    "azure": ("tofmetry.devices.azure", "AzureKinectDevice"),
    "orbbec": ("tofmetry.devices.orbbec", "OrbbecDevice"),
    "kinect2": ("tofmetry.devices.kinect2", "Kinect2Device"),
}


def make_device(name: str, **kwargs) -> Device:
    """A device by name (not yet open); ``kwargs`` go to its class.

    Raises
    ------
    DeviceError : unknown name (the known ones are listed)
    """
    if name not in DEVICES:
        raise DeviceError(f"--device: unknown device {name!r}; expected one of {', '.join(DEVICES)}")
    mod, cls = DEVICES[name]
    return getattr(importlib.import_module(mod), cls)(**kwargs)


__all__ = ["DEVICES", "Device", "DeviceError", "DeviceFrame", "DeviceInfo", "MissingExtraError", "make_device",
           "require"]
