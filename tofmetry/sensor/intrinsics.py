"""Pinhole camera model with a Brown, rational or fisheye lens (OpenCV conventions).

Frames and conventions
----------------------
* Pixel (u, v): u to the right, v down, origin at the *centre* of the top-left pixel.
* Camera frame: x right, y down, z forward (optical axis), metres unless stated.
* Depth is Z along the optical axis (not the ray length).
* Distortion ``[k1, k2, p1, p2, k3]`` in OpenCV order, applied to normalised coordinates
  ``(x, y) = (X/Z, Y/Z)``:

  .. math::
     r^2 = x^2 + y^2,\\ \\rho = 1 + k_1 r^2 + k_2 r^4 + k_3 r^6 \\\\
     x_d = x\\rho + 2p_1xy + p_2(r^2+2x^2),\\ y_d = y\\rho + p_1(r^2+2y^2) + 2p_2xy \\\\
     u = f_x x_d + c_x,\\ v = f_y y_d + c_y

  That is the default ``brown`` model; ``model="rational"`` (8 coefficients, OpenCV's rational
  model, the Azure Kinect factory lens) and ``model="fisheye"`` (Kannala–Brandt, 4 coefficients,
  ``cv2.fisheye``) are the others: see :mod:`tofmetry.sensor.lens`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor import lens as _lens


@dataclass(frozen=True)
class CameraIntrinsics:
    """Intrinsic parameters of one camera.

    Parameters
    ----------
    width, height : int
        Image size [px].
    fx, fy : float
        Focal lengths [px].
    cx, cy : float
        Principal point [px], pixel-centre origin (OpenCV convention).
    distortion : tuple of float
        Lens coefficients in OpenCV order: Brown ``(k1, k2, p1, p2, k3)`` (default), rational
        ``(k1, k2, p1, p2, k3, k4, k5, k6)`` or fisheye ``(k1, k2, k3, k4)``.
    model : str
        Lens model: ``"brown"`` (default), ``"rational"`` or ``"fisheye"``.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))
    model: str = "brown"

    def __post_init__(self) -> None:
        dist = tuple(float(d) for d in np.asarray(self.distortion, dtype=float).ravel())
        if self.model == "brown" and len(dist) == 4:
            dist = dist + (0.0,)
        if self.model == "rational" and len(dist) == 5:
            dist = dist + (0.0, 0.0, 0.0)
        object.__setattr__(self, "distortion", dist)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))
        self.validate()

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise :class:`InputError` naming the first invalid field."""
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"intrinsics: width/height must be positive, found {self.width}x{self.height}")
        _lens.check_model(self.model, self.distortion)
        vals = {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}
        for k, v in vals.items():
            if not math.isfinite(v):
                raise InputError(f"intrinsics: {k} must be finite, found {v}")
        for k in ("fx", "fy"):
            if vals[k] <= 0:
                raise InputError(f"intrinsics: {k} must be > 0 pixels, found {vals[k]}")
        if not (-0.5 * self.width <= self.cx <= 1.5 * self.width):
            raise InputError(f"intrinsics: cx={self.cx} is far outside the image width {self.width}")
        if not (-0.5 * self.height <= self.cy <= 1.5 * self.height):
            raise InputError(f"intrinsics: cy={self.cy} is far outside the image height {self.height}")
        if not all(math.isfinite(d) for d in self.distortion):
            raise InputError(f"intrinsics: distortion must be finite, found {self.distortion}")

    # ------------------------------------------------------------------ basics
    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``: the array shape of an image of this camera."""
        return (self.height, self.width)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> np.ndarray:
        """(n,) float64 lens coefficients in OpenCV order (5 Brown, 8 rational, 4 fisheye)."""
        return np.asarray(self.distortion, dtype=np.float64)

    @property
    def has_distortion(self) -> bool:
        return any(d != 0.0 for d in self.distortion)

    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view [deg] of the undistorted pinhole."""
        return (
            math.degrees(2 * math.atan(self.width / (2 * self.fx))),
            math.degrees(2 * math.atan(self.height / (2 * self.fy))),
        )

    def with_(self, **changes) -> "CameraIntrinsics":
        """Copy with some fields replaced."""
        d = self.to_dict()
        d.update(changes)
        return CameraIntrinsics.from_dict(d)

    def scaled(self, width: int, height: int) -> "CameraIntrinsics":
        """Intrinsics for the same lens resampled to ``width x height``."""
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(
            width, height, self.fx * sx, self.fy * sy,
            (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, self.distortion, self.model,
        )

    def to_dict(self) -> dict:
        """Contract form: ``{"width","height","fx","fy","cx","cy","distortion":[k1,k2,p1,p2,k3]}``,
        plus ``"model"`` for a lens other than Brown (the distortion then has its model's length)."""
        d = {
            "width": self.width, "height": self.height,
            "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
            "distortion": list(self.distortion),
        }
        if self.model != "brown":
            d["model"] = self.model
        return d

    @classmethod
    def from_dict(cls, d: dict, *, source: str = "intrinsics") -> "CameraIntrinsics":
        """Build from the contract dict; errors name ``source`` and the missing key."""
        if not isinstance(d, dict):
            raise InputError(f"{source}: expected a JSON object with width, height, fx, fy, cx, cy, distortion")
        missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy") if k not in d]
        if missing:
            raise InputError(f"{source}: missing key(s) {missing}; expected width, height, fx, fy, cx, cy, distortion")
        model = d.get("model", "brown")
        if model not in _lens.MODELS:
            raise InputError(f"{source}: unknown lens 'model' {model!r}; expected one of {sorted(_lens.MODELS)}")
        dist = d.get("distortion", [0.0] * _lens.MODELS[model])
        sizes = {"brown": (4, 5), "rational": (5, 8), "fisheye": (4,)}[model]
        if not isinstance(dist, (list, tuple)) or len(dist) not in sizes:
            raise InputError(f"{source}: 'distortion' of the {model} model must be a list "
                             f"[{','.join(_lens.COEFFICIENT_NAMES[model])}], found {dist!r}")
        try:
            return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]),
                       float(d["cx"]), float(d["cy"]), tuple(float(x) for x in dist), model)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise InputError(f"{source}: {exc}") from None
            raise InputError(f"{source}: non-numeric value ({exc})") from None

    # ------------------------------------------------------------------ model
    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Apply the lens distortion to normalised coordinates.

        Parameters
        ----------
        xy : (N, 2) float64
            Undistorted normalised coordinates ``(X/Z, Y/Z)``.

        Returns
        -------
        (N, 2) float64 distorted normalised coordinates.
        """
        return _lens.distort(np.asarray(xy, dtype=np.float64), self.model, self.dist_array)

    def undistort_normalized(self, xy_d: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Invert :meth:`distort_normalized` by Newton iteration (to ~1e-12; NaN where it fails).

        Parameters
        ----------
        xy_d : (N, 2) float64
            Distorted normalised coordinates.

        Returns
        -------
        (N, 2) float64 undistorted normalised coordinates.
        """
        return _lens.undistort(np.asarray(xy_d, dtype=np.float64), self.model, self.dist_array, max(iterations, 30))

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project camera-frame points to pixels, with distortion.

        Parameters
        ----------
        points : (N, 3) float
            Points in the camera frame (any length unit); Z must be > 0.

        Returns
        -------
        (N, 2) float64 pixel coordinates (u, v); NaN where Z <= 0.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[:, :2] / z[:, None]
        xy[z <= 0] = np.nan
        xd = _lens.distort(xy, self.model, self.dist_array)
        return np.column_stack([self.fx * xd[:, 0] + self.cx, self.fy * xd[:, 1] + self.cy])

    def pixel_to_normalized(self, uv: np.ndarray, undistort: bool = True) -> np.ndarray:
        """Pixels (N, 2) -> undistorted normalised coordinates (N, 2)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        xy_d = np.column_stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy])
        if undistort and (self.has_distortion or self.model == "fisheye"):
            return _lens.undistort(xy_d, self.model, self.dist_array)
        return xy_d

    def backproject(self, uv: np.ndarray, depth: np.ndarray, undistort: bool = True) -> np.ndarray:
        """Back-project pixels with Z depth to camera-frame points.

        Parameters
        ----------
        uv : (N, 2) float
            Pixel coordinates.
        depth : (N,) float
            Z along the optical axis (output unit = this unit).
        undistort : bool
            Remove lens distortion (default). ``False`` is the plain pinhole.

        Returns
        -------
        (N, 3) float64 points.
        """
        xy = self.pixel_to_normalized(uv, undistort)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        return np.column_stack([xy * z[:, None], z])

    def ray_table(self, undistort: bool = True) -> np.ndarray:
        """Per-pixel normalised ray ``(x, y)`` such that the point is ``Z * (x, y, 1)``.

        Cached per parameter set. Returns
        -------
        (H, W, 2) float64, read-only.
        """
        return _ray_table_cached(self._key(), bool(undistort))

    def _key(self) -> tuple:
        return (self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.distortion, self.model)


@lru_cache(maxsize=16)
def _ray_table_cached(key: tuple, undistort: bool) -> np.ndarray:
    w, h, fx, fy, cx, cy, dist, model = key
    intr = CameraIntrinsics(w, h, fx, fy, cx, cy, dist, model)
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xy = intr.pixel_to_normalized(np.column_stack([u.ravel(), v.ravel()]), undistort=undistort)
    table = xy.reshape(h, w, 2)
    table.setflags(write=False)
    return table
