"""The Kinect v2 error model: every systematic and random term of the simulator.

Each term is a pure function of arrays and an :class:`ErrorModel` holding its parameters.
Signs: a *bias* is ``measured - true`` [mm]; positive = the sensor reads too long.
Magnitudes are tied to the study (``shared/reference/kinect-v2-assessment-paper.txt``):

=================  ==========================================================================
term               paper
=================  ==========================================================================
wiggling           §4.2.2, Fig. 7a: central deviation -15 mm .. +7 mm for 0.8-4.5 m, strong past 4.5
deformation        §4.2.3, Fig. 8: curved residual surface, ~1 cm in the corners, growing with range
amplitude_bias     §3.3.1: black (1/6 of white amplitude) reads up to 12 mm long; CD up to 6 cm, uneven
noise              §3.2 / Fig. 3, 7b: ~1 mm at ~1 m centre, growing with range and toward corners
flying             §3.3.2: mixed pixels at depth edges; outdoors ~2 % of the valid points
invalid            §3.1 / §3.3.2: 0.5-4.5 m; outdoors only ~20 % of the 217 088 pixels valid
warmup             §3.2: ~5 mm drift over the first 30 min, fan starts at ~20 min, then +-1 mm
mounting_offset    §4.2.2: ~2 cm between the tripod fixing point and the optical centre
quantize           depth delivered as whole millimetres (uint16), 0 = invalid
=================  ==========================================================================
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from tofmetry.errors import InputError

#: Names of the switchable error terms.
TERMS: tuple[str, ...] = (
    "wiggling", "deformation", "amplitude_bias", "noise", "flying", "invalid", "warmup",
    "mounting_offset", "quantize",
)

#: Half modulation wavelength of the 80 MHz Kinect v2 carrier: c / (2 f) [m].
HALF_WAVELENGTH_M = 299_792_458.0 / (2 * 80e6)


@dataclass(frozen=True)
class ErrorModel:
    """Parameters and on/off switches of the simulated Kinect v2 errors.

    Build with ``ErrorModel()`` (everything on), ``ErrorModel.none()`` (ideal sensor,
    still quantised), ``ErrorModel().without("noise", "flying")`` or
    ``ErrorModel.only("wiggling")`` (+ quantisation; ``quantize=False`` for float depth). Parameters can be changed with :meth:`with_`.

    Attributes
    ----------
    enabled : frozenset of str
        Active terms, a subset of :data:`TERMS`.
    amp_white_1m : float
        IR amplitude of a white (albedo 0.8) frontal surface at 1 m on the optical axis
        (paper §3.3.1: 12 000; black ~2 000).
    albedo_white : float
        Albedo taken as "white" for the amplitude calibration and the amplitude bias.
    vignetting_power : float
        Illumination/lens falloff ``cos(off-axis angle) ** p``.
    wiggle_* :
        Wiggling = linear trend + 3 harmonics of the 80 MHz half wavelength + steep growth
        past ``wiggle_steep_start_m`` (see :func:`wiggling_mm`).
    deform_* :
        Per-pixel surface (see :func:`deformation_mm`).
    amp_bias_mm_per_ln : float
        Amplitude bias ``k * ln(A_white / A)``; 12 mm / ln 6 = 6.7 mm (paper §3.3.1).
    reflective_max_mm, reflective_jitter_mm : float
        Extra, spatially uneven bias of reflective samples (CD: up to 6 cm) and its per-frame jitter.
    noise_sigma_mm : float
        Temporal sigma at ``amp_white_1m`` (white, 1 m, centre); scales as sqrt(A_ref / A).
    noise_near_gain, noise_near_scale_m : float
        Extra noise close to the minimum range (paper Fig. 7b: the 0.8 m station stands out;
        sigma(0.8 m) = 1.34 mm > sigma(1 m) = 1.26 mm < sigma(1.25 m) = 1.5 mm).
    flying_gap_mm : float
        Sub-pixel depth spread above which a pixel is a mixed ("flying") pixel.
    flying_jitter : float
        Per-frame relative jitter of the sub-pixel weights of mixed pixels.
    flying_label_mm : float
        A mixed pixel is *labelled* flying in a frame when its value is farther than this
        from every surface it straddles.
    min_range_mm, max_range_mm, min_amplitude : float
        Validity limits.
    ambient : float
        Strong ambient (sun) light, 0..1. Raises the amplitude threshold and the noise and
        sprays flying pixels, more toward the edges of the field of view (§3.3.2).
    ambient_amp_threshold, ambient_noise_amp, ambient_spray_prob : float
        Ambient model parameters at ``ambient = 1``.
    warmup_* :
        Warm-up drift (see :func:`warmup_mm`).
    mounting_offset_mm : float
        Optical centre lies this far in *front* of the tripod reference point (toward the
        scene): true optical-centre distance = station distance - offset.
    """

    enabled: frozenset = field(default_factory=lambda: frozenset(TERMS))
    # amplitude model
    amp_white_1m: float = 12_000.0
    albedo_white: float = 0.8
    vignetting_power: float = 3.0
    amp_noise_rel: float = 0.01
    # (a) wiggling
    wiggle_offset_mm: float = -10.0
    wiggle_slope_mm_per_m: float = 3.0
    wiggle_amps_mm: tuple = (4.5, 2.5, 0.8)
    wiggle_phases: tuple = (0.02, 3.69, 6.15)
    wiggle_steep_start_m: float = 4.4
    wiggle_steep_mm: float = 30.0
    # (b) deformation
    deform_corner_mm_1m: float = 10.5
    deform_centre_mm_1m: float = -2.0
    deform_range_gain: float = 0.5
    deform_sharpness: float = 2.2
    deform_radius: float = 0.98
    deform_centre_shift: tuple = (0.01, -0.005)
    deform_aspect: float = 1.08
    deform_skew_mm_1m: float = 0.5
    # (c) amplitude bias
    amp_bias_mm_per_ln: float = 12.0 / math.log(6.0)
    reflective_max_mm: float = 60.0
    reflective_jitter_mm: float = 6.0
    # (d) noise
    noise_sigma_mm: float = 1.2
    noise_near_gain: float = 8.0
    noise_near_scale_m: float = 0.1
    noise_sigma_max_mm: float = 150.0
    # (e) flying
    flying_gap_mm: float = 30.0
    flying_jitter: float = 0.35
    flying_label_mm: float = 15.0
    # (f) invalid
    min_range_mm: float = 500.0
    max_range_mm: float = 4500.0
    min_amplitude: float = 30.0
    ambient: float = 0.0
    ambient_amp_threshold: float = 770.0
    ambient_noise_amp: float = 4000.0
    ambient_spray_prob: float = 0.025
    # (g) warm-up
    warmup_mm: float = 5.0
    warmup_tau_s: float = 720.0
    warmup_fan_s: float = 1200.0
    warmup_fan_tau_s: float = 240.0
    warmup_fan_level: float = 0.7
    warmup_wander_mm: float = 0.3
    warmup_wander_period_s: float = 900.0
    # (h) mounting offset
    mounting_offset_mm: float = 20.0

    def __post_init__(self) -> None:
        en = frozenset(self.enabled)
        unknown = sorted(en - set(TERMS))
        if unknown:
            raise InputError(f"ErrorModel: unknown error term(s) {unknown}; known terms: {list(TERMS)}")
        object.__setattr__(self, "enabled", en)
        if not 0.0 <= self.ambient <= 1.0:
            raise InputError(f"ErrorModel: ambient must be within 0..1, found {self.ambient}")

    # ------------------------------------------------------------ switches
    @classmethod
    def none(cls, quantize: bool = True, **params) -> "ErrorModel":
        """Ideal sensor: every term off except (optionally) the mm quantisation."""
        return cls(enabled=frozenset({"quantize"} if quantize else set()), **params)

    @classmethod
    def only(cls, *terms: str, quantize: bool = True, **params) -> "ErrorModel":
        """Only the named terms on, plus the mm quantisation unless ``quantize=False``
        (then depth frames are float64 mm and cannot be written as captures)."""
        en = set(terms) | ({"quantize"} if quantize else set())
        return cls(enabled=frozenset(en), **params)

    def without(self, *terms: str) -> "ErrorModel":
        """Copy with the named terms switched off."""
        _check_terms(terms)
        return dataclasses.replace(self, enabled=self.enabled - set(terms))

    def with_terms(self, *terms: str) -> "ErrorModel":
        """Copy with the named terms switched on."""
        _check_terms(terms)
        return dataclasses.replace(self, enabled=self.enabled | set(terms))

    def with_(self, **params) -> "ErrorModel":
        """Copy with parameters replaced."""
        return dataclasses.replace(self, **params)

    def on(self, term: str) -> bool:
        """Whether ``term`` is enabled."""
        return term in self.enabled

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["enabled"] = sorted(self.enabled)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ErrorModel":
        d = dict(d)
        d["enabled"] = frozenset(d.get("enabled", TERMS))
        for k, v in list(d.items()):
            if isinstance(v, list):
                d[k] = tuple(v)
        return cls(**d)


def _check_terms(terms) -> None:
    bad = sorted(set(terms) - set(TERMS))
    if bad:
        raise InputError(f"unknown error term(s) {bad}; known terms: {list(TERMS)}")


# ---------------------------------------------------------------------- terms
def wiggling_mm(z_mm: np.ndarray, em: ErrorModel) -> np.ndarray:
    """(a) Range-dependent systematic error ("wiggling") [mm].

    ``w(z) = o + s (z - 0.8) + sum_k a_k sin(2 pi k z / L + phi_k) + g max(0, z - z_s)^1.5``
    with ``L`` = 1.874 m, the half wavelength of the 80 MHz modulation (harmonics
    k = 1, 2, 3 of a not perfectly sinusoidal modulation, paper §2.3) and a steep growth
    past ``z_s`` = 4.4 m. Between 0.8 and 4.5 m it spans -15 .. +7 mm (paper Fig. 7a).

    Parameters
    ----------
    z_mm : array of float [mm]
        Depth Z (the Kinect delivers Z; the residual is modelled as a function of Z).

    Returns
    -------
    Bias array of the same shape [mm].
    """
    z = np.asarray(z_mm, dtype=np.float64) * 1e-3
    w = em.wiggle_offset_mm + em.wiggle_slope_mm_per_m * (z - 0.8)
    for k, (a, p) in enumerate(zip(em.wiggle_amps_mm, em.wiggle_phases), start=1):
        w = w + a * np.sin(2 * np.pi * k * z / HALF_WAVELENGTH_M + p)
    w = w + em.wiggle_steep_mm * np.maximum(z - em.wiggle_steep_start_m, 0.0) ** 1.5
    return w


def deformation_shape(xy: np.ndarray, em: ErrorModel) -> np.ndarray:
    """(b) Per-pixel deformation pattern at 1 m [mm] from normalised rays.

    An exponential bowl in an off-centre, slightly elliptic radius, plus a small skew:
    negative in a central disc (``deform_centre_mm_1m`` = -2 mm), +10.4 .. +15 mm in the four
    corner 10x10 patches of the Kinect v2 at 1 m (paper Fig. 8: ~1 cm), not radially
    symmetric and not a polynomial.

    Parameters
    ----------
    xy : (..., 2) float64
        Undistorted normalised ray coordinates (``intr.ray_table()``).

    Returns
    -------
    (...) float64 [mm] at 1 m.
    """
    x = xy[..., 0] - em.deform_centre_shift[0]
    y = xy[..., 1] - em.deform_centre_shift[1]
    q = ((x * em.deform_aspect) ** 2 + y ** 2) / em.deform_radius ** 2  # ~1 in the Kinect v2 corners
    a = em.deform_sharpness
    span = em.deform_corner_mm_1m - em.deform_centre_mm_1m
    bowl = em.deform_centre_mm_1m + span * (np.exp(a * q) - 1.0) / (math.exp(a) - 1.0)
    skew = em.deform_skew_mm_1m * np.tanh(2.0 * x * y / 0.4)
    return bowl + skew


def deformation_scale(z_mm: np.ndarray, em: ErrorModel) -> np.ndarray:
    """Range growth of the deformation: ``(1 - g) + g z[m]`` (1 at 1 m; 2 at 3 m for g = 0.5)."""
    z = np.asarray(z_mm, dtype=np.float64) * 1e-3
    return (1.0 - em.deform_range_gain) + em.deform_range_gain * z


def deformation_mm(xy: np.ndarray, z_mm: np.ndarray, em: ErrorModel) -> np.ndarray:
    """(b) Per-pixel surface deformation [mm] = :func:`deformation_shape` x :func:`deformation_scale`."""
    return deformation_shape(xy, em) * deformation_scale(z_mm, em)


def amplitude_bias_mm(rel_reflectance: np.ndarray, em: ErrorModel) -> np.ndarray:
    """(c) Amplitude-related bias [mm]: ``k ln(A_white / A)``, dark surfaces read long.

    Parameters
    ----------
    rel_reflectance : array
        ``A / A_white``: amplitude relative to a white frontal surface at the same pixel
        and range (1 for white, ~1/6 for black -> +12 mm).
    """
    r = np.clip(np.asarray(rel_reflectance, dtype=np.float64), 1e-3, None)
    return em.amp_bias_mm_per_ln * np.log(1.0 / r)


def noise_sigma_mm(amplitude: np.ndarray, z_mm: np.ndarray, em: ErrorModel) -> np.ndarray:
    """(d) Temporal noise sigma [mm].

    ``sigma = s0 sqrt(A_ref / A) (1 + g exp(-(z - 0.5 m) / l)) sqrt(1 + ambient A_amb / A)``:
    shot-noise-like, so it grows with range (1/r^2 amplitude), toward the corners
    (vignetting) and on dark surfaces; ``s0`` = 1.2 mm for white at 1 m on the axis.
    """
    a = np.maximum(np.asarray(amplitude, dtype=np.float64), 1.0)
    z = np.asarray(z_mm, dtype=np.float64) * 1e-3
    s = em.noise_sigma_mm * np.sqrt(em.amp_white_1m / a)
    s = s * (1.0 + em.noise_near_gain * np.exp(-np.maximum(z - 0.5, 0.0) / em.noise_near_scale_m))
    if em.ambient > 0:
        s = s * np.sqrt(1.0 + em.ambient * em.ambient_noise_amp / a)
    return np.minimum(s, em.noise_sigma_max_mm)


def warmup_mm(t_s: np.ndarray | float, em: ErrorModel) -> np.ndarray:
    """(g) Warm-up drift [mm] as a function of the time since power-on [s].

    A thermal state heats as ``1 - exp(-t / tau)``; at ``t_fan`` (20 min) the fan starts
    and the state relaxes toward ``fan_level`` (kink). Drift = ``k (state - fan_level)``
    scaled so that it is ``-warmup_mm`` at power-on (about 5 mm over the first 30 min,
    paper §3.2), then stable; a small wander (0.3 mm) remains afterwards.
    """
    t = np.asarray(t_s, dtype=np.float64)
    heat = 1.0 - np.exp(-np.maximum(t, 0.0) / em.warmup_tau_s)
    s_fan = 1.0 - math.exp(-em.warmup_fan_s / em.warmup_tau_s)
    after = em.warmup_fan_level + (s_fan - em.warmup_fan_level) * np.exp(
        -np.maximum(t - em.warmup_fan_s, 0.0) / em.warmup_fan_tau_s)
    state = np.where(t < em.warmup_fan_s, heat, after)
    k = em.warmup_mm / em.warmup_fan_level
    wander = em.warmup_wander_mm * np.sin(2 * np.pi * t / em.warmup_wander_period_s) * (1 - np.exp(-t / 1800.0))
    return k * (state - em.warmup_fan_level) + wander


def vignetting(xy: np.ndarray, em: ErrorModel) -> np.ndarray:
    """Illumination falloff ``cos(theta)^p`` of the off-axis angle, from normalised rays (..., 2)."""
    cos_t = 1.0 / np.sqrt(1.0 + xy[..., 0] ** 2 + xy[..., 1] ** 2)
    return cos_t ** em.vignetting_power


def white_amplitude(xy: np.ndarray, range_m: np.ndarray, em: ErrorModel) -> np.ndarray:
    """Amplitude of a white frontal surface at ray length ``range_m`` [m] seen along ``xy``."""
    r = np.maximum(np.asarray(range_m, dtype=np.float64), 1e-3)
    return em.amp_white_1m * vignetting(xy, em) / r ** 2


def amplitude(albedo: np.ndarray, cos_incidence: np.ndarray, xy: np.ndarray, range_m: np.ndarray,
              em: ErrorModel) -> np.ndarray:
    """IR amplitude: ``A_white,1m (albedo / albedo_white) cos(i) cos(theta)^p / r^2``.

    Calibrated so that white (0.8) at 1 m centre gives 12 000 and black (0.133) 2 000
    (paper §3.3.1).
    """
    return white_amplitude(xy, range_m, em) * (np.asarray(albedo) / em.albedo_white) * np.clip(cos_incidence, 0.0, 1.0)
