"""A family of random Kinect-v2-class sensors, drawn by seed, for testing methods on families.

A calibration method built beside one simulated sensor can fit that sensor's very formulas.
:func:`random_sensor` draws a whole sensor (lens + every systematic and random error) from
distributions at least as wide as the differences between real devices, so a method can be
tested on many sensors it was not built beside. :func:`default_sensor` is the simulator's
Kinect v2 (``ErrorModel()`` and the typical lens). ``paper`` below is the study
``shared/reference/kinect-v2-assessment-paper.txt``; U(a, b) is uniform, logU log-uniform.

Lens (:mod:`tofmetry.simulate.lens`): 512 x 424, fx = 365 (1 + U(-5 %, 5 %)), fy = fx (1 + U(-1 %, 1 %)),
principal point = image centre + U(-15, 15) px per axis, radial profile drawn (k1 ~ U(0.05, 0.16),
``f(0.6^2)`` ~ U(-0.008, 0.014), ``f(0.9^2)`` ~ U(-0.14, 0.16), k2, k3 solved: barrel or pincushion
corners, spanning the 9 real iai_kinect2 calibrations and beyond), p1, p2 ~ U(-2e-3, 2e-3); kept only
if the Brown map is monotonic and invertible to 5 % beyond the image corners.

Range error (:mod:`tofmetry.simulate.range_error`; paper §4.2.2, Fig. 7a: -15 .. +7 mm at the centre
over 0.8-4.5 m, strong past 4.5 m):

* variable: radial range with probability 0.75 (what a continuous-wave ToF measures), Z 0.25;
  applied along the ray (``W / rho`` in Z) or directly in Z, 0.5 each;
* trend about 0.8 m: offset U(-15, 10) mm, slope U(-3, 3) mm/m, quadratic U(-1, 1) mm/m^2,
  scale (gain) error U(-0.5 %, 0.5 %) of the range;
* 1, 2 or 3 periodic components (probabilities 0.4, 0.4, 0.2), periods logU(0.35, 3.0) m (the
  4-phase aliasing of the modulation's odd harmonics gives c/(8 f): 0.47 m at 80 MHz, 0.31 m at
  120 MHz; the half wavelengths are 1.87 and 1.25 m), fundamental amplitude logU(1, 6) mm for the
  first component and logU(0.3, 4) mm for the others, 1-3 harmonics (kept while the harmonic's
  period is >= 0.2 m) of amplitude U(0.1, 0.6) x the fundamental, phases U(0, 2 pi);
* steep growth with probability 0.5: past U(4.0, 5.0) m, U(10, 40) mm per m^p, p ~ U(1.2, 2.0).

Per-pixel deformation (:mod:`tofmetry.simulate.deformation`; paper §4.2.3, Fig. 8 and 9b: negative
central disc, "about 1 centimeter" and "more than 1 cm on the corners", growing with range). The
components are drawn in relative units (the bowl's corner-to-centre span is 1), then the whole surface
is scaled so that its largest corner deviation from the image centre at 1 m (10 x 10 patches) is
T ~ U(3, 15) mm; a draw whose interior deviates more than 1.6 T from the centre is redrawn:

* exponential bowl with probability 0.8: corners of either sign (positive 0.7), central value
  -U(0.05, 0.3) x the span, sharpness U(0.8, 3.5), radius U(0.85, 1.15), aspect U(0.9, 1.2),
  centre shift U(-0.05, 0.05), skew U(-0.1, 0.1);
* tilt (probability 0.5): ``t_x x + t_y y`` reaching U(0.1, 0.4) at the image edge, direction U(0, 2 pi);
* 1-3 Fourier modes (probability 0.5): ``cos(pi (k_x x / x_c + k_y y / y_c) + phase)``,
  k_x in {0, 1, 2}, k_y in {0, +-1, +-2} (not both 0), amplitude U(0.05, 0.25), phase U(0, 2 pi);
* 1-2 Gaussian bumps (probability 0.4): centre uniform inside the image, sigma U(0.1, 0.35)
  (normalised units), amplitude +-U(0.1, 0.4);
* corner fall-off (probability 0.5, always when nothing else was drawn): zero up to U(0.75, 0.92) of
  the corner radius, power U(1.5, 4), amplitude U(0.3, 1.0) with the bowl's sign (probability 0.75),
  own range growth ``(1 - g) + g Z^n``: n = 1, g ~ U(0, 0.6) or n = 2, g ~ U(0.05, 0.4) (0.5 each);
* range dependence: linear ``(1 - g) + g Z`` (probability 0.4, g ~ U(-0.2, 0.8)), quadratic
  ``(1 - g) + g Z^2`` (0.3, g ~ U(0.05, 0.35)), constant (0.15), decay ``exp(-(Z - 1) / l)``
  (0.15, l ~ U(1.5, 6) m).

Amplitude bias (paper §3.3.1: black, 1/6 of the white amplitude, reads up to 12 mm long):
``k ln(A_white / A)`` with k ~ U(4, 9) mm per ln (the study: 6.7), plus ``k_abs ln(12000 / A)`` in the
absolute amplitude with k_abs ~ U(0, 3) mm per ln (white walls show it: it grows with range and toward
the corners). Amplitude model: white at 1 m U(9000, 15000), vignetting ``cos^p`` with p ~ U(2, 4).

Noise: sigma0 (white, 1 m, centre) ~ U(0.6, 2.0) mm (paper §3.2, Fig. 7b: ~1.3 mm), near-range
gain U(4, 10). Mounting offset (tripod screw to optical centre) U(5, 40) mm (paper §4.2.2: ~2 cm).
Warm-up (paper §3.2: ~5 mm over 30 min, fan at 20 min, then ~1 mm): drift U(2, 8) mm, time constant
U(480, 1000) s, fan start U(900, 1500) s, residual wander U(0.1, 0.5) mm over U(600, 1500) s.

Walls and tripods are never exactly frontal (paper §3.2: "the sensor is not placed perfectly parallel
to the wall"; §4.2.1 needed prisms surveyed by tachymetry to ensure it): :func:`station_tilts` draws
one small tilt per wall station.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics
from tofmetry.sensor.profiles import KINECT_V2
from tofmetry.simulate import deformation as D
from tofmetry.simulate import range_error as RE
from tofmetry.simulate.errors import ErrorModel
from tofmetry.simulate.lens import corner_rays, lens_check, random_intrinsics

#: Kinds of sensors the CLI can draw.
SENSOR_KINDS = ("kinect_v2", "random")
_PATCH = 10  # corner / centre patch size [px] of the deformation magnitudes


@dataclass(frozen=True)
class SensorDraw:
    """One sensor of the family: its lens and its error model.

    Attributes
    ----------
    seed : int or None, the seed of :func:`random_sensor` (None for :func:`default_sensor`)
    kind : str, ``"kinect_v2"`` (the default sensor) or ``"random"``
    intrinsics : CameraIntrinsics, the true lens
    errors : ErrorModel, the true errors
    """

    seed: int | None
    kind: str
    intrinsics: CameraIntrinsics
    errors: ErrorModel

    def with_errors(self, errors: ErrorModel) -> "SensorDraw":
        """Copy with another error model (e.g. terms switched off)."""
        return dataclasses.replace(self, errors=errors)

    def camera(self, seed: int = 0, supersample: int = 3):
        """A :class:`~tofmetry.simulate.camera.VirtualKinect` of this sensor (``seed``: noise stream)."""
        from tofmetry.simulate.camera import VirtualKinect

        return VirtualKinect(self.errors, seed=seed, intrinsics=self.intrinsics, supersample=supersample)

    def describe(self) -> dict:
        """JSON-able summary of the draw: lens, range error, deformation, amplitude, noise, offsets."""
        return describe(self)

    def to_dict(self) -> dict:
        """JSON-able record of the whole draw (``from_dict`` inverts it; ``describe`` is informative)."""
        return {"kind": self.kind, "seed": self.seed, "intrinsics": self.intrinsics.to_dict(),
                "error_model": self.errors.to_dict(), "describe": self.describe()}

    @classmethod
    def from_dict(cls, d: dict) -> "SensorDraw":
        for k in ("kind", "intrinsics", "error_model"):
            if k not in d:
                raise InputError(f"SensorDraw.from_dict: missing key {k!r}; expected kind, seed, intrinsics, error_model")
        return cls(d.get("seed"), d["kind"], CameraIntrinsics.from_dict(d["intrinsics"]),
                   ErrorModel.from_dict(d["error_model"]))


def default_sensor() -> SensorDraw:
    """The simulator's Kinect v2: typical lens (``KINECT_V2.depth``) and ``ErrorModel()``."""
    return SensorDraw(None, "kinect_v2", KINECT_V2.depth, ErrorModel())


def sensor_by_kind(kind: str, seed: int = 0) -> SensorDraw:
    """``"kinect_v2"`` -> :func:`default_sensor`; ``"random"`` -> :func:`random_sensor` (``seed``)."""
    if kind == "kinect_v2":
        return default_sensor()
    if kind == "random":
        return random_sensor(seed)
    raise InputError(f"sensor: expected one of {list(SENSOR_KINDS)}, found {kind!r}")


def _rng(seed: int, stream: int) -> np.random.Generator:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"random_sensor: seed must be a non-negative integer, found {seed!r}")
    return np.random.default_rng(np.random.SeedSequence([int(seed), 0x5E45, stream]))


def random_sensor(seed: int) -> SensorDraw:
    """Draw a Kinect-v2-class sensor (module docstring: every distribution). Deterministic per ``seed``.

    Parameters
    ----------
    seed : int >= 0

    Returns
    -------
    SensorDraw with ``kind="random"``.
    """
    rng = _rng(seed, 1)
    intr = random_intrinsics(rng)
    rays = corner_rays(intr)
    corner_xy = (float(np.abs(rays[:, 0]).mean()), float(np.abs(rays[:, 1]).mean()))
    params = {"deform_corner_xy": corner_xy}
    params |= _draw_range_error(rng)
    params |= _draw_deformation(rng, intr, corner_xy)
    params |= {
        "amp_bias_mm_per_ln": rng.uniform(4.0, 9.0), "amp_bias_abs_mm_per_ln": rng.uniform(0.0, 3.0),
        "amp_white_1m": rng.uniform(9000.0, 15000.0), "vignetting_power": rng.uniform(2.0, 4.0),
        "noise_sigma_mm": rng.uniform(0.6, 2.0), "noise_near_gain": rng.uniform(4.0, 10.0),
        "mounting_offset_mm": rng.uniform(5.0, 40.0),
        "warmup_mm": rng.uniform(2.0, 8.0), "warmup_tau_s": rng.uniform(480.0, 1000.0),
        "warmup_fan_s": rng.uniform(900.0, 1500.0), "warmup_wander_mm": rng.uniform(0.1, 0.5),
        "warmup_wander_period_s": rng.uniform(600.0, 1500.0),
    }
    params = {k: (float(v) if isinstance(v, np.floating) else v) for k, v in params.items()}
    return SensorDraw(int(seed), "random", intr, ErrorModel(**params))


def _draw_range_error(rng: np.random.Generator) -> dict:
    p = {"range_variable": "radial" if rng.random() < 0.75 else "z",
         "range_apply": "ray" if rng.random() < 0.5 else "z",
         "wiggle_offset_mm": rng.uniform(-15.0, 10.0), "wiggle_slope_mm_per_m": rng.uniform(-3.0, 3.0),
         "wiggle_quad_mm_per_m2": rng.uniform(-1.0, 1.0), "wiggle_gain": rng.uniform(-0.005, 0.005)}
    n_comp = int(rng.choice([1, 2, 3], p=[0.4, 0.4, 0.2]))
    periods, counts, amps, phases = [], [], [], []
    for c in range(n_comp):
        period = float(math.exp(rng.uniform(math.log(0.35), math.log(3.0))))
        a1 = math.exp(rng.uniform(math.log(1.0), math.log(6.0)) if c == 0 else rng.uniform(math.log(0.3), math.log(4.0)))
        n_h = min(int(rng.integers(1, 4)), max(1, int(period / 0.2)))
        periods.append(period)
        counts.append(n_h)
        amps += [a1] + [a1 * rng.uniform(0.1, 0.6) for _ in range(n_h - 1)]
        phases += [rng.uniform(0.0, 2 * math.pi) for _ in range(n_h)]
    p |= {"wiggle_periods_m": tuple(periods), "wiggle_harmonics": tuple(counts),
          "wiggle_amps_mm": tuple(float(a) for a in amps), "wiggle_phases": tuple(float(v) for v in phases)}
    if rng.random() < 0.5:
        p |= {"wiggle_steep_start_m": rng.uniform(4.0, 5.0), "wiggle_steep_mm": rng.uniform(10.0, 40.0),
              "wiggle_steep_power": rng.uniform(1.2, 2.0)}
    else:
        p |= {"wiggle_steep_mm": 0.0}
    return p


@lru_cache(maxsize=64)
def _probe_rays(key: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Rays of the 4 corner and the centre 10 x 10 patches (5, 100, 2), and of every 4th pixel (N, 2)."""
    intr = CameraIntrinsics(*key)
    n, H, W = _PATCH, intr.height, intr.width
    u0s = [(0, 0), (W - n, 0), (0, H - n), (W - n, H - n), (W // 2 - n // 2, H // 2 - n // 2)]
    du, dv = np.meshgrid(np.arange(n), np.arange(n))
    patches = np.stack([intr.pixel_to_normalized(np.column_stack([(u + du).ravel(), (v + dv).ravel()]))
                        for u, v in u0s])
    gu, gv = np.meshgrid(np.append(np.arange(0, W, 4), W - 1), np.append(np.arange(0, H, 4), H - 1))
    grid = intr.pixel_to_normalized(np.column_stack([gu.ravel(), gv.ravel()]))
    return patches, grid


def _patch_means(intr: CameraIntrinsics, field) -> tuple[np.ndarray, float]:
    """(4,) corner 10x10 patch means and the centre patch mean of ``field(xy (..., 2)) -> (...)``."""
    m = field(_probe_rays(intr._key())[0]).mean(axis=1)
    return m[:4], float(m[4])


def _draw_deformation(rng: np.random.Generator, intr: CameraIntrinsics, corner_xy: tuple) -> dict:
    grid = _probe_rays(intr._key())[1]
    xc, yc = corner_xy
    for _ in range(50):
        target = rng.uniform(3.0, 15.0)
        sign = 1.0 if rng.random() < 0.7 else -1.0
        p: dict = {"deform_corner_xy": corner_xy}
        kinds = []
        if rng.random() < 0.8:
            span = sign * 1.0
            kinds.append("bowl")
            p |= {"deform_corner_mm_1m": span * (1 - (centre := rng.uniform(0.05, 0.3))),
                  "deform_centre_mm_1m": -span * centre, "deform_sharpness": rng.uniform(0.8, 3.5),
                  "deform_radius": rng.uniform(0.85, 1.15), "deform_aspect": rng.uniform(0.9, 1.2),
                  "deform_centre_shift": tuple(rng.uniform(-0.05, 0.05, 2)),
                  "deform_skew_mm_1m": span * rng.uniform(-0.1, 0.1)}
        else:
            p |= {"deform_corner_mm_1m": 0.0, "deform_centre_mm_1m": 0.0, "deform_skew_mm_1m": 0.0}
        if rng.random() < 0.5:
            kinds.append("tilt")
            phi, mag = rng.uniform(0, 2 * math.pi), rng.uniform(0.1, 0.4)
            p["deform_tilt_mm_1m"] = (mag * math.cos(phi) / xc, mag * math.sin(phi) / yc)
        if rng.random() < 0.5:
            kinds.append("fourier")
            modes = []
            for _ in range(int(rng.integers(1, 4))):
                kx, ky = 0, 0
                while kx == 0 and ky == 0:
                    kx, ky = int(rng.integers(0, 3)), int(rng.integers(0, 3))
                modes.append((rng.uniform(0.05, 0.25), float(kx), float(ky * rng.choice([-1, 1])),
                              rng.uniform(0, 2 * math.pi)))
            p["deform_modes"] = tuple(modes)
        if rng.random() < 0.4:
            kinds.append("bumps")
            p["deform_bumps"] = tuple((rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.4), rng.uniform(-xc, xc),
                                       rng.uniform(-yc, yc), rng.uniform(0.1, 0.35))
                                      for _ in range(int(rng.integers(1, 3))))
        if rng.random() < 0.5 or not kinds:
            kinds.append("corner_falloff")
            quad = rng.random() < 0.5
            p |= {"deform_corner_falloff_mm_1m": (sign if rng.random() < 0.75 else -sign) * rng.uniform(0.3, 1.0),
                  "deform_corner_start": rng.uniform(0.75, 0.92), "deform_corner_power": rng.uniform(1.5, 4.0),
                  "deform_corner_range_power": 2.0 if quad else 1.0,
                  "deform_corner_range_gain": rng.uniform(0.05, 0.4) if quad else rng.uniform(0.0, 0.6)}
        u = rng.random()
        if u < 0.4:
            p |= {"deform_range_kind": "linear", "deform_range_gain": rng.uniform(-0.2, 0.8)}
        elif u < 0.7:
            p |= {"deform_range_kind": "quadratic", "deform_range_gain": rng.uniform(0.05, 0.35)}
        elif u < 0.85:
            p |= {"deform_range_kind": "constant"}
        else:
            p |= {"deform_range_kind": "decay", "deform_range_decay_m": rng.uniform(1.5, 6.0)}
        p = {k: (tuple(float(x) for x in v) if k in ("deform_centre_shift", "deform_tilt_mm_1m") else v)
             for k, v in p.items()}
        em = ErrorModel(**p)
        corners, centre = _patch_means(intr, lambda xy: D.deformation_mm(xy, np.full(xy.shape[:-1], 1000.0), em))
        peak = float(np.abs(corners - centre).max())
        if peak < 1e-6:
            continue
        scale = target / peak
        interior = D.deformation_mm(grid, np.full(len(grid), 1000.0), em)
        if np.abs(interior - centre).max() * scale > 1.6 * target:
            continue
        return _scale_deformation(p, scale)
    raise InputError("random_sensor: no deformation within bounds in 50 draws")  # pragma: no cover


def _scale_deformation(p: dict, s: float) -> dict:
    """Multiply every deformation amplitude of the parameter dict ``p`` by ``s``."""
    q = dict(p)
    for k in ("deform_corner_mm_1m", "deform_centre_mm_1m", "deform_skew_mm_1m", "deform_corner_falloff_mm_1m"):
        if k in q:
            q[k] = float(q[k] * s)
    if "deform_tilt_mm_1m" in q:
        q["deform_tilt_mm_1m"] = tuple(float(v * s) for v in q["deform_tilt_mm_1m"])
    for k in ("deform_modes", "deform_bumps"):
        if k in q:
            q[k] = tuple((float(m[0] * s),) + tuple(float(v) for v in m[1:]) for m in q[k])
    return q


def station_tilts(n_stations: int, max_tilt_deg: float, seed: int = 0) -> np.ndarray:
    """Per-station wall tilts: the wall normal is off the optical axis by up to ``max_tilt_deg``.

    The tilt angle is ``max_tilt_deg sqrt(U(0, 1))`` (uniform over the disc of directions), in a
    direction U(0, 2 pi), split into rotations about x and y (``scenes.wall``'s ``tilt_deg``;
    the resulting normal is within ``max_tilt_deg`` of the axis).

    Parameters
    ----------
    n_stations : int >= 0; max_tilt_deg : float >= 0 [deg]; seed : int, deterministic stream.

    Returns
    -------
    (n_stations, 2) float64 [deg]: ``(rx, ry)`` per station (zeros when ``max_tilt_deg`` is 0).
    """
    if n_stations < 0 or not (max_tilt_deg >= 0 and math.isfinite(max_tilt_deg)):
        raise InputError(f"station_tilts: need n_stations >= 0 and a finite max_tilt_deg >= 0, "
                         f"found {n_stations}, {max_tilt_deg}")
    if max_tilt_deg == 0:
        return np.zeros((n_stations, 2))
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x711, 2]))
    mag = max_tilt_deg * np.sqrt(rng.random(n_stations))
    phi = rng.uniform(0, 2 * np.pi, n_stations)
    return np.column_stack([mag * np.cos(phi), mag * np.sin(phi)])


def describe(draw: SensorDraw) -> dict:
    """JSON-able summary of ``draw`` (see :meth:`SensorDraw.describe`)."""
    em, intr = draw.errors, draw.intrinsics
    chk = lens_check(intr)
    rays = corner_rays(intr)
    pin = np.column_stack([rays[:, 0] * intr.fx + intr.cx, rays[:, 1] * intr.fy + intr.cy])
    corners_uv = np.array([[0, 0], [intr.width - 1, 0], [0, intr.height - 1], [intr.width - 1, intr.height - 1]])
    dcorn, dcent = _patch_means(intr, lambda xy: D.deformation_mm(xy, np.full(xy.shape[:-1], 1000.0), em))
    d3corn, d3cent = _patch_means(intr, lambda xy: D.deformation_mm(xy, np.full(xy.shape[:-1], 3000.0), em))
    zc = np.linspace(800.0, 4500.0, 371)
    w_centre = RE.range_error_curve_mm(zc, em)
    comps = [{"period_m": P, "amplitudes_mm": [a for _, a, _ in h], "phases_rad": [ph for _, _, ph in h]}
             for P, h in RE.wiggle_components(em)]
    kinds = [k for k, on in (("bowl", em.deform_corner_mm_1m != em.deform_centre_mm_1m or em.deform_skew_mm_1m != 0),
                             ("tilt", any(v != 0 for v in em.deform_tilt_mm_1m)), ("fourier", bool(em.deform_modes)),
                             ("bumps", bool(em.deform_bumps)), ("corner_falloff", em.deform_corner_falloff_mm_1m != 0))
             if on]
    return {
        "kind": draw.kind, "seed": draw.seed, "enabled": sorted(em.enabled),
        "lens": {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy, "distortion": list(intr.distortion),
                 "corner_ray_radius": chk.corner_radius, "invertible": chk.ok,
                 "corner_distortion_px": float(np.abs(pin - corners_uv).max())},
        "range_error": {
            "variable": em.range_variable, "applied": em.range_apply, "offset_mm": em.wiggle_offset_mm,
            "slope_mm_per_m": em.wiggle_slope_mm_per_m, "quad_mm_per_m2": em.wiggle_quad_mm_per_m2,
            "gain": em.wiggle_gain, "components": comps,
            "steep": ({"start_m": em.wiggle_steep_start_m, "mm": em.wiggle_steep_mm, "power": em.wiggle_steep_power}
                      if em.wiggle_steep_mm != 0 else None),
            "curve_min_max_mm_0.8_4.5m": [float(w_centre.min()), float(w_centre.max())]},
        "deformation": {
            "kinds": kinds, "range_kind": em.deform_range_kind,
            "corner_minus_centre_mm_1m": [float(v) for v in dcorn - dcent],
            "corner_max_abs_mm_1m": float(np.abs(dcorn - dcent).max()),
            "corner_max_abs_mm_3m": float(np.abs(d3corn - d3cent).max())},
        "amplitude_bias": {"relative_mm_per_ln": em.amp_bias_mm_per_ln, "absolute_mm_per_ln": em.amp_bias_abs_mm_per_ln,
                           "absolute_ref": em.amp_bias_abs_ref},
        "amp_white_1m": em.amp_white_1m, "vignetting_power": em.vignetting_power,
        "noise_sigma_mm": em.noise_sigma_mm, "mounting_offset_mm": em.mounting_offset_mm, "warmup_mm": em.warmup_mm,
    }
