"""Acquisition paths around an object on the ground, drawn by seed (camera-to-world poses).

Two kinds, as a user scans a small object (study §5.1):

* ``turntable``: the object turns on a turntable in front of a fixed camera, which is the same
  as the camera moving on a horizontal circle about the object: views evenly spaced in azimuth,
  one elevation, the object centred, no roll;
* ``handheld``: the camera carried around the object by hand: uneven azimuth steps (+-35 % of
  the mean step), the distance varying +-12 %, the elevation +-8 deg about its mean, a roll
  (tilt about the viewing axis) of up to +-15 deg and the aim off the object centre by up to
  4 % of the distance.

:func:`random_path` draws: the kind (0.5 each), 6-16 views, the mean slant distance from the
object centre in 0.6-1.5 m (at least ``0.5 m + 0.75 x`` the object's largest side, so that its
near side stays beyond the sensor's 0.5 m minimum range, and at most 4.5 x the largest side, so
that the object fills a useful part of the image), the mean elevation U(15, 45) deg, and the
start azimuth U(0, 360) deg. :func:`two_rings` is the plan's proposal: a ring plus a higher ring
of zenithal views (study §6.3).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tofmetry.errors import InputError
from tofmetry.simulate.poses import look_at


@dataclass
class PathDraw:
    """A set of camera poses around an object.

    Attributes
    ----------
    kind : ``"turntable"``, ``"handheld"`` or ``"two_rings"``
    poses : list of (4, 4) camera-to-world [m] (z-up world, object on the ground at the origin)
    distance_m : mean slant distance from the object centre [m]
    elevation_deg : mean elevation [deg]
    seed : int or None
    params : the other drawn parameters (JSON-able)
    """

    kind: str
    poses: list
    distance_m: float
    elevation_deg: float
    seed: int | None = None
    params: dict = field(default_factory=dict)

    @property
    def n_views(self) -> int:
        return len(self.poses)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "n_views": self.n_views, "distance_m": round(self.distance_m, 4),
                "elevation_deg": round(self.elevation_deg, 2), "seed": self.seed, **self.params}


def _direction(az_rad: float, el_rad: float) -> np.ndarray:
    return np.array([np.cos(el_rad) * np.cos(az_rad), np.cos(el_rad) * np.sin(az_rad), np.sin(el_rad)])


def _roll(T: np.ndarray, deg: float) -> np.ndarray:
    a = np.radians(deg)
    R = np.eye(4)
    R[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return T @ R


def turntable(n_views: int, distance_m: float, elevation_deg: float, target, start_deg: float = 0.0) -> PathDraw:
    """``n_views`` evenly spaced on a circle, ``distance_m`` (slant) from ``target``, looking at it."""
    if n_views < 1 or not distance_m > 0:
        raise InputError(f"turntable: need n_views >= 1 and distance_m > 0, found {n_views}, {distance_m}")
    t = np.asarray(target, float)
    el = np.radians(elevation_deg)
    poses = [look_at(t + distance_m * _direction(np.radians(start_deg) + 2 * np.pi * k / n_views, el), t)
             for k in range(n_views)]
    return PathDraw("turntable", poses, float(distance_m), float(elevation_deg), params={"start_deg": float(start_deg)})


def handheld(n_views: int, distance_m: float, elevation_deg: float, target, rng: np.random.Generator,
             start_deg: float = 0.0, max_roll_deg: float = 15.0, step_jitter: float = 0.35,
             distance_jitter: float = 0.12, elevation_jitter_deg: float = 8.0, aim_jitter: float = 0.04) -> PathDraw:
    """A hand-held loop around ``target`` (module docstring): uneven steps, varying distance and
    elevation, roll, aim off-centre. The loop still closes (the steps sum to 360 deg)."""
    if n_views < 2 or not distance_m > 0:
        raise InputError(f"handheld: need n_views >= 2 and distance_m > 0, found {n_views}, {distance_m}")
    t = np.asarray(target, float)
    steps = 1.0 + rng.uniform(-step_jitter, step_jitter, n_views)
    az = np.radians(start_deg) + 2 * np.pi * np.concatenate([[0.0], np.cumsum(steps)[:-1]]) / steps.sum()
    poses, rolls = [], []
    for a in az:
        d = distance_m * (1 + rng.uniform(-distance_jitter, distance_jitter))
        el = np.radians(np.clip(elevation_deg + rng.uniform(-elevation_jitter_deg, elevation_jitter_deg), 5.0, 80.0))
        aim = t + rng.uniform(-aim_jitter, aim_jitter, 3) * distance_m
        roll = float(rng.uniform(-max_roll_deg, max_roll_deg))
        poses.append(_roll(look_at(t + d * _direction(a, el), aim), roll))
        rolls.append(round(roll, 2))
    return PathDraw("handheld", poses, float(distance_m), float(elevation_deg),
                    params={"start_deg": float(start_deg), "azimuth_deg": [round(float(np.degrees(x)) % 360, 2) for x in az],
                            "roll_deg": rolls})


def two_rings(n_low: int, n_high: int, distance_m: float, elevation_deg: float, high_elevation_deg: float, target,
              start_deg: float = 0.0) -> PathDraw:
    """A ring of ``n_low`` views plus a ring of ``n_high`` zenithal views (higher elevation),
    interleaved in azimuth; processed ring by ring (low ring, then high ring)."""
    low = turntable(n_low, distance_m, elevation_deg, target, start_deg).poses
    high = turntable(n_high, distance_m, high_elevation_deg, target, start_deg + 180.0 / n_low).poses if n_high else []
    return PathDraw("two_rings", low + high, float(distance_m), float(elevation_deg),
                    params={"n_low": n_low, "n_high": n_high, "high_elevation_deg": float(high_elevation_deg),
                            "start_deg": float(start_deg)})


def distance_bounds(size_m: float, lo: float = 0.6, hi: float = 1.5) -> tuple[float, float]:
    """Slant distances [m] the family draws for an object whose largest side is ``size_m``."""
    a = max(lo, 0.5 + 0.75 * size_m)
    b = min(hi, max(4.5 * size_m, a))
    return a, max(a, b)


def random_path(seed: int, target, size_m: float, n_views: tuple[int, int] = (6, 16),
                kinds: tuple[str, ...] = ("turntable", "handheld")) -> PathDraw:
    """Draw a path (module docstring) around ``target`` (the object's centre, z-up world) for an
    object whose largest side is ``size_m`` [m]."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xA7B]))
    kind = str(rng.choice(list(kinds)))
    n = int(rng.integers(n_views[0], n_views[1] + 1))
    lo, hi = distance_bounds(size_m)
    dist = float(rng.uniform(lo, hi))
    el = float(rng.uniform(15.0, 45.0))
    start = float(rng.uniform(0.0, 360.0))
    p = turntable(n, dist, el, target, start) if kind == "turntable" else handheld(n, dist, el, target, rng, start)
    p.seed = int(seed)
    return p
