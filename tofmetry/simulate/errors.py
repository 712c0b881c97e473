"""The Kinect v2 error model: every systematic and random term of the simulator.

Each term is a pure function of arrays and an :class:`ErrorModel` holding its parameters.
Signs: a *bias* is ``measured - true`` [mm]; positive = the sensor reads too long.
``ErrorModel()`` is the simulator's Kinect v2; its magnitudes are tied to the study
(``shared/reference/kinect-v2-assessment-paper.txt``). Other sensors of the same class
(:mod:`tofmetry.simulate.family`) change the parameters; every field's default is this sensor.

=================  ==========================================================================
term               paper
=================  ==========================================================================
wiggling           §4.2.2, Fig. 7a: central deviation -15 mm .. +7 mm for 0.8-4.5 m, strong past 4.5
                   (:mod:`~tofmetry.simulate.range_error`: trend + periodic components, of Z or
                   of the radial range, applied in Z or along the ray)
deformation        §4.2.3, Fig. 8: curved residual surface, ~1 cm in the corners, growing with range
                   (:mod:`~tofmetry.simulate.deformation`)
amplitude_bias     §3.3.1: black (1/6 of white amplitude) reads up to 12 mm long; CD up to 6 cm, uneven;
                   optionally also a term in the absolute amplitude (range, vignetting)
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

from tofmetry._shared.study_constants import AMPLITUDE_BIAS_MM_PER_LN
from tofmetry.errors import InputError
from tofmetry.simulate.deformation import (  # noqa: F401  (re-exported: the terms live in their modules)
    RANGE_KINDS, corner_scale, corner_shape, deformation_mm, deformation_scale, deformation_shape,
)
from tofmetry.simulate.range_error import range_error_curve_mm, ray_factor, wiggling_mm  # noqa: F401

#: Names of the switchable error terms.
TERMS: tuple[str, ...] = (
    "wiggling", "deformation", "amplitude_bias", "noise", "flying", "invalid", "warmup",
    "mounting_offset", "quantize",
)

#: Half modulation wavelength of the 80 MHz Kinect v2 carrier: c / (2 f) [m].
HALF_WAVELENGTH_M = 299_792_458.0 / (2 * 80e6)

#: Range variables and applications of the range error (``ErrorModel.range_variable`` / ``range_apply``).
RANGE_VARIABLES = ("z", "radial")
RANGE_APPLY = ("z", "ray")


@dataclass(frozen=True)
class ErrorModel:
    """Parameters and on/off switches of the simulated Kinect v2 errors.

    Build with ``ErrorModel()`` (everything on), ``ErrorModel.none()`` (ideal sensor,
    still quantised), ``ErrorModel().without("noise", "flying")`` or
    ``ErrorModel.only("wiggling")`` (+ quantisation; ``quantize=False`` for float depth).
    Parameters can be changed with :meth:`with_`. Every default is the simulator's Kinect v2.

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
        Range error curve (see :mod:`tofmetry.simulate.range_error`): ``offset`` [mm],
        ``slope`` [mm/m] and ``quad`` [mm/m^2] about 0.8 m, ``gain`` (scale error, mm per mm),
        periodic components of periods ``wiggle_periods_m`` [m] whose harmonics 1..n_c
        (``wiggle_harmonics``, one count per period; None = one component holding all
        amplitudes) have amplitudes ``wiggle_amps_mm`` [mm] and phases ``wiggle_phases``
        [rad] (flat, component after component), and a steep growth
        ``steep_mm max(0, d - steep_start_m)^steep_power``. Default: linear trend + 3 harmonics
        of the 80 MHz half wavelength + steep growth past 4.4 m.
    optical_blur_px : float
        Gaussian sigma of the lens's point spread [px], on top of the pixel's own area, in the IR
        amplitude image: the sub-rays of a supersampled pixel's amplitude
        (:func:`tofmetry.simulate.render.render`) sample the pixel area convolved with it. The
        depth of a mixed pixel is still taken over the pixel's area alone (the flying-pixel model
        matched to the study): spreading it by the point spread too widens the band of mixed
        pixels along depth edges to about two pixels, which the reconstruction's registration does
        not yet survive on the study's small 8-view scan (model vs reference 5.7 mm instead of 0.5). Measured on the real Kinect v2 board recording (``../shared/data``, 14 IR images):
        tofmetry's X-junction corner fit finds an edge sigma of 0.39-0.51 px (median 0.41 px),
        against 0.29 px for a pixel's area alone (sqrt(1/12)); the optics add sqrt(0.41^2 - 0.29^2)
        = 0.29 px. With 0 the edges are as sharp as the pixel grid allows, sharper than a real
        Kinect's.
    range_variable : {"z", "radial"}
        The range error is a function of the radial range ``Z sqrt(1+x^2+y^2)`` (default: a
        continuous-wave ToF camera measures the phase of the light's path, so its wiggling follows
        the ray length, paper §2.3) or of Z.
    range_apply : {"z", "ray"}
        The range error is added to the radial range, i.e. ``W / rho`` in Z (default: the camera
        converts the ray length to Z), or to Z. ``range_variable="z", range_apply="z"`` is the
        form this simulator had before the sensor family (kept for comparison, e.g. with
        ``ErrorModel.with_(range_variable="z", range_apply="z")``); on the optical axis both
        forms are the same, so the study's central-deviation curve (Fig. 7a) is unchanged.
    deform_* :
        Per-pixel surface (see :mod:`tofmetry.simulate.deformation`): the exponential bowl
        (``corner``/``centre`` values at 1 m [mm], ``sharpness`` > 0, ``radius``,
        ``centre_shift``, ``aspect``, ``skew``), ``deform_tilt_mm_1m`` (mm per unit of x and
        of y at 1 m), ``deform_modes`` ((amp_mm, kx, ky, phase), ...) Fourier modes,
        ``deform_bumps`` ((amp_mm, x0, y0, sigma), ...) Gaussian bumps (normalised units),
        the range dependence ``deform_range_kind`` in :data:`RANGE_KINDS` with
        ``deform_range_gain`` / ``deform_range_decay_m`` [m], the corner fall-off
        (``deform_corner_falloff_mm_1m`` at the corner, ``deform_corner_start`` 0.71..1,
        ``deform_corner_power``, range growth ``(1 - g) + g Z^n`` with
        ``deform_corner_range_gain`` and ``deform_corner_range_power``) and
        ``deform_corner_xy``, the normalised ray coordinates of the image corners.
    amp_bias_mm_per_ln : float
        Amplitude bias ``k * ln(A_white / A)``; 12 mm / ln 6 = 6.7 mm (paper §3.3.1).
    amp_bias_abs_mm_per_ln, amp_bias_abs_ref : float
        Bias in the *absolute* amplitude ``k_abs ln(A_ref / A)`` [mm] (default off): a white
        wall shows it too, growing with range and toward the vignetted corners.
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
    optical_blur_px: float = 0.29
    # (a) wiggling / range error
    wiggle_offset_mm: float = -10.0
    wiggle_slope_mm_per_m: float = 3.0
    wiggle_amps_mm: tuple = (4.5, 2.5, 0.8)
    wiggle_phases: tuple = (0.02, 3.69, 6.15)
    wiggle_steep_start_m: float = 4.4
    wiggle_steep_mm: float = 30.0
    wiggle_quad_mm_per_m2: float = 0.0
    wiggle_gain: float = 0.0
    wiggle_periods_m: tuple = (HALF_WAVELENGTH_M,)
    wiggle_harmonics: tuple | None = None
    wiggle_steep_power: float = 1.5
    range_variable: str = "radial"
    range_apply: str = "ray"
    # (b) deformation
    deform_corner_mm_1m: float = 10.5
    deform_centre_mm_1m: float = -2.0
    deform_range_gain: float = 0.5
    deform_sharpness: float = 2.2
    deform_radius: float = 0.98
    deform_centre_shift: tuple = (0.01, -0.005)
    deform_aspect: float = 1.08
    deform_skew_mm_1m: float = 0.5
    deform_range_kind: str = "linear"
    deform_range_decay_m: float = 2.0
    deform_tilt_mm_1m: tuple = (0.0, 0.0)
    deform_modes: tuple = ()
    deform_bumps: tuple = ()
    deform_corner_falloff_mm_1m: float = 0.0
    deform_corner_start: float = 0.8
    deform_corner_power: float = 2.0
    deform_corner_range_gain: float = 0.0
    deform_corner_range_power: float = 1.0
    deform_corner_xy: tuple = (0.77, 0.64)
    # (c) amplitude bias
    amp_bias_mm_per_ln: float = AMPLITUDE_BIAS_MM_PER_LN
    amp_bias_abs_mm_per_ln: float = 0.0
    amp_bias_abs_ref: float = 12_000.0
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
        for name in ("wiggle_amps_mm", "wiggle_phases", "wiggle_periods_m", "deform_centre_shift",
                     "deform_tilt_mm_1m", "deform_modes", "deform_bumps", "deform_corner_xy", "wiggle_harmonics"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _tuplify(v))
        if not 0.0 <= self.ambient <= 1.0:
            raise InputError(f"ErrorModel: ambient must be within 0..1, found {self.ambient}")
        _validate(self)

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

    def amplitude_slope_mm_per_ln(self) -> float:
        """The slope [mm per ln unit] of the depth bias in ``ln(A_white / A)`` between surfaces seen at
        one pixel and range: the relative and the absolute amplitude terms together, ``k + k_abs``
        (at a fixed place both change with ``ln A`` alike); 0 with ``amplitude_bias`` off. What a
        grey-level board measures and what an object's dark and bright parts differ by."""
        return self.amp_bias_mm_per_ln + self.amp_bias_abs_mm_per_ln if self.on("amplitude_bias") else 0.0

    def to_dict(self) -> dict:
        """JSON-able dict of every field (``enabled`` as a sorted list)."""
        d = dataclasses.asdict(self)
        d["enabled"] = sorted(self.enabled)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ErrorModel":
        """Inverse of :meth:`to_dict` (lists, also nested ones, become tuples); unknown keys raise."""
        d = dict(d)
        unknown = sorted(set(d) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise InputError(f"ErrorModel.from_dict: unknown field(s) {unknown}")
        d["enabled"] = frozenset(d.get("enabled", TERMS))
        for k, v in list(d.items()):
            if isinstance(v, list):
                d[k] = _tuplify(v)
        return cls(**d)


def _tuplify(v):
    """Lists/tuples (nested) -> tuples of floats/ints/str."""
    if isinstance(v, (list, tuple, np.ndarray)):
        return tuple(_tuplify(x) for x in v)
    if isinstance(v, np.generic):
        return v.item()
    return v


def _validate(em: ErrorModel) -> None:
    """Raise :class:`InputError` naming the first inconsistent parameter of ``em``."""
    def bad(name, expected, found):
        raise InputError(f"ErrorModel: {name} must be {expected}, found {found!r}")

    if em.range_variable not in RANGE_VARIABLES:
        bad("range_variable", f"one of {RANGE_VARIABLES}", em.range_variable)
    if em.range_apply not in RANGE_APPLY:
        bad("range_apply", f"one of {RANGE_APPLY}", em.range_apply)
    if em.deform_range_kind not in RANGE_KINDS:
        bad("deform_range_kind", f"one of {RANGE_KINDS}", em.deform_range_kind)
    if len(em.wiggle_amps_mm) != len(em.wiggle_phases):
        bad("wiggle_phases", f"as long as wiggle_amps_mm ({len(em.wiggle_amps_mm)})", em.wiggle_phases)
    if not em.wiggle_periods_m or any(not (p > 0 and math.isfinite(p)) for p in em.wiggle_periods_m):
        bad("wiggle_periods_m", "a non-empty tuple of positive periods [m]", em.wiggle_periods_m)
    if em.wiggle_harmonics is None:
        if len(em.wiggle_periods_m) != 1:
            bad("wiggle_harmonics", "one harmonic count per period when there are several periods",
                em.wiggle_harmonics)
    else:
        h = em.wiggle_harmonics
        if len(h) != len(em.wiggle_periods_m) or any(int(n) != n or n < 0 for n in h):
            bad("wiggle_harmonics", f"{len(em.wiggle_periods_m)} non-negative integer counts (one per period)", h)
        if sum(h) != len(em.wiggle_amps_mm):
            bad("wiggle_harmonics", f"counts summing to len(wiggle_amps_mm) = {len(em.wiggle_amps_mm)}", h)
    if not em.deform_sharpness > 0:
        bad("deform_sharpness", "> 0", em.deform_sharpness)
    if em.deform_range_kind == "decay" and not em.deform_range_decay_m > 0:
        bad("deform_range_decay_m", "> 0 for deform_range_kind='decay'", em.deform_range_decay_m)
    if len(em.deform_corner_xy) != 2 or not all(v > 0 for v in em.deform_corner_xy):
        bad("deform_corner_xy", "two positive normalised corner coordinates (x_c, y_c)", em.deform_corner_xy)
    if not 0.0 <= em.deform_corner_start < 1.0:
        bad("deform_corner_start", "within [0, 1)", em.deform_corner_start)
    for name, n in (("deform_modes", 4), ("deform_bumps", 4)):
        if any(len(m) != n for m in getattr(em, name)):
            bad(name, f"a tuple of {n}-tuples", getattr(em, name))
    if any(not b[3] > 0 for b in em.deform_bumps):
        bad("deform_bumps", "bumps with sigma > 0", em.deform_bumps)
    if len(em.deform_tilt_mm_1m) != 2:
        bad("deform_tilt_mm_1m", "(t_x, t_y)", em.deform_tilt_mm_1m)
    if not em.amp_bias_abs_ref > 0:
        bad("amp_bias_abs_ref", "> 0", em.amp_bias_abs_ref)


def _check_terms(terms) -> None:
    bad = sorted(set(terms) - set(TERMS))
    if bad:
        raise InputError(f"unknown error term(s) {bad}; known terms: {list(TERMS)}")


# ---------------------------------------------------------------------- terms
def amplitude_bias_mm(rel_reflectance: np.ndarray, em: ErrorModel) -> np.ndarray:
    """(c) Amplitude-related bias [mm]: ``k ln(A_white / A)``, dark surfaces read long.

    Parameters
    ----------
    rel_reflectance : array
        ``A / A_white``: amplitude relative to a white surface facing the ray (normal incidence) at the same pixel
        and range (1 for white, ~1/6 for black -> +12 mm).
    """
    r = np.clip(np.asarray(rel_reflectance, dtype=np.float64), 1e-3, None)
    return em.amp_bias_mm_per_ln * np.log(1.0 / r)


def amplitude_bias_abs_mm(amplitude_: np.ndarray, em: ErrorModel) -> np.ndarray:
    """(c) Bias in the absolute amplitude [mm]: ``k_abs ln(A_ref / A)`` (``amp_bias_abs_*``).

    Unlike :func:`amplitude_bias_mm` a white wall shows it: it grows with range (A ~ 1/r^2:
    ``2 k_abs ln(r / 1 m)`` on the axis) and toward the vignetted corners.

    Parameters
    ----------
    amplitude_ : array
        Noise-free IR amplitude (clipped at 1).

    Returns
    -------
    Array of the same shape [mm] (zeros when ``amp_bias_abs_mm_per_ln`` is 0).
    """
    a = np.maximum(np.asarray(amplitude_, dtype=np.float64), 1.0)
    return em.amp_bias_abs_mm_per_ln * np.log(em.amp_bias_abs_ref / a)


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
    cos_t = 1.0 / ray_factor(xy)
    return cos_t ** em.vignetting_power


def white_amplitude(xy: np.ndarray, range_m: np.ndarray, em: ErrorModel) -> np.ndarray:
    """Amplitude of a white surface facing the ray (normal incidence) at ray length ``range_m`` [m] seen along
    ``xy``; a fronto-parallel wall returns ``cos theta`` of it off the axis, and reads ``k ln(1 / cos theta)`` long."""
    r = np.maximum(np.asarray(range_m, dtype=np.float64), 1e-3)
    return em.amp_white_1m * vignetting(xy, em) / r ** 2


def amplitude(albedo: np.ndarray, cos_incidence: np.ndarray, xy: np.ndarray, range_m: np.ndarray,
              em: ErrorModel) -> np.ndarray:
    """IR amplitude: ``A_white,1m (albedo / albedo_white) cos(i) cos(theta)^p / r^2``.

    Calibrated so that white (0.8) at 1 m centre gives 12 000 and black (0.133) 2 000
    (paper §3.3.1).
    """
    return white_amplitude(xy, range_m, em) * (np.asarray(albedo) / em.albedo_white) * np.clip(cos_incidence, 0.0, 1.0)
