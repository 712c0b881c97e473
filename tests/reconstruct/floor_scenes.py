"""A floor seen by a pitched camera, a box face standing in the image's middle: the views the support curve's
tests read (:mod:`tofmetry.reconstruct._support_curve`). Camera frame: x right, y down, z forward."""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct._preprocess import ViewData
from tofmetry.reconstruct._segment import Segmentation
from tofmetry.sensor import CameraIntrinsics

INTR = CameraIntrinsics(512, 424, 365.0, 365.0, 256.0, 212.0)
#: six cameras over a floor: height [m], pitch down [deg]
POSES = [(0.30, 20), (0.40, 28), (0.50, 35), (0.35, 45), (0.60, 60), (0.45, 25)]


def wiggle_mm(z):
    """A range wiggle [mm] at measured depths ``z`` [mm]: periods 470 and 900 mm, up to 3.5 mm."""
    return 2.5 * np.sin(2 * np.pi * z / 470.0 + 0.7) + 1.0 * np.sin(2 * np.pi * z / 900.0 + 2.0)


def floor_and_box(h_m: float, pitch_deg: float, box_x: float, box_y: tuple[float, float], box_z_m: float,
                  near_m: float, far_m: float = 2.0, error_mm=None, noise_mm: float = 0.0, rng=None,
                  name: str = "00") -> tuple[ViewData, Segmentation]:
    """A floor ``h_m`` below a camera pitched down ``pitch_deg``, seen within ``near_m``-``far_m`` [m], and a
    fronto-parallel box face at ``box_z_m`` [m] on the rays with ``|x| < box_x`` and ``box_y[0] < y < box_y[1]``
    (normalised). ``error_mm(z_mm, xy)``: a depth error [mm] added to every pixel, and ``noise_mm`` of noise drawn
    from ``rng``. The segmentation: the box the object, the floor's true plane the support."""
    H, W = INTR.shape
    rays = INTR.ray_table(True).reshape(-1, 2)
    t = np.radians(pitch_deg)
    up = np.array([0.0, -np.cos(t), -np.sin(t)])  # world up in the camera frame
    den = -(np.c_[rays, np.ones(len(rays))] @ up)
    z = np.where(den > 1e-6, h_m / np.maximum(den, 1e-6), np.inf)
    floor = (z > near_m) & (z < far_m)
    box = (np.abs(rays[:, 0]) < box_x) & (rays[:, 1] > box_y[0]) & (rays[:, 1] < box_y[1])
    z = np.where(box, box_z_m, z)
    index = np.nonzero(floor | box)[0]
    zm = z[index] * 1e3
    if error_mm is not None:
        zm = zm + error_mm(zm, rays[index])
    if noise_mm:
        zm = zm + rng.normal(0.0, noise_mm, len(index))
    pts = np.c_[rays[index], np.ones(len(index))] * zm[:, None] * 1e-3
    depth = np.zeros(H * W)
    depth[index] = zm
    n = len(index)
    view = ViewData(name, depth.reshape(H, W), pts, index, np.tile(-up, (n, 1)), np.ones(n), None, {})
    obj = box[index]
    return view, Segmentation(obj, ~obj, None, np.r_[up, h_m], 0.9)
