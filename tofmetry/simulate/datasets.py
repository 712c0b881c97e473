"""Dataset writers: simulated contract folders plus truth files at the dataset root.

Every writer puts the data in the contract layout (``capture.json`` sensor
``"kinect_v2"``, ``depth/*.png`` ...) through :class:`tofmetry.io.CaptureWriter` and
writes ``truth.json`` (and ``truth.npz`` for arrays) *next to* the captures, never inside
them; processing must never read them. The true intrinsics go into ``truth.json``, not
into ``capture.json`` (the user is expected to calibrate).

Every writer takes an optional ``sensor`` (:class:`~tofmetry.simulate.family.SensorDraw`: lens
and error model, e.g. ``random_sensor(seed)``); ``errors``, when also given, replaces the
sensor's error model. A random sensor is another Kinect-v2-class device: its captures still
say ``"kinect_v2"``; ``truth.json`` records the whole draw under ``"sensor"``.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from tofmetry.errors import InputError
from tofmetry.io import CaptureMeta, CaptureWriter, atomic_dir, atomic_write_bytes, atomic_write_json, write_stations_csv
from tofmetry.simulate import scenes
from tofmetry.simulate.camera import VirtualKinect
from tofmetry.simulate.errors import ErrorModel
from tofmetry.simulate.family import SensorDraw, default_sensor
from tofmetry.simulate.walls import DEFAULT_DISTANCES_MM, iter_wall_stations, plan_wall_stations, resolve_tilts

Progress = Callable[[int], None] | None

__all__ = ["DEFAULT_DISTANCES_MM", "wall_capture", "wall_dataset", "checkerboard_images", "charuco_images", "scan", "warmup", "noise",
           "materials", "outdoor", "write_frames"]


def _write_npz(path: Path, **arrays) -> Path:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return atomic_write_bytes(path, buf.getvalue())


def _truth_common(vk: VirtualKinect, seed: int, sensor: SensorDraw) -> dict:
    return {"simulated": True, "seed": seed, "true_intrinsics": vk.intrinsics.to_dict(),
            "error_model": vk.errors.to_dict(), "sensor": sensor.to_dict(),
            "note": "ground truth of a simulated dataset: processing must never read this file"}


def _sensor(errors: ErrorModel | None, sensor: SensorDraw | None, quantize: bool = True) -> SensorDraw:
    """The sensor to simulate: ``sensor`` (default Kinect v2) with ``errors`` replacing its error model."""
    if sensor is not None and not isinstance(sensor, SensorDraw):
        raise InputError(f"sensor: expected a SensorDraw (tofmetry.simulate.family), found {type(sensor).__name__}")
    s = sensor if sensor is not None else default_sensor()
    if errors is not None:
        s = s.with_errors(errors)
    if quantize and not s.errors.on("quantize"):
        raise InputError("dataset writers need quantised depth (uint16 mm): enable the 'quantize' term")
    return s


def write_frames(path: Path, frames_iter, meta: CaptureMeta, force: bool = False, progress: Progress = None,
                 with_ir: bool = True, colour: tuple | None = None) -> tuple[Path, list]:
    """Stream simulated frames into a capture folder; returns (path, per-frame flying masks).

    ``colour``: ``(image (Hc, Wc, 3) uint8, ColourCamera)``: the colour frame of frame 0 and, beside
    the frames, the colour camera's calibration (``color_intrinsics.json``, ``extrinsics.json``), as
    a device's factory calibration."""
    from tofmetry.io.colour_calibration import write_colour_calibration

    flying = []
    with CaptureWriter(path, meta, force=force) as w:
        if colour is not None:
            write_colour_calibration(w.staging, colour[1].intrinsics, colour[1].ir_to_color, source="simulated colour camera")
        for fr in frames_iter:
            w.add(fr.depth, ir=fr.ir if with_ir else None, color=colour[0] if colour is not None and w.n == 0 else None)
            flying.append(fr.flying)
            if progress is not None:
                progress(1)
    return Path(path), flying


def _write_static_capture(path: Path, vk: VirtualKinect, scene, rd, n_frames: int, progress: Progress,
                          t0_s: float = 3600.0, pose: np.ndarray | None = None):
    """Frames of a static scene (rendered once as ``rd``), one per second from ``t0_s`` (warm sensor).
    Returns what :func:`write_frames` returns (path, per-frame flying labels)."""
    ts = t0_s + np.arange(n_frames, dtype=float)
    meta = CaptureMeta(sensor="kinect_v2", timestamps_s=ts.tolist())
    return write_frames(path, vk.iter_frames(scene, n_frames, pose, rendering=rd, timestamps_s=ts), meta,
                        progress=progress)


def wall_capture(out: str | os.PathLike, distance_mm: float = 1000.0, n_frames: int = 50,
                 errors: ErrorModel | None = None, seed: int = 0, tilt_deg: tuple = (0.0, 0.0),
                 t0_s: float = 3600.0, force: bool = False, progress: Progress = None,
                 sensor: SensorDraw | None = None) -> Path:
    """One capture of a white wall at ``distance_mm`` from the optical centre; ``truth.json`` inside
    ``out/`` next to the capture sub-folder ``out/capture``.

    Returns the dataset folder ``out``; the capture is ``out/capture``.
    """
    out = Path(out)
    sensor = _sensor(errors, sensor)
    vk = sensor.camera(seed)
    scene = scenes.wall(distance_mm / 1000.0, tilt_deg)
    rd = vk.render(scene)
    with atomic_dir(out, force=force) as tmp:
        _write_static_capture(tmp / "capture", vk, scene, rd, n_frames, progress, t0_s=t0_s)
        truth = _truth_common(vk, seed, sensor) | {"dataset": "wall", "scene": scene.info,
                                           "optical_centre_distance_mm": float(distance_mm)}
        atomic_write_json(tmp / "truth.json", truth)
        _write_npz(tmp / "truth.npz", true_depth_mm=rd.true_depth)
    return out


def wall_dataset(out: str | os.PathLike, distances_mm: Sequence[float] = DEFAULT_DISTANCES_MM, n_frames: int = 50,
                 errors: ErrorModel | None = None, seed: int = 0, tilt_deg: tuple = (0.0, 0.0),
                 force: bool = False, progress: Progress = None, sensor: SensorDraw | None = None,
                 tilt_jitter_deg: float = 0.0, tilts_deg=None) -> Path:
    """Wall dataset for depth calibration (paper §4.2.1).

    ``stations.csv`` gives, per station, the distance from the tripod *reference point* to
    the wall, as a tachymeter would; the optical centre is ``mounting_offset_mm`` (20 mm for
    the default sensor) closer to the wall, so the true optical-centre distance = csv distance
    - offset (recorded in ``truth.json`` ``stations[*].optical_centre_mm``). Frames are 1 s
    apart, sensor warm (t >= 3600 s). The wall is tilted by ``tilt_deg`` plus, per station, a
    random tilt of up to ``tilt_jitter_deg`` (:func:`~tofmetry.simulate.family.station_tilts`,
    drawn from ``seed``), or by the explicit per-station ``tilts_deg`` (S, 2) [deg].

    Writes ``out/stations.csv``, ``out/d<distance>/`` captures, ``out/truth.json`` (the sensor
    draw; per station the tilt and the true plane ``n . p = d`` in the camera frame, metres) and
    ``out/truth.npz`` (``true_depth_<name>`` (H, W) [mm]). Returns ``out``.
    :func:`tofmetry.simulate.walls.wall_station_means` gives the same frames' statistics in memory.
    """
    sensor = _sensor(errors, sensor)
    em = sensor.errors
    d = [float(x) for x in distances_mm]
    offset = em.mounting_offset_mm if em.on("mounting_offset") else 0.0
    tilts = resolve_tilts(len(d), tilt_deg, tilt_jitter_deg, seed, tilts_deg)
    plan = plan_wall_stations(d, n_frames, offset, tilts)
    out = Path(out)
    vk = sensor.camera(seed)
    stations, truth_st, arrays = [], [], {}
    with atomic_dir(out, force=force) as tmp:
        for st, scene, rd, frames in iter_wall_stations(vk, plan):
            meta = CaptureMeta(sensor="kinect_v2", timestamps_s=st.timestamps_s.tolist())
            write_frames(tmp / st.name, frames, meta, progress=progress)
            stations.append((st.name, st.distance_mm))
            truth_st.append({"capture": st.name, "distance_mm": st.distance_mm, "optical_centre_mm": st.optical_centre_mm,
                             "tilt_deg": list(st.tilt_deg), "plane_normal": scene.info["plane_normal"],
                             "plane_d_m": scene.info["plane_d_m"], "plane_point_m": scene.info["plane_point_m"]})
            arrays[f"true_depth_{st.name}"] = rd.true_depth.astype(np.float32)
        write_stations_csv(tmp / "stations.csv", stations)
        truth = _truth_common(vk, seed, sensor) | {
            "dataset": "wall", "n_frames": n_frames, "tilt_deg": list(tilt_deg),
            "tilt_jitter_deg": float(tilt_jitter_deg) if tilts_deg is None else None,
            "mounting_offset_mm": offset,
            "mounting_offset_note": "optical centre is this far in front of the tripod reference point: "
                                    "true optical-centre distance = stations.csv distance - offset",
            "plane_note": "camera frame at the station (x right, y down, z forward), metres: plane_normal . p = plane_d_m",
            "stations": truth_st}
        atomic_write_json(tmp / "truth.json", truth)
        _write_npz(tmp / "truth.npz", **arrays)
    return out


def checkerboard_images(out: str | os.PathLike, n_images: int = 20, board: tuple[int, int] = (9, 6),
                        square_mm: float = 50.0, seed: int = 0, errors: ErrorModel | None = None,
                        supersample: int = 4, force: bool = False, progress: Progress = None,
        sensor: SensorDraw | None = None) -> Path:
    """IR images (16-bit PNG) of a checkerboard for intrinsic calibration (paper §4.1).

    A 50 cm x 35 cm board (9 x 6 inner corners, 50 mm squares) at 0.55-1.0 m, tilted by
    16-45 deg, pushed in turn against the image centre, each image corner and each edge
    (``tofmetry.simulate.poses.board_poses``) so that the corners of the image are covered, as
    a careful photogrammetrist shoots a calibration set. The sensor's noise, vignetting and
    quantisation stay on (``errors``). IR amplitude is anti-aliased (``supersample`` x
    ``supersample`` sub-rays per pixel). Writes ``out/ir_000.png ...``, ``out/board.json``
    ``{"cols","rows","square_mm"}`` (inner corners) and ``out/truth.json`` (true intrinsics,
    board-to-camera poses; board frame: origin at the first inner corner, x along the
    columns, y along the rows, object point (i, j) = (i s, j s, 0)). Returns ``out``.
    """
    from tofmetry.simulate.poses import board_poses

    cols, rows = int(board[0]), int(board[1])
    if n_images < 1:
        raise InputError(f"checkerboard_images: n_images must be >= 1, found {n_images}")
    sensor = _sensor(errors, sensor, quantize=False)
    vk = sensor.camera(seed, supersample)
    rng = np.random.default_rng([seed, 7])
    sq = square_mm / 1000.0
    poses = board_poses(n_images, vk.intrinsics, cols, rows, sq, rng)
    out = Path(out)
    with atomic_dir(out, force=force) as tmp:
        names = _write_board_images(tmp, vk, (scenes.checkerboard(cols, rows, sq, T) for T in poses), progress)
        atomic_write_json(tmp / "board.json", {"cols": cols, "rows": rows, "square_mm": float(square_mm)})
        truth = _truth_common(vk, seed, sensor) | {
            "dataset": "checkerboard_images", "board": {"cols": cols, "rows": rows, "square_mm": float(square_mm)},
            "board_frame": "origin at the first inner corner, x along columns, y along rows, z into the board",
            "images": [{"file": n, "board_to_camera": T} for n, T in zip(names, poses)]}
        atomic_write_json(tmp / "truth.json", truth)
    return out


#: The ChArUco board the virtual sensor renders by default: 13 x 10 squares of 80 mm (104 x 80 cm, an A0
#: print; 108 corners), 56 mm DICT_4X4_100 markers: a marker module of 9.3 mm is 2.8 px at 1.2 m on the
#: Kinect v2, 2 px at 45 deg tilt, the least the ArUco decoder reads reliably on the dark IR image.
CHARUCO_DEFAULT = {"squares_x": 13, "squares_y": 10, "square_mm": 80.0, "marker_mm": 56.0,
                   "dictionary": "DICT_4X4_100"}
#: Distances of the ChArUco views [m]: far enough for most of the large board to be in view.
CHARUCO_DISTANCES_M = (0.7, 1.2)


def charuco_poses_for(n_images: int, intr, board: dict, seed: int) -> list:
    """The board-to-camera poses [m] of :func:`charuco_images` (``rng [seed, 11]``)."""
    from tofmetry.simulate.poses import charuco_poses

    sq = board["square_mm"] / 1000.0
    c, r = board["squares_x"] - 1, board["squares_y"] - 1
    gx, gy = np.meshgrid(np.arange(1, c + 1) * sq, np.arange(1, r + 1) * sq)
    pts = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    return charuco_poses(n_images, intr, board["squares_x"] * sq, board["squares_y"] * sq,
                         np.random.default_rng([int(seed), 11]), dist_range=CHARUCO_DISTANCES_M, corners_m=pts)


def charuco_images(out: str | os.PathLike, n_images: int = 10, board: dict | None = None, seed: int = 0,
                   errors: ErrorModel | None = None, supersample: int = 4, force: bool = False,
                   progress: Progress = None, sensor: SensorDraw | None = None) -> Path:
    """IR images (16-bit PNG) of a ChArUco board for intrinsic calibration, partial views included.

    The board (``board``: ``squares_x, squares_y, square_mm, marker_mm, dictionary``; default
    :data:`CHARUCO_DEFAULT`, 104 x 80 cm) at 0.7-1.2 m, tilted up to 45 deg, aimed in turn at the
    image centre, corners and edges and overhanging them
    (:func:`tofmetry.simulate.poses.charuco_poses`): the corners reach the image border. Writes
    ``out/ir_000.png ...``, ``out/board.json`` (the board, ``"type": "charuco"``) and
    ``out/truth.json`` (true intrinsics, board-to-camera poses; OpenCV's ChArUco board frame:
    origin at the outer top-left corner of the squares). Returns ``out``.
    """

    b = dict(CHARUCO_DEFAULT if board is None else board)
    if n_images < 1:
        raise InputError(f"charuco_images: n_images must be >= 1, found {n_images}")
    sensor = _sensor(errors, sensor, quantize=False)
    vk = sensor.camera(seed, supersample)
    poses = charuco_poses_for(n_images, vk.intrinsics, b, seed)
    out = Path(out)
    with atomic_dir(out, force=force) as tmp:
        names = _write_board_images(tmp, vk, (
            scenes.charuco(b["squares_x"], b["squares_y"], b["square_mm"] / 1000.0, b["marker_mm"] / 1000.0,
                           b["dictionary"], board_to_world=T) for T in poses), progress)
        atomic_write_json(tmp / "board.json", {"type": "charuco", **b})
        truth = _truth_common(vk, seed, sensor) | {
            "dataset": "charuco_images", "board": {"type": "charuco", **b},
            "board_frame": "OpenCV ChArUco: origin at the outer top-left corner of the squares, x along columns, "
                           "y along rows, z into the board; metres",
            "images": [{"file": n, "board_to_camera": T} for n, T in zip(names, poses)]}
        atomic_write_json(tmp / "truth.json", truth)
    return out


def _write_board_images(tmp: Path, vk, board_scenes, progress: Progress = None) -> list[str]:
    """One IR frame of each scene of the iterable ``board_scenes`` as ``tmp/ir_NNN.png`` (16-bit);
    returns the file names."""
    from tofmetry.io.images import write_png16

    names = []
    for k, scene in enumerate(board_scenes):
        name = f"ir_{k:03d}.png"
        write_png16(tmp / name, next(vk.iter_frames(scene, 1)).ir)
        names.append(name)
        if progress is not None:
            progress(1)
    return names


def _load_mesh(mesh) -> tuple[np.ndarray, np.ndarray]:
    from tofmetry.io import read_ply
    from tofmetry.simulate.meshes import balustrade_mesh

    if mesh is None:
        return balustrade_mesh()
    if isinstance(mesh, (str, os.PathLike)):
        d = read_ply(mesh)
        if "faces" not in d or len(d["faces"]) == 0:
            raise InputError(f"{mesh}: the mesh PLY has no faces (a triangle mesh is needed)")
        return d["points"], d["faces"]
    v, f = mesh
    return np.asarray(v, float), np.asarray(f, np.int64)


def scan(out: str | os.PathLike, n_views: int = 8, radius_m: float = 1.0, n_frames: int = 10, mesh=None,
         errors: ErrorModel | None = None, seed: int = 0, elevation_deg: float = 30.0,
         force: bool = False, progress: Progress = None,
         sensor: SensorDraw | None = None, poses: Sequence[np.ndarray] | None = None,
         info: dict | None = None, color=None, mat=None) -> Path:
    """Scan dataset of an object on the ground (paper §5): ``n_views`` views on a circle.

    Cameras ``radius_m`` (slant range) from the object centre, ``elevation_deg`` above the
    horizontal (looking down), object central in the image. ``mesh``: None (balustrade),
    a PLY path, ``(vertices, triangles)`` or ``(vertices, triangles, albedo)`` with one IR albedo per
    triangle (a painted object, :func:`tofmetry.simulate.objects.paint`); it is placed on the ground
    (z-up world).
    ``poses``: explicit camera-to-world poses (4, 4) [m] in that world (e.g. a path of
    :mod:`tofmetry.simulate.paths` around :class:`~tofmetry.simulate.objects.ObjectDraw`
    vertices, which are already placed); they replace the circle (``n_views``, ``radius_m``,
    ``elevation_deg`` are then unused). ``info``: JSON-able description recorded in ``truth.json``
    (e.g. the object and path draws).
    ``color``: a :class:`~tofmetry.simulate.color.ColourCamera` (``True``: the Kinect v2's, 2 DN
    noise): each view also gets one colour frame, ray cast from the colour camera's own viewpoint
    (:func:`~tofmetry.simulate.color.render_colour`), and its calibration beside the frames.
    ``mat``: a :class:`~tofmetry.simulate.mat.DotMat` printed sheet under the object (the study's flat
    targets as a pattern; recorded in ``truth.json``).
    Writes ``out/views/00 ...`` captures (depth + IR [+ colour]), ``out/reference.ply`` (the placed mesh,
    world frame, metres) and ``out/truth.json`` (camera-to-world poses). Returns ``out``.
    """
    from tofmetry.io import write_ply
    from tofmetry.simulate.color import ColourCamera, render_colour
    from tofmetry.simulate.objects import textured_scene
    from tofmetry.simulate.poses import orbit_poses

    sensor = _sensor(errors, sensor)
    albedo = None
    if isinstance(mesh, tuple) and len(mesh) == 3:  # (vertices, triangles, albedo per triangle)
        mesh, albedo = mesh[:2], mesh[2]
    v, f = _load_mesh(mesh)
    scene = textured_scene(v, f, albedo, mat)
    vw = scene.info["mesh_vertices_world"]
    target = np.array([0.0, 0.0, (vw[:, 2].max()) / 2])
    if poses is None:
        poses = orbit_poses(n_views, radius_m, elevation_deg, target)
    else:
        poses = [np.asarray(T, np.float64) for T in poses]
        if len(poses) < 1 or any(T.shape != (4, 4) or not np.isfinite(T).all() for T in poses):
            raise InputError("scan: poses must be a non-empty list of finite (4, 4) camera-to-world matrices")
    cam = ColourCamera(noise_dn=2.0) if color is True else (color or None)
    if cam is not None and not isinstance(cam, ColourCamera):
        raise InputError(f"scan: color must be True, False/None or a ColourCamera, found {type(color).__name__}")
    vk = sensor.camera(seed)
    rng_c = np.random.default_rng([seed, 7])
    out = Path(out)
    with atomic_dir(out, force=force) as tmp:
        views = []
        for k, T in enumerate(poses):
            name = f"{k:02d}"
            ts = 3600.0 + 60.0 * k + np.arange(n_frames, dtype=float)
            meta = CaptureMeta(sensor="kinect_v2", timestamps_s=ts.tolist())
            colour = None if cam is None else (render_colour(scene, cam, T, rng=rng_c).image, cam)
            write_frames(tmp / "views" / name, vk.iter_frames(scene, n_frames, T, timestamps_s=ts), meta,
                         progress=progress, colour=colour)
            views.append({"name": name, "camera_to_world": T})
        write_ply(tmp / "reference.ply", vw, faces=scene.info["mesh_triangles"])
        truth = _truth_common(vk, seed, sensor) | {
            "dataset": "scan", "world": "z up, ground plane z = 0, object centred on the z axis",
            "radius_m": radius_m, "elevation_deg": elevation_deg, "target_m": target, "views": views}
        if cam is not None:
            truth["color_camera"] = cam.to_dict()
        if mat is not None:
            truth["mat"] = mat.to_dict()
        if info:
            truth["info"] = info
        atomic_write_json(tmp / "truth.json", truth)
    return out


def warmup(out: str | os.PathLike, duration_s: float = 5400.0, interval_s: float = 15.0, distance_m: float = 1.36,
           errors: ErrorModel | None = None, seed: int = 0, tilt_deg: tuple = (1.5, -2.0),
           force: bool = False, progress: Progress = None,
        sensor: SensorDraw | None = None) -> Path:
    """Warm-up experiment (paper §3.2): wall ~1.36 m, slightly tilted, one frame every 15 s
    from power-on (``timestamps_s`` from 0) for 1.5 h. Writes ``out/capture`` and
    ``out/truth.json`` (true drift per frame). Returns ``out``."""
    from tofmetry.simulate.errors import warmup_mm

    if not interval_s > 0 or not duration_s >= 0:
        raise InputError(f"warmup: need interval_s > 0 and duration_s >= 0, found {interval_s}, {duration_s}")
    sensor = _sensor(errors, sensor)
    em = sensor.errors
    ts = np.arange(0.0, duration_s + 1e-9, interval_s)
    vk = sensor.camera(seed)
    scene = scenes.wall(distance_m, tilt_deg)
    rd = vk.render(scene)
    out = Path(out)
    with atomic_dir(out, force=force) as tmp:
        meta = CaptureMeta(sensor="kinect_v2", timestamps_s=ts.tolist())
        write_frames(tmp / "capture", vk.iter_frames(scene, len(ts), rendering=rd, timestamps_s=ts), meta,
                     progress=progress)
        drift = warmup_mm(ts, em) if em.on("warmup") else np.zeros_like(ts)
        truth = _truth_common(vk, seed, sensor) | {"dataset": "warmup", "scene": scene.info, "timestamps_s": ts,
                                           "true_drift_mm": drift}
        atomic_write_json(tmp / "truth.json", truth)
        _write_npz(tmp / "truth.npz", true_depth_mm=rd.true_depth)
    return out


def noise(out: str | os.PathLike, n_frames: int = 100, distance_m: float = 1.15, errors: ErrorModel | None = None,
          seed: int = 0, force: bool = False, progress: Progress = None,
        sensor: SensorDraw | None = None) -> Path:
    """Noise experiment (paper §3.2, Fig. 3): ``n_frames`` of a wall at 1.15 m. Writes
    ``out/capture``, ``out/truth.json`` and ``out/truth.npz`` (``noise_sigma_mm`` (H, W),
    ``true_depth_mm``). Returns ``out``."""
    from tofmetry.simulate.errors import noise_sigma_mm

    sensor = _sensor(errors, sensor)
    em = sensor.errors
    vk = sensor.camera(seed)
    scene = scenes.wall(distance_m)
    rd = vk.render(scene)
    out = Path(out)
    with atomic_dir(out, force=force) as tmp:
        _write_static_capture(tmp / "capture", vk, scene, rd, n_frames, progress)
        sig = noise_sigma_mm(rd.amplitude, rd.depth0, em) if em.on("noise") else np.zeros_like(rd.depth0)
        atomic_write_json(tmp / "truth.json", _truth_common(vk, seed, sensor) | {"dataset": "noise", "scene": scene.info})
        _write_npz(tmp / "truth.npz", noise_sigma_mm=sig.astype(np.float32), true_depth_mm=rd.true_depth)
    return out


def _label_rect(labels: np.ndarray, lab: int, inset: int) -> tuple[list, list] | None:
    vv, uu = np.nonzero(labels == lab)
    if vv.size == 0:
        return None
    full = [int(uu.min()), int(vv.min()), int(uu.max()) + 1, int(vv.max()) + 1]
    ins = [full[0] + inset, full[1] + inset, full[2] - inset, full[3] - inset]
    return full, ins


def materials(out: str | os.PathLike, board: str = "grey", n_frames: int = 20, distance_m: float = 1.0,
              errors: ErrorModel | None = None, seed: int = 0, inset_px: int = 3,
              force: bool = False, progress: Progress = None,
        sensor: SensorDraw | None = None) -> Path:
    """Material / grey-level experiment (paper §3.3.1, Fig. 4).

    ``board="grey"``: grey-level checkerboard; ``"samples"``: material samples incl. a
    reflective CD. Writes ``out/capture`` (depth + IR), ``out/regions.json`` (user input format
    of the assessment: ``{"regions": [{"name", "rect": [u0, v0, u1, v1], "reference"}]}``,
    rect = pixel box, u1/v1 exclusive, inset by ``inset_px`` from the sample edges),
    ``out/truth.json`` (albedos, reflective flags, full pixel boxes) and ``out/truth.npz``
    (``labels`` (H, W), ``true_depth_mm``). Returns ``out``.
    """
    if board not in ("grey", "samples"):
        raise InputError(f"materials: board must be 'grey' or 'samples', found {board!r}")
    sensor = _sensor(errors, sensor)
    scene = scenes.grey_board(distance_m) if board == "grey" else scenes.material_board(distance_m)
    vk = sensor.camera(seed)
    rd = vk.render(scene)
    regions, samples = [], []
    for s in scene.info["samples"]:
        r = _label_rect(rd.labels, s["label"], inset_px)
        if r is None:
            continue
        regions.append({"name": s["name"], "rect": r[1], "reference": bool(s["reference"])})
        samples.append(s | {"rect_px_full": r[0], "rect_px": r[1]})
    out = Path(out)
    with atomic_dir(out, force=force) as tmp:
        _write_static_capture(tmp / "capture", vk, scene, rd, n_frames, progress)
        atomic_write_json(tmp / "regions.json", {"rect_convention": "[u0, v0, u1, v1] pixels, u1 and v1 exclusive",
                                                 "regions": regions})
        atomic_write_json(tmp / "truth.json", _truth_common(vk, seed, sensor) | {
            "dataset": "materials", "board": board, "scene": {k: v for k, v in scene.info.items() if k != "samples"},
            "samples": samples, "labels": {int(k): v for k, v in scene.labels.items()}})
        _write_npz(tmp / "truth.npz", labels=rd.labels, true_depth_mm=rd.true_depth)
    return out


#: Camera pose of the outdoor scene: 1.35 m high, ~1.4 m from the box, looking down at the table.
OUTDOOR_POSITION = (0.0, 0.9, 1.35)
OUTDOOR_TARGET = (0.0, 2.2, 0.75)


def outdoor(out: str | os.PathLike, n_frames: int = 10, ambient: float = 1.0, errors: ErrorModel | None = None,
            seed: int = 0, force: bool = False, progress: Progress = None,
        sensor: SensorDraw | None = None) -> Path:
    """Sunny outdoor acquisition (paper §3.3.2, Fig. 5): a table with a box, far background,
    ``ambient`` = 1. About 20 % of the 217 088 pixels stay valid, ~2 % of them flying, more
    toward the edges of the field of view. Writes ``out/capture`` (depth + IR),
    ``out/truth.json`` and ``out/truth.npz`` (``flying`` (T, H, W), ``labels``). Returns ``out``."""
    from tofmetry.simulate.poses import look_at

    sensor = _sensor(errors, sensor)
    sensor = sensor.with_errors(sensor.errors.with_(ambient=float(ambient)))
    vk = sensor.camera(seed)
    scene = scenes.outdoor_table()
    T = look_at(OUTDOOR_POSITION, OUTDOOR_TARGET)
    rd = vk.render(scene, T)
    out = Path(out)
    with atomic_dir(out, force=force) as tmp:
        _, fly = _write_static_capture(tmp / "capture", vk, scene, rd, n_frames, progress, pose=T)
        atomic_write_json(tmp / "truth.json", _truth_common(vk, seed, sensor) | {
            "dataset": "outdoor", "ambient": ambient, "camera_to_world": T, "scene": scene.info,
            "labels": {int(k): v for k, v in scene.labels.items()}})
        _write_npz(tmp / "truth.npz", flying=np.stack(fly), labels=rd.labels, true_depth_mm=rd.true_depth)
    return out
