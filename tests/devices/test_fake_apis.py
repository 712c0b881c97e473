"""Orbbec and Kinect v2 (libfreenect2) devices against fakes of their Python APIs (no SDK, no hardware),
and the missing-extra message of every real device."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest

from tofmetry.devices import MissingExtraError, make_device
from tofmetry.devices.base import DeviceError


def _fake_orbbec(frames):
    ob = types.ModuleType("pyorbbecsdk")

    class Prof:
        def get_fps(self):
            return 30

    class Profiles:
        def get_default_video_stream_profile(self):
            return Prof()

    class DF:
        def __init__(self, a, t):
            self.a, self.t = a, t

        def get_width(self):
            return self.a.shape[1]

        def get_height(self):
            return self.a.shape[0]

        def get_data(self):
            return self.a.tobytes()

        def get_depth_scale(self):
            return 0.5            # counts of 0.5 mm

        def get_timestamp(self):
            return self.t

    class FS:
        def __init__(self, df):
            self.df = df

        def get_depth_frame(self):
            return self.df

    class Pipeline:
        def __init__(self):
            self.k = 0

        def get_stream_profile_list(self, kind):
            return Profiles()

        def start(self, cfg):
            pass

        def stop(self):
            pass

        def get_camera_param(self):
            p = types.SimpleNamespace(width=4, height=3, fx=2.0, fy=2.0, cx=1.5, cy=1.0)
            return types.SimpleNamespace(depth_intrinsic=p)

        def wait_for_frames(self, ms):
            a = frames[self.k % len(frames)]
            self.k += 1
            return FS(DF(a, 33.0 * self.k))

    ob.Pipeline, ob.Config = Pipeline, lambda: types.SimpleNamespace(enable_stream=lambda p: None)
    ob.OBSensorType = types.SimpleNamespace(DEPTH_SENSOR=1)
    return ob


def test_orbbec_against_a_fake_api(monkeypatch):
    raw = np.array([[2000, 0, 4001, 10]] * 3, np.uint16)
    monkeypatch.setitem(sys.modules, "pyorbbecsdk", _fake_orbbec([raw]))
    with make_device("orbbec") as dev:
        assert dev.info.depth_intrinsics.shape == (3, 4) and dev.info.fps == 30
        f = dev.read()
    np.testing.assert_array_equal(f.depth[0], [1000, 0, 2000, 5])    # 0.5 mm counts -> mm (4001/2 rounds to even)
    assert f.timestamp_s == pytest.approx(0.033)


def _fake_freenect2():
    fn = types.ModuleType("pylibfreenect2")
    fn.FrameType = types.SimpleNamespace(Ir=2, Depth=4)

    class Frame:
        def __init__(self, val, ts):
            self.val, self.timestamp = val, ts

        def asarray(self, dtype):
            return np.full((424, 512), self.val, dtype)

    class Listener:
        def __init__(self, types_):
            self.released = 0

        def waitForNewFrame(self):
            return {4: Frame(1500.4, 12345), 2: Frame(800.0, 12345)}

        def release(self, frames):
            self.released += 1

    class Dev:
        def setIrAndDepthFrameListener(self, lst):
            pass

        def startStreams(self, rgb, depth):
            pass

        def getIrCameraParams(self):
            return types.SimpleNamespace(fx=365.0, fy=365.0, cx=256.0, cy=212.0, k1=0.09, k2=-0.27, p1=0.0, p2=0.0,
                                         k3=0.09)

        def stop(self):
            pass

        def close(self):
            pass

    class Ctx:
        def enumerateDevices(self):
            return 1

        def getDeviceSerialNumber(self, i):
            return b"000123"

        def openDevice(self, serial):
            return Dev()

    fn.Freenect2, fn.SyncMultiFrameListener = Ctx, Listener
    return fn


def test_kinect2_against_a_fake_api(monkeypatch):
    monkeypatch.setitem(sys.modules, "pylibfreenect2", _fake_freenect2())
    with make_device("kinect2") as dev:
        assert dev.info.serial == "000123" and dev.info.depth_intrinsics.distortion[1] == -0.27
        f = dev.read()
    assert f.depth.dtype == np.uint16 and f.depth[0, 0] == 1500 and f.ir[0, 0] == 800
    assert f.timestamp_s == pytest.approx(1.2345)


@pytest.mark.parametrize("name,module,extra", [("azure", "pyk4a", "azure"), ("orbbec", "pyorbbecsdk", "orbbec"),
                                               ("kinect2", "pylibfreenect2", "kinect2"),
                                               ("realsense", "pyrealsense2", "realsense")])
def test_missing_extra_names_it(monkeypatch, name, module, extra):
    monkeypatch.setitem(sys.modules, module, None)          # import fails as if not installed
    with pytest.raises(MissingExtraError, match=rf"pip install tofmetry\[{extra}\]"):
        make_device(name).open()


def test_unknown_device():
    with pytest.raises(DeviceError, match="unknown device 'webcam'"):
        make_device("webcam")
