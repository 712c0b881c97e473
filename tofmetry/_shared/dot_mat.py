"""A printed dot mat under the object: the study's flat targets, as a pattern the IR amplitude shows.

The study placed flat targets on the ground around its object to register the views (§5, Fig. 10a).
A plain object that the geometry cannot pin (a vase of revolution, a smooth dome, a thin plaque)
gives the registration nothing else to hold on to; a sheet printed with dots and laid under it does.
:class:`DotMat` is such a sheet: a rectangle (A1 paper by default, 0.594 x 0.841 m) printed with
dark dots of random radius on a light ground, lying on the ground plane z = 0 centred under the
object (its long side turned by ``yaw_deg``). Its albedos are those of matt paper in the near IR
(toner 0.12, paper 0.8); outside it the ground keeps its own albedo. A ToF camera reads the dots
a little farther than the paper around them (amplitude-dependent range error): that comes from the
virtual sensor's error model, as it would from a real one.

:func:`dot_mat_image` is the sheet as an image to print; :func:`dot_mask` looks the pattern up at
points of the ground (the virtual sensor's texture, :func:`tofmetry.simulate.mat.dot_mat_texture`);
:meth:`DotMat.dots` gives the layout that :mod:`tofmetry.reconstruct` locates each view on.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np
from scipy.spatial import cKDTree

from tofmetry.errors import InputError

__all__ = ["A1_M", "DotMat", "dot_mask", "dot_mat_image"]

#: A1 paper [m]
A1_M = (0.594, 0.841)


@dataclass(frozen=True)
class DotMat:
    """A printed dot mat (module docstring).

    Attributes
    ----------
    seed : the dot layout's seed
    size_m : (width, length) of the sheet [m]
    dot_radius_m : (min, max) dot radius [m]; at 1 m a Kinect v2 pixel spans about 2.7 mm
    cover : share of the sheet the dots cover (about; overlapping dots cover less)
    yaw_deg : the sheet's long side turned about z from world y [deg]
    dark, light : near-IR albedo of the toner and of the paper
    """

    seed: int = 0
    size_m: tuple = A1_M
    dot_radius_m: tuple = (0.008, 0.025)
    cover: float = 0.35
    yaw_deg: float = 0.0
    dark: float = 0.12
    light: float = 0.8

    def __post_init__(self):
        w, h = self.size_m
        r0, r1 = self.dot_radius_m
        if not (w > 0 and h > 0 and 0 < r0 <= r1 and 0 < self.cover < 1 and 0 <= self.dark < self.light <= 1):
            raise InputError(f"DotMat: expected size_m > 0, 0 < dot radii min <= max, 0 < cover < 1 and "
                             f"0 <= dark < light <= 1, found {self}")

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict, source: str = "mat") -> "DotMat":
        """The mat a :meth:`to_dict` describes (``source`` names it in errors)."""
        if not isinstance(d, dict):
            raise InputError(f"{source}: expected a JSON object describing a dot mat, found {type(d).__name__}")
        known = set(cls.__dataclass_fields__)
        extra = sorted(set(d) - known)
        if extra:
            raise InputError(f"{source}: unknown dot-mat field(s) {extra}; expected some of {sorted(known)}")
        try:
            kw = {k: (tuple(float(x) for x in v) if k in ("size_m", "dot_radius_m") else v) for k, v in d.items()}
            return cls(**kw)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{source}: not a dot mat ({exc})") from None

    def dots(self) -> tuple[np.ndarray, np.ndarray]:
        """Dot centres (K, 2) in the sheet's frame [m] (origin at its centre) and radii (K,) [m]."""
        rng = np.random.default_rng(np.random.SeedSequence([int(self.seed), 0xD07]))
        w, h = self.size_m
        r0, r1 = self.dot_radius_m
        mean_area = np.pi * (r0 * r0 + r0 * r1 + r1 * r1) / 3  # E[pi r^2], r ~ U(r0, r1)
        k = max(1, int(round(self.cover * w * h / mean_area)))
        c = rng.uniform([-w / 2, -h / 2], [w / 2, h / 2], size=(k, 2))
        return c, rng.uniform(r0, r1, size=k)

    def overlapping(self) -> np.ndarray:
        """(K,) bool, the printed dots (:meth:`dots`) whose disc meets another's: printed over each
        other they read as one blob whose centre lies between theirs: 2.9 mm RMS from either on a
        family plaque's scan (session 50), where its dots printed apart read 0.3-0.8 mm."""
        c, r = self.dots()
        out = np.zeros(len(c), bool)
        i, j = cKDTree(c).query_pairs(2.0 * float(np.max(r)), output_type="ndarray").T
        meet = np.linalg.norm(c[i] - c[j], axis=1) < r[i] + r[j]
        out[i[meet]] = out[j[meet]] = True
        return out


def _sheet_coords(mat: DotMat, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.radians(mat.yaw_deg)
    c, s = np.cos(a), np.sin(a)
    return c * x + s * y, -s * x + c * y


@lru_cache(maxsize=4)
def _raster(mat: DotMat, pixel_m: float = 0.0005) -> np.ndarray:
    """The sheet's dots on a grid of ``pixel_m`` cells (rows along v from -h/2, columns along u from -w/2)."""
    w, h = mat.size_m
    nu, nv = int(np.ceil(w / pixel_m)), int(np.ceil(h / pixel_m))
    img = np.zeros((nv, nu), bool)
    centres, radii = mat.dots()
    for (cu, cv), r in zip(centres, radii):
        j0, j1 = max(0, int((cu - r + w / 2) / pixel_m)), min(nu, int((cu + r + w / 2) / pixel_m) + 1)
        i0, i1 = max(0, int((cv - r + h / 2) / pixel_m)), min(nv, int((cv + r + h / 2) / pixel_m) + 1)
        if j1 <= j0 or i1 <= i0:
            continue
        uu = (np.arange(j0, j1) + 0.5) * pixel_m - w / 2
        vv = (np.arange(i0, i1) + 0.5) * pixel_m - h / 2
        img[i0:i1, j0:j1] |= (uu[None, :] - cu) ** 2 + (vv[:, None] - cv) ** 2 <= r * r
    return img


def dot_mask(mat: DotMat, x: np.ndarray, y: np.ndarray, pixel_m: float = 0.0005) -> tuple[np.ndarray, np.ndarray]:
    """Which ground points (x, y) [m] (world, mat centred at the origin) lie on the sheet, and which
    on a dot (looked up on a grid of ``pixel_m`` cells).

    Returns (on_sheet (N,) bool, on_dot (N,) bool)."""
    u, v = _sheet_coords(mat, np.asarray(x, np.float64), np.asarray(y, np.float64))
    w, h = mat.size_m
    on = (np.abs(u) < w / 2) & (np.abs(v) < h / 2)
    img = _raster(mat, pixel_m)
    j = np.clip(((u + w / 2) / pixel_m).astype(np.int64), 0, img.shape[1] - 1)
    i = np.clip(((v + h / 2) / pixel_m).astype(np.int64), 0, img.shape[0] - 1)
    return on, on & img[i, j]


def dot_mat_image(mat: DotMat, dpi: float = 150.0) -> np.ndarray:
    """The sheet as a (H, W) uint8 image to print at ``dpi`` (0 = toner, 255 = paper; rows along its
    length from +v down, columns along its width from -u)."""
    if not dpi > 0:
        raise InputError(f"dot_mat_image: dpi must be > 0, found {dpi}")
    img = _raster(mat, 0.0254 / dpi)
    return np.where(img[::-1], 0, 255).astype(np.uint8)
