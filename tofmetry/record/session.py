"""What every recording protocol shares: the request to the operator, the status, the base class.

A session is fed frames one by one (:meth:`Session.feed`) and answers with a :class:`Status`:
what to show, and possibly a :class:`Request` for the operator (move the camera, type the
reference distance). The runner (:mod:`tofmetry.record.runner`) passes requests to a prompt
callback: the terminal's ``input()``, or a test playing the operator on the virtual device.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from tofmetry.devices.base import DeviceFrame, DeviceInfo
from tofmetry.io import CaptureMeta


@dataclass
class Request:
    """Something only the operator can do.

    Attributes
    ----------
    kind : ``"move"`` (move camera or target, then confirm) or ``"distance"`` (type a number [mm])
    text : the instruction
    target : machine-readable details (e.g. ``{"distance_mm": 1500}``, ``{"cells": [...]}``)
    """

    kind: str
    text: str
    target: dict = field(default_factory=dict)


@dataclass
class Status:
    """What a session shows after a frame."""

    protocol: str
    message: str
    lines: list[str] = field(default_factory=list)
    done: bool = False
    request: Request | None = None
    recorded: int = 0


class Session:
    """Base of the four protocols; subclasses implement :meth:`feed` and may extend the others."""

    protocol = "session"

    def __init__(self, out: str | Path):
        self.out = Path(out)
        self.info: DeviceInfo | None = None
        self.done = False
        self.notes: list[str] = []
        self.summary: dict = {}

    def start(self, info: DeviceInfo) -> Status | None:
        """Called once the device is open; may return a first status with a request."""
        self.info = info
        return None

    def feed(self, frame: DeviceFrame) -> Status:
        raise NotImplementedError

    def answer(self, request: Request, text: str | None) -> None:
        """The operator's answer to ``request`` (None: confirmed without text)."""

    def finish(self) -> dict:
        """Close every open file; returns the summary (also written as ``record.json`` by the runner)."""
        return self.summary

    def capture_meta(self, **extra) -> CaptureMeta:
        """``capture.json`` content for this device: sensor, intrinsics, device block, protocol."""
        info = self.info
        return CaptureMeta(sensor=info.sensor, depth_unit_mm=1.0, intrinsics=info.depth_intrinsics,
                           extra={"device": info.to_dict(), "protocol": self.protocol, **extra})
