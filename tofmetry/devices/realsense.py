"""Intel RealSense depth cameras through ``pyrealsense2`` (``pip install tofmetry[realsense]``).

Three sources, one class: a live camera (``rs.pipeline``), a ``.bag`` recording played back by the
library (not in real time: every frame is delivered), or any frame queue of the library such as an
``rs.syncer`` fed by an ``rs.software_device`` (synthetic frames through the real library, which
is how the tests drive it without hardware). Depth is converted from the device's depth units to
millimetres; the ASIC and projector temperatures are reported where the sensor supports them.
"""

from __future__ import annotations

import os

import numpy as np

from tofmetry.devices.base import Device, DeviceError, DeviceFrame, DeviceInfo, require
from tofmetry.sensor.intrinsics import CameraIntrinsics

EXTRA = "realsense"


def _rs():
    return require("pyrealsense2", EXTRA, "RealSense")


def intrinsics_from_rs(ri, rs) -> CameraIntrinsics:
    """A :class:`CameraIntrinsics` from an ``rs.intrinsics`` (Brown models keep their 5 coefficients;
    other models are kept as a plain pinhole and said so by the caller)."""
    dist = (0.0,) * 5
    if ri.model in (rs.distortion.brown_conrady, rs.distortion.modified_brown_conrady,
                    rs.distortion.inverse_brown_conrady):
        c = list(ri.coeffs)[:5]
        dist = tuple(float(x) for x in c)
    return CameraIntrinsics(int(ri.width), int(ri.height), float(ri.fx), float(ri.fy), float(ri.ppx), float(ri.ppy), dist)


class RealSenseDevice(Device):
    """A RealSense camera, a ``.bag`` playback, or a library frame queue.

    Parameters
    ----------
    bag : path of a ``.bag`` recording to play back (None: a live camera, or ``queue``)
    width, height, fps : depth stream of a live camera
    serial : serial number of the live camera to open (None: the first one)
    queue : an object with ``wait_for_frames(timeout_ms)`` (e.g. an ``rs.syncer`` started on a
        ``software_device`` sensor); ``sensor`` is then that sensor (for depth units and temperatures)
    timeout_s : how long to wait for a frame [s]
    """

    name = "realsense"

    def __init__(self, bag: str | os.PathLike | None = None, *, width: int = 640, height: int = 480, fps: int = 30,
                 serial: str | None = None, queue=None, sensor=None, timeout_s: float = 5.0):
        super().__init__()
        self.bag = None if bag is None else str(bag)
        self.width, self.height, self.fps, self.serial = width, height, fps, serial
        self._queue, self._sensor, self.timeout_s = queue, sensor, timeout_s
        self._pipe = None
        self._scale_mm = 1.0
        self._rsm = None

    def _open(self) -> DeviceInfo:
        rs = self._rsm = _rs()
        serial = self.serial or ""
        if self._queue is None:
            if self.bag is not None and not os.path.isfile(self.bag):
                raise DeviceError(f"RealSense playback: file not found: {self.bag}")
            self._pipe = rs.pipeline()
            cfg = rs.config()
            if self.bag is not None:
                cfg.enable_device_from_file(self.bag, repeat_playback=False)
            else:
                if self.serial:
                    cfg.enable_device(self.serial)
                cfg.enable_stream(rs.stream.depth, self.width, self.height, rs.format.z16, self.fps)
            try:
                prof = self._pipe.start(cfg)
            except RuntimeError as exc:
                raise DeviceError(f"RealSense: could not start {'playback of ' + self.bag if self.bag else 'the camera'}: {exc}") from None
            dev = prof.get_device()
            if self.bag is not None:
                dev.as_playback().set_real_time(False)
            self._sensor = dev.first_depth_sensor()
            try:
                serial = dev.get_info(rs.camera_info.serial_number)
            except RuntimeError:
                serial = self.bag or ""
            vprof = prof.get_stream(rs.stream.depth).as_video_stream_profile()
            intr, fps = intrinsics_from_rs(vprof.get_intrinsics(), rs), float(vprof.fps())
        else:
            intr, fps = None, float(self.fps)
            for sp in (self._sensor.get_stream_profiles() if self._sensor is not None else []):
                if sp.stream_type() == rs.stream.depth and sp.is_video_stream_profile():
                    vp = sp.as_video_stream_profile()
                    intr, fps = intrinsics_from_rs(vp.get_intrinsics(), rs), float(vp.fps())
                    break
        units = self._option("depth_units")
        self._scale_mm = 1.0 if units is None else float(units) * 1000.0
        return DeviceInfo(name="realsense", sensor="realsense", serial=serial or "RealSense frame queue",
                          depth_intrinsics=intr, depth_unit_mm=1.0, fps=fps)

    def _option(self, name: str):
        rs = self._rsm
        opt = getattr(rs.option, name, None)
        if self._sensor is None or opt is None:
            return None
        try:
            return float(self._sensor.get_option(opt)) if self._sensor.supports(opt) else None
        except RuntimeError:
            return None

    def _read(self) -> DeviceFrame | None:
        rs = self._rsm
        ms = int(self.timeout_s * 1000)
        if self._pipe is not None:
            ok, fs = self._pipe.try_wait_for_frames(ms)
            if not ok:
                if self.bag is not None:
                    return None           # end of the recording
                raise DeviceError(f"RealSense: no frame within {self.timeout_s:g} s")
        else:
            try:
                fs = self._queue.wait_for_frames(ms)
            except RuntimeError:
                return None
        df = fs.get_depth_frame()
        if not df:
            return None
        raw = np.asanyarray(df.get_data())
        if abs(self._scale_mm - 1.0) < 1e-6:
            depth = raw.astype(np.uint16, copy=True)
        else:
            depth = np.clip(np.rint(raw * self._scale_mm), 0, 65535).astype(np.uint16)
        if self._info is not None and self._info.depth_intrinsics is None:
            self._info.depth_intrinsics = intrinsics_from_rs(df.profile.as_video_stream_profile().get_intrinsics(), rs)
        temps = {k: v for k in ("asic_temperature", "projector_temperature") if (v := self._option(k)) is not None}
        return DeviceFrame(depth=depth, timestamp_s=df.get_timestamp() / 1000.0, temperature_c=temps)

    def _close(self) -> None:
        if self._pipe is not None:
            try:
                self._pipe.stop()
            except RuntimeError:
                pass
            self._pipe = None
