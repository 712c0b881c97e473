"""Kinect v2 through libfreenect2's Python binding ``pylibfreenect2`` (``pip install tofmetry[kinect2]``;
the libfreenect2 C++ library must be installed on the system).

Follows the binding's example: ``Freenect2().openDevice(serial, pipeline)``, a
``SyncMultiFrameListener`` for depth and IR, ``waitForNewFrame()``; depth and IR arrive as float32
millimetres / amplitudes (512 x 424) and are delivered as uint16. The IR camera's parameters from
the device are its intrinsics (libfreenect2 gives a pinhole and k1..k3). Tested against a fake of
this API (no device or library in CI).
"""

from __future__ import annotations

import numpy as np

from tofmetry.devices.base import Device, DeviceError, DeviceFrame, DeviceInfo, require
from tofmetry.sensor.intrinsics import CameraIntrinsics

EXTRA = "kinect2"


class Kinect2Device(Device):
    """The first (or the ``serial``) Kinect v2 through libfreenect2.

    Parameters
    ----------
    serial : device serial number (None: the first device)
    """

    name = "kinect2"

    def __init__(self, serial: str | None = None):
        super().__init__()
        self.serial = serial
        self._dev = self._listener = self._frames = None
        self._fn = None

    def _open(self) -> DeviceInfo:
        fn = self._fn = require("pylibfreenect2", EXTRA, "Kinect v2")
        ctx = fn.Freenect2()
        if ctx.enumerateDevices() == 0:
            raise DeviceError("Kinect v2: no device connected (libfreenect2 found none)")
        serial = self.serial or ctx.getDeviceSerialNumber(0)
        self._dev = ctx.openDevice(serial)
        types = fn.FrameType.Ir | fn.FrameType.Depth
        self._listener = fn.SyncMultiFrameListener(types)
        self._dev.setIrAndDepthFrameListener(self._listener)
        self._dev.startStreams(rgb=False, depth=True)
        p = self._dev.getIrCameraParams()
        intr = CameraIntrinsics(512, 424, float(p.fx), float(p.fy), float(p.cx), float(p.cy),
                                (float(p.k1), float(p.k2), float(p.p1), float(p.p2), float(p.k3)))
        s = serial.decode() if isinstance(serial, bytes) else str(serial)
        return DeviceInfo(name="kinect2", sensor="kinect_v2", serial=s, depth_intrinsics=intr, fps=30.0)

    def _read(self) -> DeviceFrame | None:
        fn = self._fn
        frames = self._listener.waitForNewFrame()
        try:
            d = frames[fn.FrameType.Depth]
            ir = frames[fn.FrameType.Ir]
            depth = np.clip(np.rint(d.asarray(np.float32)), 0, 65535).astype(np.uint16).reshape(424, 512)
            amp = np.clip(np.rint(ir.asarray(np.float32)), 0, 65535).astype(np.uint16).reshape(424, 512)
            t = float(d.timestamp) * 1e-4    # libfreenect2: units of 0.1 ms
        finally:
            self._listener.release(frames)
        return DeviceFrame(depth=depth, timestamp_s=t, ir=amp)

    def _close(self) -> None:
        if self._dev is not None:
            self._dev.stop()
            self._dev.close()
            self._dev = None
