"""Occlusion-aware colouring of depth points from a colour camera (pure functions on arrays).

The colour camera sits a few centimetres beside the IR camera, so it sees some surfaces the IR
camera sees from behind a nearer object: a point there must get *no colour*, not the colour of
the occluder. A z-buffer is rendered from the colour camera's viewpoint: every point is splatted
as a square twice the size of its depth pixel's footprint in the colour image, keeping the
nearest Z per colour pixel. Twice, because the depth data place a surface's edge only to within
one depth pixel: it may lie anywhere between the last sample on the surface and the first one
beyond, and a point behind that gap must not be coloured. A point is
coloured only when its own Z is within a tolerance of the z-buffer at its pixel; the colour is
then interpolated bilinearly.

The tolerance is ``occlusion_tol_m`` plus three times the lateral size of the point's footprint:
a surface inclined up to ~65° to the colour camera changes depth by less than that across one
splat (half-diagonal 1.4 footprints), while an occluder is farther in front than that at a real
depth edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics


@dataclass(frozen=True)
class ColourSample:
    """Colours of depth points seen by a colour camera.

    Attributes
    ----------
    colors : (N, 3) uint8 RGB; 0 where ``colored`` is False (that is *no colour*, not black)
    colored : (N,) bool, True where the colour camera sees the point
    in_view : (N,) bool, the point projects inside the colour image (in front of the camera)
    occluded : (N,) bool, in view but hidden behind a nearer surface (z-buffer)
    """

    colors: np.ndarray
    colored: np.ndarray
    in_view: np.ndarray
    occluded: np.ndarray

    @property
    def share_colored(self) -> float:
        """Share of the points that got a colour (0..1; 0 for no points)."""
        return float(self.colored.mean()) if self.colored.size else 0.0

    def summary(self) -> dict:
        """Counts for reports: points, coloured, out of view, occluded, share coloured."""
        n = int(self.colored.size)
        return {"points": n, "colored": int(self.colored.sum()), "out_of_view": int(n - self.in_view.sum()),
                "occluded": int(self.occluded.sum()), "share_colored": self.share_colored}


@numba.njit(cache=True)
def _splat_zbuffer(u, v, z, half, zbuf):  # pragma: no cover - compiled
    H, W = zbuf.shape
    for k in range(u.shape[0]):
        h = half[k]
        u0 = max(0, int(np.floor(u[k] - h + 0.5)))
        u1 = min(W - 1, int(np.floor(u[k] + h + 0.5)))
        v0 = max(0, int(np.floor(v[k] - h + 0.5)))
        v1 = min(H - 1, int(np.floor(v[k] + h + 0.5)))
        zk = z[k]
        for vv in range(v0, v1 + 1):
            for uu in range(u0, u1 + 1):
                if zk < zbuf[vv, uu]:
                    zbuf[vv, uu] = zk


def colour_zbuffer(uv: np.ndarray, z: np.ndarray, footprint_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Z-buffer of splatted points in the colour image.

    Parameters
    ----------
    uv : (N, 2) float pixel positions (u, v) in the colour image
    z : (N,) float depth Z in the colour camera frame [m]
    footprint_px : (N,) float, half side of each point's square splat [colour px]
    shape : (H, W) of the colour image

    Returns
    -------
    (H, W) float64 nearest Z [m] per colour pixel, inf where no point lands.
    """
    zbuf = np.full(shape, np.inf)
    half = np.maximum(np.asarray(footprint_px, np.float64), 0.5)
    _splat_zbuffer(np.ascontiguousarray(uv[:, 0], np.float64), np.ascontiguousarray(uv[:, 1], np.float64),
                   np.ascontiguousarray(z, np.float64), np.ascontiguousarray(half), zbuf)
    return zbuf


def bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples of an (H, W, C) image at float pixels (u, v) (N,) inside it -> (N, C) float64."""
    H, W = image.shape[:2]
    u = np.clip(u, 0, W - 1)
    v = np.clip(v, 0, H - 1)
    u0 = np.minimum(np.floor(u).astype(np.int64), W - 2)
    v0 = np.minimum(np.floor(v).astype(np.int64), H - 2)
    a = (u - u0)[:, None]
    b = (v - v0)[:, None]
    im = image.astype(np.float64) if image.dtype != np.float64 else image
    return ((1 - a) * (1 - b) * im[v0, u0] + a * (1 - b) * im[v0, u0 + 1]
            + (1 - a) * b * im[v0 + 1, u0] + a * b * im[v0 + 1, u0 + 1])


def colour_points(points: np.ndarray, color_image: np.ndarray, color_intr: CameraIntrinsics,
                  depth_to_color: Extrinsics, depth_focal_px: float | None = None,
                  occlusion_tol_m: float = 0.005) -> ColourSample:
    """Colour depth points from a colour image, deciding visibility with a colour-camera z-buffer.

    Parameters
    ----------
    points : (N, 3) float [m] in the depth (IR) camera frame
    color_image : (Hc, Wc, 3) uint8 RGB
    color_intr : CameraIntrinsics of the colour camera (Hc, Wc), any lens model
    depth_to_color : Extrinsics, depth camera -> colour camera [m]
    depth_focal_px : focal length of the depth camera [px]; sets each point's footprint
        ``Z_depth / f_depth`` [m]. Default: a 2-colour-pixel footprint.
    occlusion_tol_m : base depth tolerance of the visibility test [m]

    Returns
    -------
    ColourSample
    """
    img = np.asarray(color_image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"color image: expected (H, W, 3) RGB, found shape {img.shape}")
    if img.shape[:2] != color_intr.shape:
        raise InputError(f"color image {img.shape[1]}x{img.shape[0]} does not match colour intrinsics "
                         f"{color_intr.width}x{color_intr.height}")
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = len(p)
    pc = depth_to_color.apply(p)
    with np.errstate(invalid="ignore"):
        uv = color_intr.project(pc)
    H, W = color_intr.shape
    in_view = (pc[:, 2] > 0) & np.isfinite(uv).all(axis=1)
    in_view &= (uv[:, 0] > -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < H - 0.5)
    fc = 0.5 * (color_intr.fx + color_intr.fy)
    idx = np.flatnonzero(in_view)
    zc = pc[idx, 2]
    if depth_focal_px is None:
        foot = np.full(idx.size, 2.0)
    else:
        foot = fc * p[idx, 2] / (float(depth_focal_px) * zc)
    zbuf = colour_zbuffer(uv[idx], zc, foot, (H, W))
    ui = np.clip(np.rint(uv[idx, 0]).astype(np.int64), 0, W - 1)
    vi = np.clip(np.rint(uv[idx, 1]).astype(np.int64), 0, H - 1)
    tol = occlusion_tol_m + 3.0 * foot * zc / fc
    visible = zc <= zbuf[vi, ui] + tol
    colored = np.zeros(n, bool)
    colored[idx[visible]] = True
    occluded = np.zeros(n, bool)
    occluded[idx[~visible]] = True
    colors = np.zeros((n, 3), np.uint8)
    sel = idx[visible]
    if sel.size:
        colors[sel] = np.clip(np.rint(bilinear(img, uv[sel, 0], uv[sel, 1])), 0, 255).astype(np.uint8)
    return ColourSample(colors, colored, in_view, occluded)
