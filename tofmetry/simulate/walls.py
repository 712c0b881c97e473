"""Wall stations of a depth-calibration dataset, shared by the writer and the in-memory path.

:func:`plan_wall_stations` fixes the geometry and the time line of a wall dataset (paper
§4.2.1: a white wall, one tripod station per distance, frames 1 s apart, ~2 min to move the
tripod, warm sensor); :func:`iter_wall_stations` renders each station and streams its frames
through :meth:`VirtualKinect.iter_frames`. :func:`tofmetry.simulate.datasets.wall_dataset`
writes those frames as PNG captures; :func:`wall_station_means` reduces them in memory to
per-pixel temporal statistics, for running a method on a family of sensors without files.
With the same sensor, distances, frames, tilts and seed both see the very same frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from tofmetry.errors import InputError
from tofmetry.simulate import scenes
from tofmetry.simulate.camera import Frame, VirtualKinect
from tofmetry.simulate.family import SensorDraw, default_sensor, station_tilts
from tofmetry.simulate.render import Rendering

#: Default wall stations [mm]: 0.8 m, then 1 m to 4.5 m every 25 cm (paper §4.2.1, cut at 4.5 m).
DEFAULT_DISTANCES_MM = (800,) + tuple(range(1000, 4501, 250))
#: Power-on to the first frame [s] (warm sensor) and time to move the tripod between stations [s].
T0_S, MOVE_S = 3600.0, 120.0


@dataclass(frozen=True)
class WallStation:
    """Geometry and time line of one wall station (camera at the identity pose, metres).

    Attributes
    ----------
    name : str, capture name ``d<distance>``
    distance_mm : float, tripod reference point to the wall along the optical axis (stations.csv)
    optical_centre_mm : float, optical centre to the wall along the optical axis = distance - offset
    tilt_deg : (2,) rotation of the wall normal about x then y [deg]
    timestamps_s : (T,) float64, time since power-on of each frame [s]
    """

    name: str
    distance_mm: float
    optical_centre_mm: float
    tilt_deg: tuple
    timestamps_s: np.ndarray

    def scene(self):
        """The wall as a :class:`~tofmetry.simulate.surfaces.Scene` (plane truth in ``scene.info``)."""
        return scenes.wall(self.optical_centre_mm / 1000.0, self.tilt_deg)


def resolve_tilts(n: int, tilt_deg=(0.0, 0.0), tilt_jitter_deg: float = 0.0, seed: int = 0,
                  tilts_deg=None) -> np.ndarray:
    """Per-station tilts (n, 2) [deg]: explicit ``tilts_deg``, else ``tilt_deg`` plus
    :func:`~tofmetry.simulate.family.station_tilts` ``(n, tilt_jitter_deg, seed)``."""
    if tilts_deg is not None:
        t = np.asarray(tilts_deg, dtype=np.float64)
        if t.shape != (n, 2) or not np.all(np.isfinite(t)):
            raise InputError(f"tilts_deg: expected a finite ({n}, 2) array (rx, ry per station) [deg], found shape {t.shape}")
        return t
    base = np.asarray(tilt_deg, dtype=np.float64)
    if base.shape != (2,):
        raise InputError(f"tilt_deg: expected (rx, ry) [deg], found {tilt_deg!r}")
    return base + station_tilts(n, float(tilt_jitter_deg), seed)


def plan_wall_stations(distances_mm: Sequence[float], n_frames: int, offset_mm: float,
                       tilts_deg: np.ndarray) -> list[WallStation]:
    """Stations in the given order: names, optical-centre distances, tilts and time stamps.

    Parameters
    ----------
    distances_mm : strictly increasing positive [mm] (tripod reference point to wall)
    n_frames : int >= 1, frames per station, 1 s apart
    offset_mm : float, mounting offset (optical centre in front of the reference point) [mm]
    tilts_deg : (S, 2) [deg]
    """
    d = [float(x) for x in distances_mm]
    if not d or any(not (x > 0 and math.isfinite(x)) for x in d) or any(b <= a for a, b in zip(d, d[1:])):
        raise InputError(f"wall_dataset: distances_mm must be positive and strictly increasing, found {d}")
    if n_frames < 1:
        raise InputError(f"wall_dataset: n_frames must be >= 1, found {n_frames}")
    if any(x - offset_mm <= 0 for x in d):
        raise InputError(f"wall_dataset: every distance must exceed the mounting offset {offset_mm} mm, found {d}")
    out, t = [], T0_S
    for dist, tilt in zip(d, np.asarray(tilts_deg, float)):
        ts = t + np.arange(n_frames, dtype=float)
        t = ts[-1] + MOVE_S
        out.append(WallStation(f"d{int(round(dist)):04d}", dist, dist - offset_mm,
                               (float(tilt[0]), float(tilt[1])), ts))
    return out


def iter_wall_stations(vk: VirtualKinect, stations: Sequence[WallStation], *,
                       with_ir: bool = True) -> Iterator[tuple[WallStation, object, Rendering, Iterator[Frame]]]:
    """For each station in order: ``(station, scene, rendering, frames)``; consume ``frames`` before
    the next station (the noise streams of ``vk`` are numbered in capture order)."""
    for st in stations:
        scene = st.scene()
        rd = vk.render(scene)
        yield st, scene, rd, vk.iter_frames(scene, len(st.timestamps_s), rendering=rd,
                                            timestamps_s=st.timestamps_s, with_ir=with_ir)


@dataclass
class StationMean:
    """Temporal statistics of one wall station, as a processing step would compute them.

    Attributes
    ----------
    name, distance_mm, optical_centre_mm, tilt_deg : see :class:`WallStation`
    mean_mm : (H, W) float64 [mm], temporal mean of the valid samples; NaN where the pixel is
        invalid (0) in more than half of the frames
    std_mm : (H, W) float64 [mm], temporal sample std (ddof = 1), NaN where ``mean_mm`` is NaN
        or fewer than 2 samples are valid
    count : (H, W) int32, valid samples per pixel
    n_frames : int
    true_depth_mm : (H, W) float64 [mm], Z of the true wall at each pixel centre
    plane_normal : (3,) float64, unit normal of the true wall in the camera frame
    plane_d_m : float, the true wall is ``plane_normal . p = plane_d_m`` (p in metres, camera frame)
    """

    name: str
    distance_mm: float
    optical_centre_mm: float
    tilt_deg: tuple
    mean_mm: np.ndarray
    std_mm: np.ndarray
    count: np.ndarray
    n_frames: int
    true_depth_mm: np.ndarray
    plane_normal: np.ndarray
    plane_d_m: float


def wall_station_means(draw: SensorDraw | None = None, distances_mm: Sequence[float] = DEFAULT_DISTANCES_MM,
                       n_frames: int = 50, tilts_deg=None, seed: int = 0, tilt_jitter_deg: float = 0.0,
                       tilt_deg=(0.0, 0.0)) -> list[StationMean]:
    """Per-station temporal mean and std of a simulated wall dataset, in memory (no PNG files).

    The frames are exactly those :func:`tofmetry.simulate.datasets.wall_dataset` writes for the
    same arguments (same :meth:`VirtualKinect.iter_frames` error path: noise, warm-up wander,
    validity and mm quantisation included), reduced with
    :class:`tofmetry.pointcloud.RunningDepthStats` (float64 shifted sums).

    Parameters
    ----------
    draw : SensorDraw, default :func:`~tofmetry.simulate.family.default_sensor`
    distances_mm : station distances, tripod reference point to wall [mm], strictly increasing
    n_frames : frames per station
    tilts_deg : (S, 2) per-station tilts [deg], or None for ``tilt_deg`` + ``tilt_jitter_deg`` draws
    seed : noise seed of the camera and of the tilt draws
    tilt_jitter_deg : max extra tilt per station [deg] (:func:`~tofmetry.simulate.family.station_tilts`)
    tilt_deg : (rx, ry) common tilt [deg]

    Returns
    -------
    list of StationMean, in station order.
    """
    from tofmetry.pointcloud import RunningDepthStats

    draw = draw if draw is not None else default_sensor()
    em = draw.errors
    if not em.on("quantize"):
        raise InputError("wall_station_means: needs quantised depth (uint16 mm) like a dataset: enable 'quantize'")
    d = list(distances_mm)
    tilts = resolve_tilts(len(d), tilt_deg, tilt_jitter_deg, seed, tilts_deg)
    offset = em.mounting_offset_mm if em.on("mounting_offset") else 0.0
    vk = draw.camera(seed)
    out = []
    for st, scene, rd, frames in iter_wall_stations(vk, plan_wall_stations(d, n_frames, offset, tilts), with_ir=False):
        rs = RunningDepthStats(rd.depth0.shape)
        for fr in frames:
            rs.update(fr.depth)
        res = rs.result()
        keep = 2 * res.count >= n_frames  # invalid in at most half of the frames
        out.append(StationMean(
            st.name, st.distance_mm, st.optical_centre_mm, st.tilt_deg,
            np.where(keep, res.mean, np.nan), np.where(keep, res.std, np.nan), res.count, n_frames,
            rd.true_depth, np.asarray(scene.info["plane_normal"], float), float(scene.info["plane_d_m"])))
    return out
