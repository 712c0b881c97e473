"""The virtual Kinect v2 as a :class:`~tofmetry.devices.base.Device` that streams in real time.

The scene and the camera pose can be changed while streaming (:meth:`VirtualDevice.set_view`):
that is how a test, or a demo, plays the operator who moves the camera or the board. The device
clock starts at power-on (``t0_s``; 0 = a cold sensor, so the warm-up drift of the simulator
shows), advances by ``1 / fps`` per frame, and with ``realtime=True`` frames are paced on the wall
clock. A temperature is reported from the simulator's thermal state.
"""

from __future__ import annotations

import math
import time

import numpy as np

from tofmetry.devices.base import Device, DeviceError, DeviceFrame, DeviceInfo
from tofmetry.sensor.profiles import KINECT_V2
from tofmetry.simulate import ErrorModel, VirtualKinect, scenes
from tofmetry.simulate.surfaces import Scene


def thermal_state(t_s: float | np.ndarray, em: ErrorModel) -> np.ndarray:
    """Heating state of the virtual sensor in [0, 1] at ``t_s`` seconds after power-on.

    The state that drives the simulator's warm-up drift (:func:`tofmetry.simulate.errors.warmup_mm`):
    it heats as ``1 - exp(-t / tau)`` until the fan starts (``warmup_fan_s``), then relaxes toward
    ``warmup_fan_level``.
    """
    t = np.maximum(np.asarray(t_s, np.float64), 0.0)
    heat = 1.0 - np.exp(-t / em.warmup_tau_s)
    s_fan = 1.0 - math.exp(-em.warmup_fan_s / em.warmup_tau_s)
    after = em.warmup_fan_level + (s_fan - em.warmup_fan_level) * np.exp(
        -np.maximum(t - em.warmup_fan_s, 0.0) / em.warmup_fan_tau_s)
    return np.where(t < em.warmup_fan_s, heat, after)


def virtual_temperature_c(t_s: float | np.ndarray, em: ErrorModel, ambient_c: float = 24.0,
                          rise_c: float = 16.0) -> np.ndarray:
    """Temperature [°C] the virtual sensor reports: ``ambient + rise * state`` (see :func:`thermal_state`)."""
    return ambient_c + rise_c * thermal_state(t_s, em)


class VirtualDevice(Device):
    """The virtual Kinect v2 streaming frames of a scene seen from a pose.

    Parameters
    ----------
    scene : Scene (world frame, metres); default a white wall 1.5 m in front of the camera
    pose : (4, 4) camera-to-world [m]; default identity
    errors : ErrorModel of the simulator (default: every term on)
    seed : noise seed (streams are deterministic)
    fps : frame rate [Hz]; the device clock advances by ``1 / fps`` per frame
    realtime : pace frames on the wall clock (the rate of a real sensor); False: as fast as computed
    t0_s : device time at the first frame, since power-on [s] (0: cold sensor; 3600: warm)
    supersample : sub-rays per pixel per axis when rendering a new view (1 is fast, 3 is the simulator's default)
    max_frames : end the stream after this many frames (None: endless)
    """

    name = "virtual"

    def __init__(self, scene: Scene | None = None, pose: np.ndarray | None = None, *, errors: ErrorModel | None = None,
                 seed: int = 0, fps: float = 30.0, realtime: bool = True, t0_s: float = 3600.0, supersample: int = 1,
                 max_frames: int | None = None):
        super().__init__()
        if not fps > 0:
            raise DeviceError(f"virtual device: fps must be > 0, found {fps}")
        self._vk = VirtualKinect(errors=errors, seed=seed, supersample=supersample)
        self._scene = scene if scene is not None else scenes.wall(1.5)
        self._pose = np.eye(4) if pose is None else np.asarray(pose, np.float64)
        self._rendering = None
        self.fps = float(fps)
        self.realtime = bool(realtime)
        self.t0_s = float(t0_s)
        self.max_frames = max_frames
        self.n_frames = 0
        self._wall0 = None

    @property
    def errors(self) -> ErrorModel:
        return self._vk.errors

    @property
    def pose(self) -> np.ndarray:
        """Current camera-to-world pose (4, 4) [m]."""
        return self._pose.copy()

    @property
    def scene(self) -> Scene:
        return self._scene

    @property
    def clock_s(self) -> float:
        """Device time of the next frame [s since power-on]."""
        return self.t0_s + self.n_frames / self.fps

    def set_view(self, scene: Scene | None = None, pose: np.ndarray | None = None) -> None:
        """Move the camera (``pose``) or change what it looks at (``scene``); rendered at the next frame."""
        if scene is not None:
            self._scene = scene
        if pose is not None:
            self._pose = np.asarray(pose, np.float64)
        self._rendering = None

    def idle(self, seconds: float) -> None:
        """Let device time pass without delivering frames (a sensor left running between recordings)."""
        self.n_frames += int(round(seconds * self.fps))

    def _open(self) -> DeviceInfo:
        self._wall0 = time.monotonic()
        return DeviceInfo(name="virtual", sensor="kinect_v2", serial="virtual Kinect v2 (simulated)",
                          depth_intrinsics=self._vk.intrinsics, color_intrinsics=None, depth_to_color=None,
                          depth_unit_mm=1.0, fps=self.fps)

    def _read(self) -> DeviceFrame | None:
        if self.max_frames is not None and self.n_frames >= self.max_frames:
            return None
        if self._rendering is None:
            self._rendering = self._vk.render(self._scene, self._pose)
        t = self.clock_s
        fr = next(self._vk.iter_frames(self._scene, 1, rendering=self._rendering, timestamps_s=np.array([t])))
        self.n_frames += 1
        if self.realtime:
            due = self._wall0 + (self.n_frames - 1) / self.fps
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        temp = float(virtual_temperature_c(t, self._vk.errors))
        return DeviceFrame(depth=fr.depth, timestamp_s=t, ir=fr.ir, temperature_c={"sensor": temp})


def default_intrinsics():
    """The virtual device's depth intrinsics (the typical Kinect v2)."""
    return KINECT_V2.depth
