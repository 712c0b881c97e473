"""Microsoft Azure Kinect through ``pyk4a`` (``pip install tofmetry[azure]``, which installs
``pyk4a-bundle``: the Python binding with the Azure Kinect SDK inside).

A live device or an ``.mkv`` recording played back by the SDK. Depth is delivered in mm as the
SDK gives it; the factory calibration gives the depth intrinsics (the SDK's 8-coefficient rational
model is reduced to tofmetry's 5-coefficient Brown model by least squares, as the MKV importer does)
and the depth->colour extrinsics; the capture's temperature is reported where the SDK has it.

``pyk4a-bundle`` is built against numpy 1.x: in an environment with numpy 2 it cannot be imported,
and :class:`~tofmetry.devices.base.MissingExtraError` says so.
"""

from __future__ import annotations

import os

import numpy as np

from tofmetry.devices.base import Device, DeviceError, DeviceFrame, DeviceInfo, require
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics

EXTRA = "azure"


def _k4a():
    return require("pyk4a", EXTRA, "Azure Kinect")


def _intrinsics(calib, kind, size, reduce_rational) -> CameraIntrinsics:
    K = np.asarray(calib.get_camera_matrix(kind), np.float64)
    rational = np.asarray(calib.get_distortion_coefficients(kind), np.float64).ravel()
    dist = tuple(float(x) for x in rational[[0, 1, 2, 3, 4]]) if rational.size >= 5 else (0.0,) * 5
    if reduce_rational is not None and rational.size == 8:
        dist5 = reduce_rational(K, rational, size)[0]
        dist = tuple(float(x) for x in dist5)
    return CameraIntrinsics(int(size[0]), int(size[1]), K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist)


class AzureKinectDevice(Device):
    """An Azure Kinect (``device_id``) or an ``.mkv`` playback (``mkv``) through pyk4a.

    Parameters
    ----------
    mkv : recording to play back (None: the live device)
    device_id : index of the live device
    reduce_rational : callable ``(K, rational8, (W, H)) -> (dist5, ...)`` reducing the SDK's rational
        model to Brown (default: :func:`tofmetry.io.azure_kinect.brown_from_rational`, as the importer)
    """

    name = "azure"

    def __init__(self, mkv: str | os.PathLike | None = None, *, device_id: int = 0, reduce_rational=None):
        super().__init__()
        self.mkv = None if mkv is None else str(mkv)
        self.device_id = device_id
        self._reduce = reduce_rational
        self._src = None

    def _open(self) -> DeviceInfo:
        k4a = _k4a()
        if self._reduce is None:
            from tofmetry.io.azure_kinect import brown_from_rational   # cv2: only once a device is used

            self._reduce = lambda K, r, size: brown_from_rational(K, r, size)
        if self.mkv is not None:
            if not os.path.isfile(self.mkv):
                raise DeviceError(f"Azure Kinect playback: file not found: {self.mkv}")
            self._src = k4a.PyK4APlayback(self.mkv)
            self._src.open()
            serial = f"playback of {self.mkv}"
        else:
            self._src = k4a.PyK4A(device_id=self.device_id)
            self._src.start()
            serial = str(getattr(self._src, "serial", f"device {self.device_id}"))
        calib = self._src.calibration
        CT = k4a.CalibrationType
        depth_size = _mode_size(calib, "depth")
        depth = _intrinsics(calib, CT.DEPTH, depth_size, self._reduce) if depth_size else None
        color_size = _mode_size(calib, "color")
        color = _intrinsics(calib, CT.COLOR, color_size, self._reduce) if color_size else None
        ext = None
        try:
            R, t = calib.get_extrinsic_parameters(CT.DEPTH, CT.COLOR)
            ext = Extrinsics(np.asarray(R, np.float64).reshape(3, 3), np.asarray(t, np.float64).ravel() / 1000.0,
                             "depth", "color")
        except (AttributeError, ValueError, RuntimeError):
            pass
        return DeviceInfo(name="azure", sensor="azure_kinect", serial=serial, depth_intrinsics=depth,
                          color_intrinsics=color, depth_to_color=ext, depth_unit_mm=1.0, fps=30.0)

    def _read(self) -> DeviceFrame | None:
        while True:
            try:
                cap = self._src.get_next_capture() if self.mkv is not None else self._src.get_capture()
            except EOFError:
                return None
            if cap.depth is not None:
                break
        temp = getattr(cap, "temperature", None)
        temps = {"sensor": float(temp)} if temp is not None and np.isfinite(temp) else {}
        ir = None if cap.ir is None else np.clip(cap.ir, 0, 65535).astype(np.uint16)
        return DeviceFrame(depth=np.asarray(cap.depth, np.uint16), timestamp_s=cap.depth_timestamp_usec / 1e6,
                           ir=ir, temperature_c=temps)

    def _close(self) -> None:
        if self._src is not None:
            (self._src.close if self.mkv is not None else self._src.stop)()
            self._src = None


def _mode_size(calib, which: str) -> tuple[int, int] | None:
    """(W, H) of the depth mode or colour resolution of a pyk4a calibration (None when off or unknown).

    Sizes from the Azure Kinect SDK's ``k4a_depth_mode_t`` / ``k4a_color_resolution_t`` tables."""
    if which == "depth":
        mode, table = getattr(calib, "depth_mode", None), {1: (320, 288), 2: (640, 576), 3: (512, 512),
                                                            4: (1024, 1024), 5: (1024, 1024)}
    else:
        mode, table = getattr(calib, "color_resolution", None), {1: (1280, 720), 2: (1920, 1080), 3: (2560, 1440),
                                                                  4: (2048, 1536), 5: (3840, 2160), 6: (4096, 3072)}
    return None if mode is None else table.get(int(mode))
