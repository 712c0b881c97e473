"""Orbbec depth cameras (Femto, Astra ...) through ``pyorbbecsdk`` (``pip install tofmetry[orbbec]``).

Follows the SDK's Python examples: a ``Pipeline`` with a ``Config`` enabling the default depth
profile; ``wait_for_frames(timeout_ms)`` gives a frame set whose depth frame holds uint16 counts
scaled by ``get_depth_scale()`` to millimetres. The depth intrinsics come from the pipeline's
camera parameters. Tested against a fake of this API (no device or SDK in CI).
"""

from __future__ import annotations

import numpy as np

from tofmetry.devices.base import Device, DeviceError, DeviceFrame, DeviceInfo, require
from tofmetry.sensor.intrinsics import CameraIntrinsics

EXTRA = "orbbec"


class OrbbecDevice(Device):
    """The first Orbbec camera found, depth stream at its default profile.

    Parameters
    ----------
    timeout_s : how long to wait for a frame [s]
    """

    name = "orbbec"

    def __init__(self, *, timeout_s: float = 5.0):
        super().__init__()
        self.timeout_s = timeout_s
        self._pipe = None

    def _open(self) -> DeviceInfo:
        ob = require("pyorbbecsdk", EXTRA, "Orbbec")
        try:
            self._pipe = ob.Pipeline()
            cfg = ob.Config()
            profiles = self._pipe.get_stream_profile_list(ob.OBSensorType.DEPTH_SENSOR)
            prof = profiles.get_default_video_stream_profile()
            cfg.enable_stream(prof)
            self._pipe.start(cfg)
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error types
            raise DeviceError(f"Orbbec: could not start the depth stream: {exc}") from None
        intr = None
        try:
            p = self._pipe.get_camera_param().depth_intrinsic
            intr = CameraIntrinsics(int(p.width), int(p.height), float(p.fx), float(p.fy), float(p.cx), float(p.cy))
        except Exception:  # noqa: BLE001 - older SDKs have no camera parameters
            pass
        return DeviceInfo(name="orbbec", sensor="orbbec", serial="Orbbec camera", depth_intrinsics=intr,
                          fps=float(prof.get_fps()))

    def _read(self) -> DeviceFrame | None:
        fs = self._pipe.wait_for_frames(int(self.timeout_s * 1000))
        if fs is None or fs.get_depth_frame() is None:
            raise DeviceError(f"Orbbec: no depth frame within {self.timeout_s:g} s")
        df = fs.get_depth_frame()
        w, h = df.get_width(), df.get_height()
        raw = np.frombuffer(df.get_data(), dtype=np.uint16).reshape(h, w)
        scale = float(df.get_depth_scale())
        depth = raw.copy() if scale == 1.0 else np.clip(np.rint(raw * scale), 0, 65535).astype(np.uint16)
        return DeviceFrame(depth=depth, timestamp_s=df.get_timestamp() / 1000.0)

    def _close(self) -> None:
        if self._pipe is not None:
            self._pipe.stop()
            self._pipe = None
