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


#: Planned board placements of a calibration set: where the board's image bounding box is pushed
#: (0 = left/top edge, 0.5 = centred, 1 = right/bottom edge). Centre, the four image corners, the
#: four edge midpoints, then the corners again (with other tilts), as a photogrammetrist shoots them.
BOARD_ANCHORS = ((0.5, 0.5), (0, 0), (1, 0), (0, 1), (1, 1), (0.5, 0), (1, 0.5), (0.5, 1), (0, 0.5))


def board_poses(n: int, intr: CameraIntrinsics, cols: int, rows: int, square_m: float, rng: np.random.Generator,
                dist_range: tuple = (0.55, 1.0), max_tilt_deg: float = 45.0, margin_px: float = 8.0,
                board_margin_m: float = 0.05) -> list[np.ndarray]:
    """Board-to-camera poses planned to cover the whole image, including its corners.

    Pose ``k`` pushes the board's projected outline (with its white margin) against the image
    region ``BOARD_ANCHORS[k % 9]`` (corners and edges to within ``margin_px``), at a distance
    drawn in ``dist_range`` [m] (pushed back when the board would not fit) and tilted by
    ``max_tilt_deg`` x (0.35..1) about a direction that turns over the set (half the poses
    tilted toward the image centre, half away), plus up to 15 deg of in-plane rotation.
    A pose is kept only if the whole board projects inside the image by ``margin_px``.

    Returns
    -------
    list of (4, 4) board-to-camera [m] (board frame: origin at the first inner corner).
    """
    w = (cols + 1) * square_m + 2 * board_margin_m
    h = (rows + 1) * square_m + 2 * board_margin_m
    xs, ys = np.linspace(-w / 2, w / 2, 7), np.linspace(-h / 2, h / 2, 7)
    outline = np.array([[x, y, 0.0] for x in xs for y in ys if x in (xs[0], xs[-1]) or y in (ys[0], ys[-1])])
    centre_off = np.array([(cols - 1) * square_m / 2, (rows - 1) * square_m / 2, 0.0])
    W, H = intr.width, intr.height
    poses: list[np.ndarray] = []
    tries = 0
    while len(poses) < n:
        tries += 1
        if tries > 200 * max(n, 1):
            raise InputError("board_poses: could not place the board inside the image; use a smaller board")
        k = len(poses)
        ax, ay = BOARD_ANCHORS[k % len(BOARD_ANCHORS)]
        rnd = k // len(BOARD_ANCHORS)
        tilt = max_tilt_deg * rng.uniform(0.35, 1.0)
        # tilt direction: toward / away from the image centre alternately (plus jitter); centre: random
        if (ax, ay) == (0.5, 0.5):
            ang = rng.uniform(0, 2 * np.pi)
        else:
            ang = np.arctan2(ay - 0.5, ax - 0.5) + (np.pi if (k + rnd) % 2 else 0.0) + rng.normal(0, 0.3)
        # rotation about the axis perpendicular to ``ang`` in the image plane
        R = rotation_xyz(tilt * np.sin(ang), -tilt * np.cos(ang), rng.uniform(-15, 15))
        d = rng.uniform(*dist_range)
        ok = False
        for _grow in range(12):
            target = np.array([W / 2.0, H / 2.0])
            for _it in range(8):
                xy = intr.pixel_to_normalized(target[None])[0]
                c = d * np.array([xy[0], xy[1], 1.0])
                pts = outline @ R.T + c
                if np.any(pts[:, 2] < 0.3):
                    break
                uv = intr.project(pts)
                lo, hi = uv.min(0), uv.max(0)
                want = []
                for a, lo_, hi_, size in ((ax, lo[0], hi[0], W), (ay, lo[1], hi[1], H)):
                    if a == 0:
                        want.append(margin_px + 1 - lo_)
                    elif a == 1:
                        want.append(size - 1 - margin_px - 1 - hi_)
                    else:
                        want.append((size - 1) / 2 - (lo_ + hi_) / 2)
                target = target + np.array(want)
            else:
                pts = outline @ R.T + c
                uv = intr.project(pts)
                if (np.all(pts[:, 2] > 0.3) and uv[:, 0].min() >= margin_px and uv[:, 1].min() >= margin_px
                        and uv[:, 0].max() <= W - 1 - margin_px and uv[:, 1].max() <= H - 1 - margin_px):
                    ok = True
                    break
            d *= 1.08
        if not ok:
            continue
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = c - R @ centre_off
        poses.append(T)
    return poses


def charuco_poses(n: int, intr: CameraIntrinsics, width_m: float, height_m: float, rng: np.random.Generator,
                  dist_range: tuple = (0.55, 1.0), max_tilt_deg: float = 45.0, min_inside: float = 0.3,
                  corners_m: np.ndarray | None = None) -> list[np.ndarray]:
    """Board-to-camera poses for a board that may leave the image (ChArUco, partial views).

    Pose ``k`` aims the board's centre at a pixel between the image centre and the region
    ``BOARD_ANCHORS[k % 9]`` (0.5-0.95 of the way, so a board larger than the field of view
    overhangs the image corner or edge and its corners reach the image border), at a distance
    drawn in ``dist_range`` [m], tilted as in :func:`board_poses`. A pose is kept when at least
    ``min_inside`` of ``corners_m`` (board points, default a 9 x 9 grid over the board) project
    inside the image.

    Parameters
    ----------
    width_m, height_m : board size [m]; board frame origin at its top-left corner, x right, y down

    Returns
    -------
    list of (4, 4) board-to-camera [m].
    """
    W, H = intr.width, intr.height
    if corners_m is None:
        gx, gy = np.meshgrid(np.linspace(0, width_m, 9), np.linspace(0, height_m, 9))
        corners_m = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    centre_off = np.array([width_m / 2, height_m / 2, 0.0])
    r_max = 1.05 * float(np.max(np.linalg.norm(intr.pixel_to_normalized(
        np.array([[0.0, 0.0], [W - 1.0, 0.0], [0.0, H - 1.0], [W - 1.0, H - 1.0]])), axis=1)))
    poses: list[np.ndarray] = []
    tries = 0
    while len(poses) < n:
        tries += 1
        if tries > 200 * max(n, 1):
            raise InputError("charuco_poses: could not place the board; use a larger board or a longer distance range")
        k = len(poses)
        ax, ay = BOARD_ANCHORS[k % len(BOARD_ANCHORS)]
        tilt = max_tilt_deg * rng.uniform(0.35, 1.0)
        if (ax, ay) == (0.5, 0.5):
            ang, reach = rng.uniform(0, 2 * np.pi), 0.0
        else:
            ang = np.arctan2(ay - 0.5, ax - 0.5) + (np.pi if k % 2 else 0.0) + rng.normal(0, 0.3)
            reach = rng.uniform(0.5, 0.95)
        R = rotation_xyz(tilt * np.sin(ang), -tilt * np.cos(ang), rng.uniform(-15, 15))
        target = np.array([W / 2 + reach * (ax - 0.5) * W, H / 2 + reach * (ay - 0.5) * H])
        xy = intr.pixel_to_normalized(target[None])[0]
        c = rng.uniform(*dist_range) * np.array([xy[0], xy[1], 1.0])
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = c - R @ centre_off
        p = corners_m @ R.T + T[:3, 3]
        if np.any(p[:, 2] < 0.2):
            continue
        uv = intr.project(p)
        inside = (uv[:, 0] >= 2) & (uv[:, 1] >= 2) & (uv[:, 0] <= W - 3) & (uv[:, 1] <= H - 3)
        inside &= np.linalg.norm(p[:, :2] / p[:, 2:], axis=1) <= r_max     # no wrap-around of the distortion
        if inside.mean() >= min_inside:
            poses.append(T)
    return poses
