"""Camera and board poses for the simulated datasets (4x4, metres)."""

from __future__ import annotations

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics
from tofmetry.simulate.scenes import rotation_xyz


def look_at(position: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world pose of a camera at ``position`` looking at ``target`` (z-up world).

    Camera axes: z forward (toward the target), x right, y down (image rows go down the
    world's ``up``).

    Returns
    -------
    (4, 4) float64 camera-to-world.
    """
    p, t, u = (np.asarray(a, float).reshape(3) for a in (position, target, up))
    z = t - p
    if np.linalg.norm(z) < 1e-9:
        raise InputError("look_at: position and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(z, u)
    if np.linalg.norm(x) < 1e-9:
        raise InputError("look_at: viewing direction parallel to the up vector")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, p
    return T


def orbit_poses(n_views: int, radius_m: float, elevation_deg: float, target: np.ndarray,
                start_deg: float = 0.0) -> list[np.ndarray]:
    """``n_views`` cameras evenly spaced on a circle, ``radius_m`` from ``target`` (slant range),
    ``elevation_deg`` above the horizontal, all looking at ``target``."""
    if n_views < 1 or not radius_m > 0:
        raise InputError(f"orbit_poses: need n_views >= 1 and radius_m > 0, found {n_views}, {radius_m}")
    el = np.radians(elevation_deg)
    out = []
    for k in range(n_views):
        az = np.radians(start_deg) + 2 * np.pi * k / n_views
        d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        out.append(look_at(np.asarray(target, float) + radius_m * d, target))
    return out


def board_poses(n: int, intr: CameraIntrinsics, cols: int, rows: int, square_m: float, rng: np.random.Generator,
                dist_range: tuple = (0.6, 1.6), max_tilt_deg: float = 40.0, margin_px: float = 12.0,
                board_margin_m: float = 0.05) -> list[np.ndarray]:
    """Board-to-camera poses covering the whole image (incl. corners), distances and tilts.

    Board centres aim at a 3 x 3 grid of image positions (cycled, jittered); tilts up to
    ``max_tilt_deg``; a pose is kept only if the whole board (with margin) projects inside
    the image by ``margin_px``.
    """
    w = (cols + 1) * square_m + 2 * board_margin_m
    h = (rows + 1) * square_m + 2 * board_margin_m
    outline = np.array([[x, y, 0.0] for x in (-w / 2, w / 2) for y in (-h / 2, h / 2)])
    outline = np.vstack([outline, [[0, -h / 2, 0], [0, h / 2, 0], [-w / 2, 0, 0], [w / 2, 0, 0]]])
    centre_off = np.array([(cols - 1) * square_m / 2, (rows - 1) * square_m / 2, 0.0])
    targets = [(0.5, 0.5)] + [(fx, fy) for fy in (0.12, 0.5, 0.88) for fx in (0.12, 0.5, 0.88) if (fx, fy) != (0.5, 0.5)]
    poses = []
    tries = 0
    while len(poses) < n:
        tries += 1
        if tries > 2000 * max(n, 1):
            raise InputError("board_poses: could not place the board inside the image; use a smaller board")
        fx, fy = targets[len(poses) % len(targets)]
        u = fx * (intr.width - 1) + rng.normal(0, 10)
        v = fy * (intr.height - 1) + rng.normal(0, 10)
        xy = intr.pixel_to_normalized(np.array([[u, v]]))[0]
        d = rng.uniform(*dist_range)
        c = d * np.array([xy[0], xy[1], 1.0])
        tilt = rng.uniform(0, max_tilt_deg)
        ang = rng.uniform(0, 2 * np.pi)
        R = rotation_xyz(tilt * np.sin(ang), tilt * np.cos(ang), rng.uniform(-15, 15))
        pts = outline @ R.T + c
        if np.any(pts[:, 2] < 0.3):
            continue
        uv = intr.project(pts)
        if (uv[:, 0].min() < margin_px or uv[:, 1].min() < margin_px or uv[:, 0].max() > intr.width - 1 - margin_px
                or uv[:, 1].max() > intr.height - 1 - margin_px):
            continue
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = c - R @ centre_off
        poses.append(T)
    return poses
