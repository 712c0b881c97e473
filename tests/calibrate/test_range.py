"""Range-error curve models: spline vs modulation harmonics, chosen by leave-one-out."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.calibrate._range import half_wavelength_mm, select_range_curve

STATIONS = np.array([800.0, *np.arange(1000.0, 4501.0, 250.0)])  # the wall stations [mm]
MIDS = (STATIONS[1:-1] + STATIONS[2:]) / 2                       # never fitted


def _wiggle(x, L=half_wavelength_mm(80.0)):
    """A CW-ToF-like wiggle: trend + harmonics 1..3 of the 80 MHz half wavelength [mm]."""
    t = (x - 800) / 1000
    return (-10 + 3 * t + 4.5 * np.sin(2 * np.pi * x / L + 0.02) + 2.5 * np.sin(4 * np.pi * x / L + 3.69)
            + 0.8 * np.sin(6 * np.pi * x / L + 6.15))


def test_half_wavelength():
    assert half_wavelength_mm(80.0) == pytest.approx(1873.7, abs=0.1)


def test_harmonic_model_predicts_between_stations():
    rng = np.random.default_rng(0)
    sigma = 0.15  # per-station noise of a central-patch mean of 50 frames + drift [mm]
    y = _wiggle(STATIONS) + rng.normal(0, sigma, len(STATIONS))
    spline = select_range_curve(STATIONS, y, model="spline")
    auto = select_range_curve(STATIONS, y, model="auto", modulation_mhz=(80.0, 16.0, 120.0))
    assert auto.name.startswith("harmonic 80 MHz"), auto.cv_rms_mm
    e_auto = np.abs(auto.spline(MIDS) - _wiggle(MIDS)).max()
    e_spline = np.abs(spline.spline(MIDS) - _wiggle(MIDS)).max()
    # least squares with p = 8 parameters on n = 16 stations: prediction error ~ sigma sqrt(p/n)
    # ~ 0.1 mm, 3.5 sigma bound; the spline cannot resolve the 0.62 m harmonic (~0.7 mm misses)
    assert e_auto < 3.5 * sigma * np.sqrt(8 / 16), e_auto
    assert e_spline > 2 * e_auto, (e_spline, e_auto)
    assert auto.cv_rms_mm[auto.name] < auto.cv_rms_mm["spline"]


def test_non_periodic_error_keeps_a_good_model():
    """An error that is not periodic in the modulation wavelengths: whatever is chosen must
    predict the unfitted midpoints about as well as the study's spline."""
    f = lambda x: -12 + 8 * np.exp(-(x - 800) / 700) + 1.5 * ((x - 2600) / 1000) ** 2  # noqa: E731
    y = f(STATIONS)
    auto = select_range_curve(STATIONS, y, model="auto", modulation_mhz=(80.0,))
    spline = select_range_curve(STATIONS, y, model="spline")
    e_auto = np.abs(auto.spline(MIDS) - f(MIDS)).max()
    e_spline = np.abs(spline.spline(MIDS) - f(MIDS)).max()
    assert auto.cv_rms_mm[auto.name] <= auto.cv_rms_mm["spline"]
    assert e_auto <= max(2 * e_spline, 0.05), (auto.name, e_auto, e_spline)


def test_unknown_modulation_is_the_spline():
    y = _wiggle(STATIONS)
    ch = select_range_curve(STATIONS, y, modulation_mhz=())
    assert ch.name == "spline" and list(ch.cv_rms_mm) == ["spline"]
    # too few stations for any harmonic model with 4 spare degrees of freedom
    few = select_range_curve(STATIONS[::4], y[::4], modulation_mhz=(80.0,))
    assert few.name == "spline"


def test_stored_bspline_matches_the_model():
    y = _wiggle(STATIONS)
    ch = select_range_curve(STATIONS, y, model="harmonic", modulation_mhz=(80.0,))
    x = np.linspace(STATIONS[0], STATIONS[-1], 2001)
    # noise-free data from the model family: the fit is exact and the 20 mm cubic
    # interpolation of it errs by ~(5/384) h^4 |R''''| < 1e-3 mm
    assert np.abs(ch.spline(x) - _wiggle(x)).max() < 1e-3


def test_bad_model_name():
    with pytest.raises(ValueError, match="range model"):
        select_range_curve(STATIONS, _wiggle(STATIONS), model="poly")
