"""Range-error curve ``R(d)``: candidate models and their selection by cross-validation.

The study fits a smoothing B-spline to the central deviations of the wall stations (§4.2.2).
Between stations such a spline can only interpolate: with stations 0.25 m apart, a wiggling
component of 0.6 m period (the 3rd harmonic of the 80 MHz carrier's 1.874 m half wavelength)
is sampled barely above its Nyquist limit and the spline misses it by up to ~0.7 mm at
stations never fitted.

Continuous-wave ToF wiggling is periodic in the unambiguous range ``c / (2 f)`` of each
modulation frequency ``f`` (the correlation signal is not a pure sinusoid, so its harmonics
alias into the phase; Lindner & Kolb 2006, Rapp 2008). A *harmonic* candidate models

    ``R(d) = sum_p a_p t^p + sum_{k} (b_k sin(2 pi k d / L) + c_k cos(2 pi k d / L))``

with ``t`` the centred distance in metres, a low-order polynomial trend and the harmonics
``k = 1..m`` of the half wavelength ``L`` whose period the station spacing can resolve (period
>= ``min_samples_per_period`` x median spacing), for every ``m`` the number of stations affords. Candidates are scored by leave-one-out
prediction at interior stations (the honest figure: it predicts a station that was not
fitted) and the best one is kept; the spline stays the choice when nothing beats it, e.g. for
a sensor whose modulation frequencies are unknown or whose wiggling is not periodic.

Whatever is chosen is stored as a cubic B-spline (interpolating the model on a 20 mm grid,
error < 1e-4 mm for periods >= 0.3 m), so the calibration file format does not depend on the
model family.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline, make_smoothing_spline

#: Speed of light [m/s].
C_M_S = 299_792_458.0


def half_wavelength_mm(f_mhz: float) -> float:
    """Unambiguous range ``c / (2 f)`` [mm] of a modulation frequency ``f_mhz`` [MHz]."""
    return C_M_S / (2.0 * f_mhz * 1e6) * 1e3


@dataclass(frozen=True)
class RangeModelChoice:
    """Outcome of :func:`select_range_curve`.

    Attributes
    ----------
    spline : scipy.interpolate.BSpline
        The chosen curve ``R(d)`` [mm] of measured distance [mm].
    name : str
        ``"spline"`` or ``"harmonic <f> MHz, trend degree <p>, k=<...>"``.
    cv_rms_mm : dict
        Leave-one-out RMS at interior stations [mm] of every candidate (NaN: not scored).
    """

    spline: BSpline
    name: str
    cv_rms_mm: dict = field(default_factory=dict)


def merge_close(x: np.ndarray, y: np.ndarray, merge_mm: float = 1.0):
    """Average points closer than ``merge_mm`` in ``x``; returns sorted ``x, y, w`` (w = count)."""
    order = np.argsort(x, kind="stable")
    x, y = np.asarray(x, float)[order], np.asarray(y, float)[order]
    gx, gy, gw = [x[0]], [y[0]], [1.0]
    for xi, yi in zip(x[1:], y[1:]):
        if xi - gx[-1] / gw[-1] < merge_mm:
            gx[-1] += xi
            gy[-1] += yi
            gw[-1] += 1.0
        else:
            gx.append(xi)
            gy.append(yi)
            gw.append(1.0)
    w = np.array(gw)
    return np.array(gx) / w, np.array(gy) / w, w


def smoothing_spline(x: np.ndarray, y: np.ndarray, w: np.ndarray, lam: float | None = None) -> BSpline:
    """Cubic smoothing spline (GCV smoothing unless ``lam``); interpolating for < 5 points."""
    if len(x) >= 5:
        return make_smoothing_spline(x, y, w=w / w.mean(), lam=lam)
    return make_interp_spline(x, y, k=min(3, len(x) - 1))


def _harmonic_design(x_mm: np.ndarray, centre_mm: float, degree: int, period_mm: float, ks) -> np.ndarray:
    t = (np.asarray(x_mm, float) - centre_mm) * 1e-3
    cols = [t ** p for p in range(degree + 1)]
    for k in ks:
        a = 2.0 * np.pi * k * np.asarray(x_mm, float) / period_mm
        cols += [np.sin(a), np.cos(a)]
    return np.column_stack(cols)


@dataclass(frozen=True)
class _Harmonic:
    degree: int
    period_mm: float
    ks: tuple
    f_mhz: float

    @property
    def n_params(self) -> int:
        return self.degree + 1 + 2 * len(self.ks)

    @property
    def name(self) -> str:
        return f"harmonic {self.f_mhz:g} MHz, trend degree {self.degree}, k={','.join(map(str, self.ks))}"

    def fit(self, x, y, w):
        c = float(np.average(x, weights=w))
        a = _harmonic_design(x, c, self.degree, self.period_mm, self.ks)
        sw = np.sqrt(w)
        coef, *_ = np.linalg.lstsq(a * sw[:, None], y * sw, rcond=None)
        return lambda xx: _harmonic_design(xx, c, self.degree, self.period_mm, self.ks) @ coef


def _as_bspline(func, lo: float, hi: float, step_mm: float = 20.0) -> BSpline:
    n = max(int(np.ceil((hi - lo) / step_mm)) + 1, 4)
    g = np.linspace(lo, hi, n)
    return make_interp_spline(g, func(g), k=3)


def _loo_rms(fit, x, y, w) -> float:
    """Leave-one-out prediction RMS at interior points (ends would be extrapolation) [mm]."""
    errs = []
    for i in range(1, len(x) - 1):
        m = np.arange(len(x)) != i
        try:
            f = fit(x[m], y[m], w[m])
        except (ValueError, np.linalg.LinAlgError):
            return float("nan")
        errs.append(float(y[i] - np.asarray(f(x[i:i + 1]))[0]))
    return float(np.sqrt(np.mean(np.square(errs)))) if errs else float("nan")


def harmonic_candidates(x: np.ndarray, modulation_mhz, max_harmonic: int = 3, degrees=(1, 2, 3),
                        min_samples_per_period: float = 2.2) -> list:
    """Harmonic candidates the sampling ``x`` [mm] can resolve (see the module docstring)."""
    x = np.sort(np.asarray(x, float))
    if len(x) < 6 or not modulation_mhz:
        return []
    spacing = float(np.median(np.diff(x)))
    out = []
    for f in modulation_mhz:
        period = half_wavelength_mm(float(f))
        ks_all = tuple(k for k in range(1, max_harmonic + 1) if period / k >= min_samples_per_period * spacing)
        for m in range(1, len(ks_all) + 1):  # harmonics 1..m: fewer stations afford fewer terms
            for deg in degrees:
                h = _Harmonic(deg, period, ks_all[:m], float(f))
                if h.n_params <= len(x) - 4:  # keep >= 4 degrees of freedom for the LOO score
                    out.append(h)
    return out


def select_range_curve(x: np.ndarray, y: np.ndarray, lam: float | None = None, merge_mm: float = 1.0,
                       model: str = "auto", modulation_mhz=(), max_harmonic: int = 3) -> RangeModelChoice:
    """Fit ``R(d)`` to central deviations ``y`` [mm] at measured distances ``x`` [mm].

    Parameters
    ----------
    x, y : (M,) float [mm]
    lam : smoothing of the spline candidate (None = GCV)
    merge_mm : points closer than this in ``x`` are averaged first
    model : ``"spline"`` (the study's choice), ``"harmonic"`` (best harmonic candidate) or
        ``"auto"`` (best of all by leave-one-out RMS; ties and failures go to the spline)
    modulation_mhz : modulation frequencies of the sensor [MHz] (empty: spline only)
    max_harmonic : highest harmonic of each half wavelength considered

    Returns
    -------
    RangeModelChoice
    """
    if model not in ("auto", "spline", "harmonic"):
        raise ValueError(f"range model must be auto, spline or harmonic, found {model!r}")
    xm, ym, wm = merge_close(x, y, merge_mm)
    spline = smoothing_spline(xm, ym, wm, lam)
    cands = harmonic_candidates(xm, modulation_mhz, max_harmonic) if model != "spline" else []
    scores = {"spline": _loo_rms(lambda a, b, c: smoothing_spline(a, b, c, lam), xm, ym, wm)}
    for h in cands:
        scores[h.name] = _loo_rms(h.fit, xm, ym, wm)
    scored = [h for h in cands if np.isfinite(scores[h.name])]
    if not scored:
        return RangeModelChoice(spline, "spline", scores)
    best = min(scored, key=lambda h: scores[h.name])
    if model == "auto" and not scores[best.name] < scores["spline"]:
        return RangeModelChoice(spline, "spline", scores)
    f = best.fit(xm, ym, wm)
    return RangeModelChoice(_as_bspline(f, float(xm[0]), float(xm[-1])), best.name, scores)
