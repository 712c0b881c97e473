"""The virtual sensor's colour camera: intrinsics, extrinsics to the IR camera, exposure, textured scene.

A colour image is ray cast from the colour camera's pose (``ir_pose @ inverse(ir_to_color)``,
camera-to-world) through its own ray table (any lens model), so it sees the scene from its own
viewpoint: a surface hidden from it behind a nearer object is simply not in the image. Surfaces
are coloured by a :data:`ColourTexture` of the world point, its scene label and its albedo; the
image is ``clip(255 * exposure * rgb + noise)``, ``rgb`` averaged over the pixel's area on edges
(adaptive supersampling, :func:`render_colour`), so board edges are anti-aliased as a sensor's
pixels integrate them.

:func:`true_point_colours` gives the truth for a colourised cloud: for points in the IR frame,
whether the colour camera sees each one (its ray from the colour camera's centre hits the scene
at the point, not nearer) and the noise-free colour there.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics
from tofmetry.sensor.profiles import KINECT_V2
from tofmetry.simulate.surfaces import PlaneSurface, Scene

#: colour(points_world (N, 3) [m], label (N,) int, albedo (N,)) -> (N, 3) float RGB in 0..1
ColourTexture = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]

_HUES = np.array([[0.9, 0.9, 0.9], [0.95, 0.35, 0.25], [0.25, 0.75, 0.35], [0.3, 0.45, 0.95],
                  [0.95, 0.85, 0.3], [0.7, 0.35, 0.85], [0.3, 0.85, 0.85]])


def default_texture(points: np.ndarray, label: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """A hue per label times the albedo, modulated by a smooth 10 cm world-space pattern.

    The pattern varies slowly against the pixel footprints (2-6 mm at 1-2 m), so colour errors
    of a colourised cloud come from registration and visibility, not from aliasing.
    """
    hue = _HUES[np.mod(label, len(_HUES))]
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    pattern = 0.8 + 0.2 * np.sin(2 * np.pi * x / 0.1) * np.sin(2 * np.pi * (y + z) / 0.1)
    return np.clip(hue * (np.clip(albedo, 0, 1) * pattern)[:, None] * 1.2, 0.0, 1.0)


@dataclass(frozen=True)
class ColourCamera:
    """The virtual sensor's colour camera.

    Attributes
    ----------
    intrinsics : CameraIntrinsics of the colour camera (default: Kinect v2 colour, 1920x1080)
    ir_to_color : Extrinsics, IR camera -> colour camera [m]
    exposure : gain on the scene radiance (1 = the texture's values map to 0..255)
    noise_dn : standard deviation of the additive image noise [digital numbers]
    texture : :data:`ColourTexture`
    """

    intrinsics: CameraIntrinsics = KINECT_V2.color
    ir_to_color: Extrinsics = KINECT_V2.ir_to_color
    exposure: float = 1.0
    noise_dn: float = 0.0
    texture: ColourTexture = field(default=default_texture, compare=False)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.exposure) and self.exposure > 0):
            raise InputError(f"ColourCamera: exposure must be > 0, found {self.exposure}")
        if not (np.isfinite(self.noise_dn) and self.noise_dn >= 0):
            raise InputError(f"ColourCamera: noise_dn must be >= 0, found {self.noise_dn}")

    def to_dict(self) -> dict:
        """JSON-able description (for ``truth.json``); the texture by its function name."""
        return {"intrinsics": self.intrinsics.to_dict(), "ir_to_color": self.ir_to_color.to_dict(),
                "exposure": float(self.exposure), "noise_dn": float(self.noise_dn),
                "texture": getattr(self.texture, "__name__", str(self.texture))}

    @classmethod
    def from_dict(cls, d: dict, texture: ColourTexture = default_texture) -> "ColourCamera":
        """Inverse of :meth:`to_dict` (the texture is passed, not read)."""
        return cls(CameraIntrinsics.from_dict(d["intrinsics"]), Extrinsics.from_dict(d["ir_to_color"]),
                   float(d["exposure"]), float(d["noise_dn"]), texture)

    def pose(self, ir_pose: np.ndarray) -> np.ndarray:
        """(4, 4) colour camera-to-world pose from the IR camera-to-world pose."""
        return np.asarray(ir_pose, np.float64) @ self.ir_to_color.inverse().matrix


@dataclass
class ColourRendering:
    """One colour image. image : (H, W, 3) uint8 RGB; depth_m : (H, W) Z [m] in the colour frame
    (inf = nothing); labels : (H, W) int32 scene label (-1 = nothing)."""

    image: np.ndarray
    depth_m: np.ndarray
    labels: np.ndarray


def _shade(cam: ColourCamera, scene: Scene, o: np.ndarray, d: np.ndarray) -> tuple:
    h = scene.intersect(o, d)
    hit = np.isfinite(h.t)
    rgb = np.zeros((len(d), 3))
    if hit.any():
        pw = o + d[hit] * h.t[hit, None]
        rgb[hit] = cam.texture(pw, h.label[hit], h.albedo[hit])
    return h, hit, rgb


#: Supersampling of :func:`render_colour` by default: 3 x 3 sub-rays per edge pixel (an n-rooks pattern of 9
#: rays drawn per pixel): the share of the pixel beyond a straight edge to 1/18 at most along a pixel row or
#: column, 0.075 RMS over edges of every direction (errors that change from pixel to pixel along an edge).
COLOUR_SUPERSAMPLE = 3
#: A pixel is an edge pixel (supersampled) when it differs from the mean of its 8 neighbours by more than
#: this [digital numbers] in some channel, or the scene label changes in its 3 x 3 neighbourhood: so is
#: every pixel next to a step of more than 8 DN (a step across one diagonal neighbour only moves the mean
#: by 1/8 of it; such a pixel has at most 1/8 of its area beyond the step), and smooth shading (curvature
#: well under 1 DN per pixel) is not.
EDGE_DN = 1.0


def _cast_pixels(cam: ColourCamera, scene: Scene, R: np.ndarray, o: np.ndarray, xy: np.ndarray, chunk: int):
    """Colour (N, 3) in 0..1, hit parameter (N,) (inf = nothing; Z [m] for ``(x, y, 1)`` rays) and label
    (N,) of the rays through normalised image points ``xy`` (N, 2)."""
    n = len(xy)
    rgb = np.zeros((n, 3))
    depth = np.full(n, np.inf)
    labels = np.full(n, -1, np.int32)
    for k0 in range(0, n, chunk):
        k1 = min(n, k0 + chunk)
        x, y = xy[k0:k1, 0:1], xy[k0:k1, 1:2]
        dirs = x * R[:, 0] + y * R[:, 1] + R[:, 2]           # R @ (x, y, 1), element-wise (no BLAS threads)
        h, hit, c = _shade(cam, scene, o, dirs)
        rgb[k0:k1] = c
        depth[k0:k1] = np.where(hit, h.t, np.inf)
        labels[k0:k1] = np.where(hit, h.label, -1)
    return rgb, depth, labels


def _edge_pixels(dn: np.ndarray, labels: np.ndarray, threshold_dn: float = EDGE_DN) -> np.ndarray:
    """Flat indices of the pixels to supersample: a colour step or a label change next to them
    (see :data:`EDGE_DN`).

    Parameters
    ----------
    dn : (H, W, 3) float, noise-free image [digital numbers]; labels : (H, W) int, -1 = nothing
    """
    import cv2

    d = np.asarray(dn, np.float32)
    box = cv2.boxFilter(d, -1, (3, 3), normalize=False, borderType=cv2.BORDER_REPLICATE)   # 3 x 3 sums
    lap = np.abs(9.0 * d - box)                  # 8 |pixel - mean of its 8 neighbours|, per channel
    edge = np.maximum(np.maximum(lap[..., 0], lap[..., 1]), lap[..., 2]) > 8.0 * threshold_dn
    lab = np.asarray(labels, np.float32)         # scene labels are small integers: exact in float32
    k = np.ones((3, 3), np.uint8)
    edge |= cv2.dilate(lab, k, borderType=cv2.BORDER_REPLICATE) != cv2.erode(lab, k, borderType=cv2.BORDER_REPLICATE)
    return np.flatnonzero(edge)


def _sub_pixel_rays(table: np.ndarray, idx: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Normalised rays (E * S, 2) of sub-pixel positions ``offsets`` (E, S, 2) [px] of the pixels ``idx``
    (E,) (flat indices), through the local Jacobian of the ray table ``table`` (H, W, 2) (central
    differences; the lens is smooth over a pixel: second-order terms ~1e-4 px)."""
    H, W = table.shape[:2]
    u, v = idx % W, idx // W
    ul, ur = np.maximum(u - 1, 0), np.minimum(u + 1, W - 1)
    vu, vd = np.maximum(v - 1, 0), np.minimum(v + 1, H - 1)
    du_ = ((table[v, ur] - table[v, ul]) / (ur - ul)[:, None])[:, None, :]     # (E, 1, 2) per px along u
    dv_ = ((table[vd, u] - table[vu, u]) / (vd - vu)[:, None])[:, None, :]
    xy = table[v, u][:, None, :] + offsets[..., 0:1] * du_ + offsets[..., 1:2] * dv_
    return xy.reshape(-1, 2)


def render_colour(scene: Scene, cam: ColourCamera, ir_pose: np.ndarray | None = None,
                  rng: np.random.Generator | None = None, chunk: int = 1 << 18,
                  supersample: int = COLOUR_SUPERSAMPLE) -> ColourRendering:
    """Ray cast the colour image of ``scene`` for the IR camera at ``ir_pose`` (camera-to-world, m).

    One ray per pixel centre through the colour camera's ray table (its lens distortion); then
    the pixels on an edge (a colour step or a change of surface in their 3 x 3 neighbourhood,
    :data:`EDGE_DN`) are cast again with ``supersample x supersample`` sub-rays spread over the
    pixel's area (an n-rooks pattern, :func:`tofmetry.simulate.render._sub_offsets`, placed through
    the local Jacobian of the ray table) and get their mean colour:
    the pixel integrates its area as a sensor's does, so edges are anti-aliased (an edge along a
    pixel row or column is placed to ``1 / supersample**2`` of a pixel). ``supersample=1``: one ray per pixel (aliased
    edges). ``depth_m`` and ``labels`` are those of the centre ray. ``rng`` draws the image
    noise (required when ``cam.noise_dn > 0``), added to the integrated pixel.
    """
    from tofmetry.simulate.render import _sub_offsets

    if cam.noise_dn > 0 and rng is None:
        raise InputError("render_colour: noise_dn > 0 needs an rng (numpy Generator)")
    if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or supersample < 1:
        raise InputError(f"render_colour: supersample must be an integer >= 1, found {supersample!r}")
    pose = cam.pose(np.eye(4) if ir_pose is None else ir_pose)
    R, o = pose[:3, :3], pose[:3, 3]
    intr = cam.intrinsics
    H, W = intr.shape
    table = np.asarray(intr.ray_table())
    rgb, depth, labels = _cast_pixels(cam, scene, R, o, table.reshape(-1, 2), chunk)
    img = 255.0 * cam.exposure * rgb
    if supersample > 1:
        eidx = _edge_pixels(img.reshape(H, W, 3), labels.reshape(H, W))
        if eidx.size:
            S = int(supersample) ** 2
            offs = _sub_offsets(int(supersample), eidx)                       # (E, S, 2) [px]
            sub, _, _ = _cast_pixels(cam, scene, R, o, _sub_pixel_rays(table, eidx, offs), chunk)
            img[eidx] = 255.0 * cam.exposure * sub.reshape(-1, S, 3).mean(axis=1)
    if cam.noise_dn > 0:
        img = img + rng.normal(0.0, cam.noise_dn, img.shape)
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8).reshape(H, W, 3)
    return ColourRendering(img, depth.reshape(H, W), labels.reshape(H, W))


def true_point_colours(scene: Scene, cam: ColourCamera, points_ir: np.ndarray, ir_pose: np.ndarray | None = None,
                       tol_m: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Truth for colourising points of the IR frame.

    Parameters
    ----------
    points_ir : (N, 3) [m], points *on the scene's surfaces* in the IR camera frame
    tol_m : a point is visible when the colour camera's ray towards it hits no surface nearer
        than the point minus ``tol_m``

    Returns
    -------
    visible : (N,) bool, the colour camera sees the point (and it is inside its image)
    colour : (N, 3) float, noise-free 0..255 colour of the point (``exposure`` applied, clipped)
    """
    p = np.asarray(points_ir, np.float64).reshape(-1, 3)
    pc = cam.ir_to_color.apply(p)
    with np.errstate(invalid="ignore"):
        uv = cam.intrinsics.project(pc)
    H, W = cam.intrinsics.shape
    inside = (pc[:, 2] > 0) & np.isfinite(uv).all(axis=1)
    inside &= (uv[:, 0] > -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < H - 0.5)
    pose = cam.pose(np.eye(4) if ir_pose is None else ir_pose)
    R, o = pose[:3, :3], pose[:3, 3]
    dirs = (pc / np.where(pc[:, 2:3] > 0, pc[:, 2:3], 1.0)) @ R.T  # camera (x, y, 1): t is Z
    h, hit, rgb = _shade(cam, scene, o, dirs)
    visible = inside & hit & (h.t >= pc[:, 2] - tol_m)
    return visible, np.clip(255.0 * cam.exposure * rgb, 0, 255)


def occluder_scene(background_m: float = 2.0, occluder_m: float = 1.2, occluder_half_width_m: float = 0.2,
                   albedo: float = 0.8) -> Scene:
    """A wall at ``background_m`` (label 1) and, in front of it at ``occluder_m``, a square panel
    (label 2) of half width ``occluder_half_width_m`` centred on the optical axis: the colour
    camera, beside the IR camera, sees a strip of the wall the IR camera sees only from behind
    the panel's edge (``baseline * (1/occluder - 1/background) * f`` pixels wide)."""
    def uniform(label):
        def tex(s, t):
            n = s.shape[0]
            return np.full(n, albedo), np.full(n, label, np.int32), np.zeros(n, bool), np.zeros(n)
        return tex

    ex, ey = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    a = occluder_half_width_m
    wall = PlaneSurface(np.array([0.0, 0.0, background_m]), ex, ey, (-5.0, 5.0, -5.0, 5.0), uniform(1))
    panel = PlaneSurface(np.array([0.0, 0.0, occluder_m]), ex, ey, (-a, a, -a, a), uniform(2))
    return Scene("occluder", [wall, panel], {1: "wall", 2: "panel"},
                 {"type": "occluder", "background_m": background_m, "occluder_m": occluder_m,
                  "occluder_half_width_m": a})
