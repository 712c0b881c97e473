"""Microsoft Azure Kinect through ``pyk4a`` (``pip install tofmetry[azure]``, which installs
``pyk4a-bundle``: the Python binding with the Azure Kinect SDK inside).

A live device or an ``.mkv`` recording played back by the SDK. Depth is delivered in mm as the
SDK gives it; the factory calibration gives the depth and colour intrinsics in the SDK's own
8-coefficient rational lens model (``CameraIntrinsics(model="rational")``, as tofmetry's MKV importer
keeps it) and the depth->colour extrinsics. pyk4a's captures carry no temperature: a live device
reports the temperature of its IMU (``"imu"``, read at each frame); a playback reports none.

``pyk4a-bundle`` is built against numpy 1.x: in an environment with numpy 2 it cannot be imported,
and :class:`~tofmetry.devices.base.MissingExtraError` says so. This module imports nothing else
that needs numpy 2 or OpenCV, so it runs in a separate ``numpy<2`` environment
(``tests/devices/test_pyk4a_playback.py`` plays the shared MKV back through it there and compares
the frames bit for bit with the importer).
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


def _intrinsics(calib, kind, size) -> CameraIntrinsics:
    """A camera of a pyk4a ``Calibration`` in the mode's pixels: (W, H), K and OpenCV's rational
    coefficients ``k1,k2,p1,p2,k3,k4,k5,k6`` as the SDK gives them."""
    K = np.asarray(calib.get_camera_matrix(kind), np.float64)
    dist = np.asarray(calib.get_distortion_coefficients(kind), np.float64).ravel()
    model = "rational" if dist.size == 8 else "brown"
    return CameraIntrinsics(int(size[0]), int(size[1]), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                            tuple(float(x) for x in dist), model)


class AzureKinectDevice(Device):
    """An Azure Kinect (``device_id``) or an ``.mkv`` playback (``mkv``) through pyk4a.

    Parameters
    ----------
    mkv : recording to play back (None: the live device)
    device_id : index of the live device
    """

    name = "azure"

    def __init__(self, mkv: str | os.PathLike | None = None, *, device_id: int = 0):
        super().__init__()
        self.mkv = None if mkv is None else str(mkv)
        self.device_id = device_id
        self._src = None

    def _open(self) -> DeviceInfo:
        k4a = _k4a()
        if self.mkv is not None:
            if not os.path.isfile(self.mkv):
                raise DeviceError(f"Azure Kinect playback: file not found: {self.mkv}")
            self._src = k4a.PyK4APlayback(self.mkv)
            try:
                self._src.open()
            except k4a.K4AException as exc:
                raise DeviceError(f"Azure Kinect playback: cannot open {self.mkv} ({exc})") from None
            serial = f"playback of {self.mkv}"
            fps = _FPS.get(int(self._src.configuration["camera_fps"]), 30.0)
        else:
            config = k4a.Config()                 # NFOV unbinned depth, 720p colour, 30 fps, IMU on
            self._src = k4a.PyK4A(config=config, device_id=self.device_id)
            try:
                self._src.start()
            except k4a.K4AException as exc:
                raise DeviceError(f"Azure Kinect: cannot start device {self.device_id} ({exc})") from None
            try:
                serial = str(self._src.serial)
            except k4a.K4AException:
                serial = f"device {self.device_id}"
            fps = _FPS.get(int(config.camera_fps), 30.0)
        calib = self._src.calibration
        CT = k4a.CalibrationType
        depth_size = _mode_size(calib, "depth")
        depth = _intrinsics(calib, CT.DEPTH, depth_size) if depth_size else None
        color_size = _mode_size(calib, "color")
        color = _intrinsics(calib, CT.COLOR, color_size) if color_size else None
        ext = None
        if color_size:
            # pyk4a >= 1.3 gives the translation in metres (the SDK's mm divided by 1000)
            R, t = calib.get_extrinsic_parameters(CT.DEPTH, CT.COLOR)
            ext = Extrinsics(np.asarray(R, np.float64).reshape(3, 3), np.asarray(t, np.float64).ravel(), "depth", "color")
        return DeviceInfo(name="azure", sensor="azure_kinect", serial=serial, depth_intrinsics=depth,
                          color_intrinsics=color, depth_to_color=ext, depth_unit_mm=1.0, fps=fps)

    @property
    def _k4a(self):
        return _k4a()

    def _read(self) -> DeviceFrame | None:
        while True:
            try:
                cap = self._src.get_next_capture() if self.mkv is not None else self._src.get_capture()
            except EOFError:
                return None
            if cap.depth is not None:
                break
        temps = {}
        if self.mkv is None:                      # the IMU's temperature, the only one pyk4a exposes
            try:
                sample = self._src.get_imu_sample(timeout=0)
                temp = None if sample is None else float(sample["temperature"])
            except (self._k4a.K4AException, KeyError, TypeError, ValueError):
                temp = None
            if temp is not None and np.isfinite(temp):
                temps = {"imu": temp}
        ir = None if cap.ir is None else np.clip(cap.ir, 0, 65535).astype(np.uint16)
        return DeviceFrame(depth=np.asarray(cap.depth, np.uint16), timestamp_s=cap.depth_timestamp_usec / 1e6,
                           ir=ir, temperature_c=temps)

    def _close(self) -> None:
        if self._src is not None:
            (self._src.close if self.mkv is not None else self._src.stop)()
            self._src = None


#: pyk4a ``FPS`` enum value -> frames per second (``k4a_fps_t``)
_FPS = {0: 5.0, 1: 15.0, 2: 30.0}


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
