"""The four recording protocols: warm-up, wall, board, object.

Each is a :class:`~tofmetry.record.session.Session` that writes the capture contract frame by
frame (:class:`~tofmetry.io.live_capture.LiveCaptureWriter`) and guides the operator with the
pure functions of :mod:`tofmetry.record.guidance`:

=========  ==========================================  ==========================================
protocol   writes                                      stops when
=========  ==========================================  ==========================================
warmup     ``OUT/`` one capture (timestamps, temps)    the drift has settled (:func:`warmup_status`)
wall       ``OUT/stations.csv`` + ``OUT/NN/`` captures every station is recorded
board      ``OUT/board.json`` + ``OUT/poses/NNNN/``     every image region x range bin is covered
object     ``OUT/views/NN/`` captures                   the views are recorded (or the predicted
                                                       completeness reaches its target)
=========  ==========================================  ==========================================
"""

from __future__ import annotations

import numpy as np

from tofmetry.assess import select_patch
from tofmetry.calibrate import detect_corners
from tofmetry.devices.base import DeviceFrame
from tofmetry.errors import InputError
from tofmetry.io import atomic_write_bytes, atomic_write_json, write_intrinsics
from tofmetry.io.board_dataset import BoardSpec, write_corners
from tofmetry.io.live_capture import LiveCaptureWriter
from tofmetry.plan import predict, proxy_from_size, ring
from tofmetry.record import guidance as G
from tofmetry.record.session import Request, Session, Status


class WarmupSession(Session):
    """Record a static wall from power-on, one frame every ``interval_s``, until the drift settles.

    Parameters
    ----------
    out : the capture folder to write
    interval_s : device time between kept frames [s] (study: 15 s)
    tolerance_mm, confirm_s : stability rule (:func:`~tofmetry.record.guidance.warmup_status`)
    max_duration_s : stop anyway after this long [s] (noted as not stable)
    patch : side of the followed patch [px] (the brightest patch of the first frame)
    """

    protocol = "warmup"

    def __init__(self, out, *, interval_s: float = 15.0, tolerance_mm: float = 1.0, confirm_s: float = 600.0,
                 max_duration_s: float = 7200.0, patch: int = 10):
        super().__init__(out)
        if not interval_s > 0 or not max_duration_s > 0:
            raise InputError(f"--interval-s and --max-minutes must be positive, found {interval_s}, {max_duration_s}")
        self.interval_s, self.tolerance_mm, self.confirm_s = interval_s, tolerance_mm, confirm_s
        self.max_duration_s, self.patch_size = max_duration_s, patch
        self.writer = None
        self.t, self.d, self.temps = [], [], []
        self.patch = None
        self.status = None

    def feed(self, frame: DeviceFrame) -> Status:
        if self.writer is None:
            self.writer = LiveCaptureWriter(self.out, self.capture_meta(interval_s=self.interval_s))
        if self.t and frame.timestamp_s - self.t[-1] < self.interval_s - 1e-6:
            return Status(self.protocol, self.status.message if self.status else "waiting", recorded=len(self.t))
        if self.patch is None:
            self.patch = select_patch(frame.depth, frame.ir, self.patch_size)[0]
        self.writer.add(frame.depth, frame.timestamp_s, ir=frame.ir, temperature_c=frame.temperature_c)
        self.t.append(frame.timestamp_s)
        self.d.append(G.patch_distance_mm(frame.depth, self.patch))
        self.temps.append(next(iter(frame.temperature_c.values()), float("nan")))
        st = self.status = G.warmup_status(np.array(self.t), np.array(self.d), self.tolerance_mm, self.confirm_s)
        over = st.elapsed_s >= self.max_duration_s
        self.done = st.stable or over
        if over and not st.stable:
            self.notes.append(f"stopped after {self.max_duration_s / 60:.0f} min without settling")
        temp = self.temps[-1]
        lines = [f"frames kept: {len(self.t)} (one every {self.interval_s:g} s)",
                 f"elapsed: {st.elapsed_s / 60:.1f} min", f"patch distance: {self.d[-1]:.1f} mm",
                 f"drift since start: {st.drift_mm:+.2f} mm",
                 f"last {self.confirm_s / 60:.0f} min peak-to-peak: {st.window_range_mm:.2f} mm"]
        if np.isfinite(temp):
            lines.append(f"temperature: {temp:.1f} °C")
        return Status(self.protocol, st.message, lines, self.done, recorded=len(self.t))

    def finish(self) -> dict:
        if self.writer is not None:
            self.writer.close()
        st = self.status
        self.summary = {"protocol": "warmup", "capture": str(self.out), "frames": len(self.t),
                        "stable": bool(st and st.stable), "elapsed_s": st.elapsed_s if st else 0.0,
                        "drift_mm": st.drift_mm if st else None, "notes": self.notes}
        return self.summary


class WallSession(Session):
    """Guide from wall station to station; record each once the wall fills the view squarely.

    Parameters
    ----------
    out : the wall dataset folder (``stations.csv`` + one capture per station)
    stations_mm : the planned distances [mm] (guidance; the reference distance is asked for)
    frames : frames per station (study: 50)
    max_tilt_deg, min_fill : checks of :func:`~tofmetry.record.guidance.wall_check`
    steady : consecutive good frames before a station is accepted
    patience : consecutive failed frames before the operator is asked to fix the set-up
    """

    protocol = "wall"

    def __init__(self, out, stations_mm, *, frames: int = 50, max_tilt_deg: float = 1.0, min_fill: float = 0.9,
                 steady: int = 3, patience: int = 10):
        super().__init__(out)
        self.stations_mm = [float(s) for s in stations_mm]
        if not self.stations_mm or min(self.stations_mm) <= 0:
            raise InputError(f"--stations-mm: need at least one positive distance, found {stations_mm}")
        if frames < 1:
            raise InputError(f"--frames must be >= 1, found {frames}")
        self.frames, self.max_tilt_deg, self.min_fill = frames, max_tilt_deg, min_fill
        self.steady, self.patience = steady, patience
        self.k = 0
        self.state = "ask-move"
        self.good = self.bad = 0
        self.reference_mm = None
        self.writer = None
        self.rows: list[tuple[str, float]] = []
        self.checks: list[dict] = []

    def start(self, info):
        super().start(info)
        if info.depth_intrinsics is None:
            raise InputError(f"device {info.name}: no depth intrinsics, needed to check the wall")
        self.out.mkdir(parents=True, exist_ok=True)
        return None

    def _move_request(self) -> Request:
        d = self.stations_mm[self.k]
        return Request("move", f"station {self.k + 1} of {len(self.stations_mm)}: place the camera about "
                       f"{d / 1000:.2f} m from the wall, square to it", {"station": self.k, "distance_mm": d})

    def feed(self, frame: DeviceFrame) -> Status:
        name = f"{self.k + 1:02d}"
        if self.state == "ask-move":
            self.state = "position"
            return Status(self.protocol, "move to the next station", request=self._move_request())
        if self.state == "position":
            chk = G.wall_check(frame.depth, self.info.depth_intrinsics, max_tilt_deg=self.max_tilt_deg,
                               min_fill=self.min_fill)
            lines = [f"station {self.k + 1}/{len(self.stations_mm)} (planned {self.stations_mm[self.k] / 1000:.2f} m)",
                     f"wall fills {100 * chk.fill:.0f} % of the view", f"yaw {chk.yaw_deg:+.2f}°, pitch {chk.pitch_deg:+.2f}°",
                     f"distance on the optical axis {chk.distance_mm:.0f} mm"]
            if chk.ok:
                self.good, self.bad = self.good + 1, 0
                if self.good >= self.steady:
                    self.checks.append({"station": name, "fill": chk.fill, "yaw_deg": chk.yaw_deg,
                                        "pitch_deg": chk.pitch_deg, "measured_mm": chk.distance_mm})
                    self.state = "ask-distance"
                    return Status(self.protocol, "wall square and filling the view", lines, request=Request(
                        "distance", f"reference distance sensor → wall for station {self.k + 1} [mm]",
                        {"station": self.k, "measured_mm": chk.distance_mm}))
                return Status(self.protocol, "checking the wall …", lines)
            self.good, self.bad = 0, self.bad + 1
            req = None
            if self.bad >= self.patience:
                self.bad = 0
                req = Request("move", "; ".join(chk.messages), {"station": self.k, "check": chk.__dict__})
            return Status(self.protocol, "; ".join(chk.messages), lines, request=req)
        # recording
        if self.writer is None:
            self.writer = LiveCaptureWriter(self.out / name, self.capture_meta(reference_distance_mm=self.reference_mm))
        self.writer.add(frame.depth, frame.timestamp_s, ir=frame.ir, temperature_c=frame.temperature_c)
        n = self.writer.n
        if n >= self.frames:
            self.writer.close()
            self.writer = None
            self.rows.append((name, self.reference_mm))
            text = "capture,distance_mm\n" + "".join(f"{c},{d:g}\n" for c, d in self.rows)
            atomic_write_bytes(self.out / "stations.csv", text.encode())
            self.k += 1
            self.state = "ask-move"
            self.done = self.k >= len(self.stations_mm)
        return Status(self.protocol, f"recording station {self.k + (0 if n < self.frames else 0)}: {n}/{self.frames}",
                      [f"station {name}: {n}/{self.frames} frames"], self.done, recorded=len(self.rows))

    def answer(self, request: Request, text: str | None) -> None:
        if request.kind != "distance":
            return
        try:
            v = float(text)
        except (TypeError, ValueError):
            raise InputError(f"reference distance for station {self.k + 1}: expected a number in mm, found {text!r}") from None
        if not v > 0:
            raise InputError(f"reference distance for station {self.k + 1}: must be > 0 mm, found {v}")
        self.reference_mm = v
        self.state = "record"

    def finish(self) -> dict:
        if self.writer is not None:
            self.writer.close()
            self.notes.append(f"station {self.k + 1} was cut short: not listed in stations.csv")
        self.summary = {"protocol": "wall", "dataset": str(self.out), "stations": [
            {"capture": c, "distance_mm": d} for c, d in self.rows], "checks": self.checks, "notes": self.notes}
        return self.summary


class BoardSession(Session):
    """Record board poses until every image region x range bin is covered (the support map, live).

    Parameters
    ----------
    out : the board dataset folder (``board.json``, ``intrinsics.json``, ``poses/NNNN/``)
    board : the chessboard (inner corners, square size)
    grid : (rows, cols) of image regions
    range_edges_mm : edges of the range bins [mm]
    frames : frames per pose
    min_pixels : board pixels that make a cell covered
    patience : frames without a new pose before the missing poses are asked for
    max_poses : stop anyway after this many poses
    """

    protocol = "board"

    def __init__(self, out, board: BoardSpec, *, grid=(3, 3), range_edges_mm=(500, 800, 1100, 1500), frames: int = 1,
                 min_pixels: int = 200, patience: int = 5, max_poses: int = 100):
        super().__init__(out)
        self.board, self.grid = board, tuple(int(g) for g in grid)
        self.edges = np.asarray(range_edges_mm, np.float64)
        self.frames, self.min_pixels, self.patience, self.max_poses = frames, min_pixels, patience, max_poses
        self.counts = None
        self.poses = 0
        self.idle = 0
        self.writer = None
        self.pending = None

    def start(self, info):
        super().start(info)
        h, w = (info.depth_intrinsics.shape if info.depth_intrinsics is not None else (424, 512))
        self.counts = np.zeros((*self.grid, len(self.edges) - 1), np.int64)
        self.out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(self.out / "board.json", {"cols": self.board.cols, "rows": self.board.rows,
                                                   "square_mm": self.board.square_mm, "sensor": info.sensor,
                                                   "source": f"tofmetry record board ({info.name})"})
        if info.depth_intrinsics is not None:
            write_intrinsics(self.out / "intrinsics.json", info.depth_intrinsics)
        return Status(self.protocol, "show the board", request=self._request())

    def missing(self):
        return G.missing_cells(self.counts, self.min_pixels)

    def _request(self) -> Request:
        miss = self.missing()
        return Request("move", "move the board to a pose still missing — "
                       + G.describe_cells(miss, self.grid, self.edges),
                       {"cells": miss, "grid": self.grid, "range_edges_mm": self.edges.tolist()})

    def _lines(self) -> list[str]:
        e = self.edges
        cov = self.counts >= self.min_pixels
        lines = [f"poses: {self.poses}; cells covered: {int(cov.sum())}/{cov.size}"]
        for b in range(cov.shape[2]):
            rows = " / ".join("".join("■" if cov[r, c, b] else "□" for c in range(cov.shape[1])) for r in range(cov.shape[0]))
            lines.append(f"{e[b] / 1000:.2f}–{e[b + 1] / 1000:.2f} m: {rows}")
        return lines

    def feed(self, frame: DeviceFrame) -> Status:
        if self.writer is not None:                       # more frames of the pose being recorded
            self.writer.add(frame.depth, frame.timestamp_s, ir=frame.ir, temperature_c=frame.temperature_c)
            if self.writer.n >= self.frames:
                self._close_pose()
            return Status(self.protocol, "recording the pose", self._lines(), self.done, recorded=self.poses)
        img = frame.ir if frame.ir is not None else None
        corners = detect_corners(img, self.board.size) if img is not None else None
        if corners is None:
            return self._idle("no board found in the IR image")
        mask = G.board_mask(corners, self.board.size, frame.depth.shape)
        cells = G.board_cells(mask, frame.depth, self.grid, self.edges)
        new = (self.counts < self.min_pixels) & (self.counts + cells >= self.min_pixels)
        if not new.any():
            return self._idle("this pose covers nothing new")
        self.counts += cells
        name = f"{self.poses:04d}"
        self.writer = LiveCaptureWriter(self.out / "poses" / name, self.capture_meta())
        self.writer.add(frame.depth, frame.timestamp_s, ir=frame.ir, temperature_c=frame.temperature_c)
        write_corners(self.out / "poses" / name / "corners.json", corners, self.board, "tofmetry record board")
        self.pending = name
        if self.writer.n >= self.frames:
            self._close_pose()
        self.idle = 0
        return Status(self.protocol, f"pose {name} recorded: {int(new.sum())} new cell(s)", self._lines(), self.done,
                      recorded=self.poses)

    def _close_pose(self) -> None:
        self.writer.close()
        self.writer = None
        self.poses += 1
        self.done = not self.missing() or self.poses >= self.max_poses

    def _idle(self, why: str) -> Status:
        self.idle += 1
        req = None
        if self.idle >= self.patience:
            self.idle = 0
            req = self._request()
        return Status(self.protocol, why, self._lines(), self.done, request=req, recorded=self.poses)

    def finish(self) -> dict:
        if self.writer is not None:
            self.writer.close()
        miss = self.missing() if self.counts is not None else []
        if miss:
            self.notes.append("not covered: " + G.describe_cells(miss, self.grid, self.edges, limit=20))
        self.summary = {"protocol": "board", "dataset": str(self.out), "poses": self.poses,
                        "cells_covered": int((self.counts >= self.min_pixels).sum()) if self.counts is not None else 0,
                        "cells": int(self.counts.size) if self.counts is not None else 0,
                        "coverage_pixels": None if self.counts is None else self.counts.tolist(), "notes": self.notes}
        return self.summary


class ObjectSession(Session):
    """Guide around an object on a ring of views; check each new view's overlap; predict completeness.

    The object stands on the ground at the origin of a z-up world; the views are planned on a ring
    (:func:`tofmetry.plan.ring`). Each new view is aligned to the previous one by ICP from the planned
    relative pose (:func:`~tofmetry.record.guidance.view_overlap`), and recorded only when enough of it
    overlaps; its pose estimate then feeds :func:`tofmetry.plan.predict` with a box of the object's size.

    Parameters
    ----------
    out : the scan dataset folder (``views/NN/``)
    size_m : (width, depth, height) of the object [m]
    n_views, distance_m, elevation_deg : the ring
    frames : frames per view
    min_overlap : share of a new view that must overlap the previous one
    patience : frames of too little overlap before the operator is asked to move
    target_completeness : stop early once the predicted completeness reaches it (None: all views)
    """

    protocol = "object"

    def __init__(self, out, size_m=(0.3, 0.3, 0.4), *, n_views: int = 8, distance_m: float = 1.0,
                 elevation_deg: float = 30.0, frames: int = 10, min_overlap: float = 0.3, patience: int = 3,
                 target_completeness: float | None = None):
        super().__init__(out)
        if n_views < 2:
            raise InputError(f"--views must be >= 2, found {n_views}")
        self.size = tuple(float(s) for s in size_m)
        self.proxy = proxy_from_size(*self.size)
        self.plan = ring(n_views, distance_m, elevation_deg, [0.0, 0.0, self.size[2] / 2])
        self.frames, self.min_overlap, self.patience = frames, min_overlap, patience
        self.target = target_completeness
        self.k = 0
        self.state = "ask-move"
        self.bad = 0
        self.writer = None
        self.prev_points = None
        self.poses: list[np.ndarray] = []
        self.overlaps: list[float] = []
        self.completeness: list[float] = []
        self._points = None

    def start(self, info):
        super().start(info)
        if info.depth_intrinsics is None:
            raise InputError(f"device {info.name}: no depth intrinsics, needed to align the views")
        (self.out / "views").mkdir(parents=True, exist_ok=True)
        return None

    def _object_points(self, depth, pose) -> np.ndarray:
        """Camera-frame points of the object: the world box around it (above the ground), from ``pose``."""
        p = G.depth_points(depth, self.info.depth_intrinsics, stride=4)
        w = p @ pose[:3, :3].T + pose[:3, 3]
        r = 0.75 * max(self.size[0], self.size[1])
        keep = (np.hypot(w[:, 0], w[:, 1]) < r) & (w[:, 2] > 0.01) & (w[:, 2] < 1.2 * self.size[2])
        return p[keep]

    def feed(self, frame: DeviceFrame) -> Status:
        planned = self.plan[self.k]
        if self.state == "ask-move":
            self.state = "position"
            pos = planned[:3, 3]
            az = float(np.degrees(np.arctan2(pos[1], pos[0])))
            return Status(self.protocol, "move to the next view", request=Request(
                "move", f"view {self.k + 1} of {len(self.plan)}: camera at azimuth {az:.0f}°, "
                f"{np.linalg.norm(pos - [0, 0, self.size[2] / 2]):.2f} m from the object, looking at it",
                {"view": self.k, "camera_to_world": planned.tolist()}))
        if self.state == "position":
            guess = planned if not self.poses else self.poses[-1] @ (np.linalg.inv(self.plan[self.k - 1]) @ planned)
            pts = self._object_points(frame.depth, guess)
            if self.k == 0:
                ov, pose, rmse = 1.0, planned, 0.0
            else:
                init = np.linalg.inv(self.poses[-1]) @ guess
                ov, T, rmse = G.view_overlap(pts, self.prev_points, init)
                pose = self.poses[-1] @ T
            lines = [f"view {self.k + 1}/{len(self.plan)}", f"object points in view: {len(pts)}",
                     f"overlap with the previous view: {100 * ov:.0f} % (need {100 * self.min_overlap:.0f} %)"]
            if self.completeness:
                lines.append(f"predicted completeness so far: {100 * self.completeness[-1]:.0f} %")
            if len(pts) < 200 or ov < self.min_overlap:
                self.bad += 1
                why = ("the object is not in view" if len(pts) < 200 else
                       f"only {100 * ov:.0f} % overlaps the previous view: move back toward it")
                req = None
                if self.bad >= self.patience:
                    self.bad = 0
                    req = Request("move", why, {"view": self.k, "camera_to_world": planned.tolist(), "overlap": ov})
                return Status(self.protocol, why, lines, request=req, recorded=len(self.poses))
            self.bad = 0
            self.poses.append(pose)
            self.overlaps.append(ov)
            self._points = pts
            self.state = "record"
            self.writer = LiveCaptureWriter(self.out / "views" / f"{self.k:02d}", self.capture_meta(
                view=self.k, camera_to_world_estimate=pose.tolist(), overlap_with_previous=ov))
        self.writer.add(frame.depth, frame.timestamp_s, ir=frame.ir, temperature_c=frame.temperature_c)
        if self.writer.n < self.frames:
            return Status(self.protocol, f"recording view {self.k + 1}: {self.writer.n}/{self.frames}",
                          recorded=len(self.poses))
        self.writer.close()
        self.writer = None
        self.prev_points = self._points
        pred = predict(self.proxy, self.poses, self.info.depth_intrinsics, n_frames=self.frames)
        self.completeness.append(pred.completeness)
        self.k += 1
        self.state = "ask-move"
        self.done = self.k >= len(self.plan) or (self.target is not None and pred.completeness >= self.target)
        return Status(self.protocol, f"view {self.k} recorded; predicted completeness {100 * pred.completeness:.0f} %",
                      [f"overlaps: {', '.join(f'{100 * o:.0f} %' for o in self.overlaps)}"], self.done,
                      recorded=len(self.poses))

    def finish(self) -> dict:
        if self.writer is not None:
            self.writer.close()
            self.notes.append(f"view {self.k + 1} was cut short")
        self.summary = {"protocol": "object", "dataset": str(self.out), "views": len(self.poses),
                        "overlaps": self.overlaps, "predicted_completeness": self.completeness,
                        "camera_to_world_estimates": [p.tolist() for p in self.poses], "notes": self.notes}
        return self.summary
