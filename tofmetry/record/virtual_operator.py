"""A simulated operator for the virtual device: it does what the protocols ask.

``tofmetry record ... --device virtual`` and the tests use it as the prompt callback: it moves the
virtual camera, the wall or the board to where a request asks and types the reference distance
the simulator knows. ``clumsy=True`` makes it err once per protocol (a tilted wall, a camera
pointed away from the object) so that the guidance has something to correct.
"""

from __future__ import annotations

import numpy as np

from tofmetry.devices.virtual import VirtualDevice
from tofmetry.io.board_dataset import BoardSpec
from tofmetry.record.session import Request
from tofmetry.simulate import scenes
from tofmetry.simulate.scenes import rotation_xyz


class VirtualOperator:
    """Answers the requests of a session by moving a :class:`VirtualDevice`.

    Parameters
    ----------
    device : the virtual device the session reads
    board : the chessboard of the board protocol
    clumsy : make one mistake per protocol (see the module docstring)
    """

    def __init__(self, device: VirtualDevice, board: BoardSpec | None = None, clumsy: bool = False):
        self.device, self.board, self.clumsy = device, board, clumsy
        self.requests: list[Request] = []
        self._erred = False
        self._wall_mm = None
        self._tried: dict = {}

    def _err_once(self) -> bool:
        if self.clumsy and not self._erred:
            self._erred = True
            return True
        return False

    def __call__(self, req: Request) -> str | None:
        self.requests.append(req)
        t = req.target
        if req.kind == "distance":
            return f"{self._wall_mm:.1f}"
        if "distance_mm" in t:                                   # wall: go to the station
            self._wall_mm = float(t["distance_mm"])
            tilt = (0.0, 4.0) if self._err_once() else (0.0, 0.0)
            self.device.set_view(scenes.wall(self._wall_mm / 1000.0, tilt))
        elif "check" in t:                                       # wall: square up
            self.device.set_view(scenes.wall(self._wall_mm / 1000.0, (0.0, 0.0)))
        elif "cells" in t:                                       # board: show a missing cell
            self._show_board(t)
        elif "camera_to_world" in t:                             # object: go to the view
            pose = np.asarray(t["camera_to_world"], np.float64)
            if t.get("view", 0) > 0 and "overlap" not in t and self._err_once():
                away = pose.copy()
                away[:3, :3] = pose[:3, :3] @ rotation_xyz(0.0, 60.0, 0.0)   # looks 60° to the side
                pose = away
            self.device.set_view(pose=pose)
        return None

    def _show_board(self, t: dict) -> None:
        cells = [tuple(c) for c in t["cells"]]
        if not cells:
            return
        # a cell asked for again (the board was not found there): try the next one
        k = self._tried.get(cells[0], 0)
        self._tried[cells[0]] = k + 1
        r, c, b = cells[k % len(cells)]
        rows, cols = t["grid"]
        e = t["range_edges_mm"]
        intr = self.device.info.depth_intrinsics
        u = (c + 0.5) / cols * intr.width
        v = (r + 0.5) / rows * intr.height
        z = 0.5 * (e[b] + e[b + 1]) / 1000.0
        x, y = (u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z
        bd = self.board
        s = bd.square_mm / 1000.0
        R = rotation_xyz(8.0 * (1 - 2 * (r % 2)), 10.0 * (1 - 2 * (c % 2)), 3.0)
        centre = np.array([(bd.cols - 1) * s / 2, (bd.rows - 1) * s / 2, 0.0])
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = np.array([x, y, z]) - R @ centre
        self.device.set_view(scenes.checkerboard(bd.cols, bd.rows, s, board_to_world=T))
