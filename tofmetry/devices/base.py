"""The one interface every depth camera is driven through: :class:`Device`.

A device is opened, streams :class:`DeviceFrame` objects (depth, optional IR and colour, a
timestamp on the device's clock and the temperature where the driver reports one) and is closed.
Its :class:`DeviceInfo` carries the intrinsics and the depth->colour extrinsics the device itself
reports (factory calibration), which the recorder stores in ``capture.json``.

Each real implementation needs an optional extra (``pip install tofmetry[azure]`` ...); a missing
extra raises :class:`MissingExtraError` naming it, only when that device is asked for.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field

import numpy as np

from tofmetry.errors import TofmetryError
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics


class MissingExtraError(TofmetryError, ImportError):
    """A device's Python package is not installed: the message names the extra to install."""


class DeviceError(TofmetryError, RuntimeError):
    """A device could not be opened or stopped delivering frames: the message says which and why."""


def require(module: str, extra: str, device: str):
    """Import ``module`` for ``device`` or raise :class:`MissingExtraError` naming ``extra``.

    Parameters
    ----------
    module : the importable name (``"pyk4a"``)
    extra : the tofmetry extra that installs it (``"azure"``)
    device : the device's name, for the message
    """
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:   # also numpy-ABI failures of a compiled extension
        raise MissingExtraError(
            f"the {device} device needs the Python package {module!r}, which could not be imported ({exc}); "
            f"install it with: pip install tofmetry[{extra}]") from None


@dataclass
class DeviceFrame:
    """One frame from a device.

    Attributes
    ----------
    depth : (H, W) uint16, depth Z [mm], 0 = no measurement
    timestamp_s : float, device clock [s] (increasing within a stream)
    ir : (H, W) uint16 amplitude, or None
    color : (Hc, Wc, 3) uint8 RGB, or None
    temperature_c : dict name -> temperature [°C] the driver reports for this frame (empty if none)
    """

    depth: np.ndarray
    timestamp_s: float
    ir: np.ndarray | None = None
    color: np.ndarray | None = None
    temperature_c: dict = field(default_factory=dict)


@dataclass
class DeviceInfo:
    """What a device says about itself once open.

    Attributes
    ----------
    name : implementation name (``"virtual"``, ``"azure"`` ...)
    sensor : sensor profile key written to ``capture.json`` (``"kinect_v2"``, ``"azure_kinect"`` ...)
    serial : serial number or a description
    depth_intrinsics : intrinsics of the depth/IR camera from the device (None if it gives none)
    color_intrinsics : intrinsics of the colour camera, or None
    depth_to_color : rigid transform depth camera -> colour camera [m], or None
    depth_unit_mm : size of one depth count [mm] (frames are delivered already in mm)
    fps : nominal frame rate [Hz]
    """

    name: str
    sensor: str
    serial: str = ""
    depth_intrinsics: CameraIntrinsics | None = None
    color_intrinsics: CameraIntrinsics | None = None
    depth_to_color: Extrinsics | None = None
    depth_unit_mm: float = 1.0
    fps: float = 30.0

    def to_dict(self) -> dict:
        """The ``device`` entry of ``capture.json`` (plain JSON types)."""
        d = {"name": self.name, "sensor": self.sensor, "serial": self.serial, "fps": self.fps,
             "depth_unit_mm": self.depth_unit_mm}
        if self.color_intrinsics is not None:
            d["color_intrinsics"] = self.color_intrinsics.to_dict()
        if self.depth_to_color is not None:
            d["depth_to_color"] = {"rotation": self.depth_to_color.rotation.tolist(),
                                   "translation_m": self.depth_to_color.translation.tolist()}
        return d


class Device(abc.ABC):
    """A depth camera: ``open()``, ``read()`` frames, ``close()`` (or use it as a context manager).

    Subclasses implement :meth:`_open`, :meth:`_read` and :meth:`_close`; :attr:`info` is valid
    after :meth:`open`.
    """

    name = "device"

    def __init__(self) -> None:
        self._info: DeviceInfo | None = None
        self._open_ = False

    @property
    def info(self) -> DeviceInfo:
        if self._info is None:
            raise DeviceError(f"{self.name}: info is available once the device is open")
        return self._info

    @property
    def is_open(self) -> bool:
        return self._open_

    def open(self) -> "Device":
        """Start the device; fills :attr:`info`. Returns self."""
        if not self._open_:
            self._info = self._open()
            self._open_ = True
        return self

    def read(self) -> DeviceFrame | None:
        """The next frame (blocking), or None at the end of a playback."""
        if not self._open_:
            raise DeviceError(f"{self.name}: read() before open()")
        return self._read()

    def frames(self):
        """Iterate over frames until the stream ends (playback) or the caller stops."""
        while True:
            f = self.read()
            if f is None:
                return
            yield f

    def close(self) -> None:
        """Stop the device (idempotent)."""
        if self._open_:
            self._open_ = False
            self._close()

    def __enter__(self) -> "Device":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @abc.abstractmethod
    def _open(self) -> DeviceInfo: ...

    @abc.abstractmethod
    def _read(self) -> DeviceFrame | None: ...

    def _close(self) -> None:  # noqa: B027 - optional hook
        pass
