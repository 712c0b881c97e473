"""Error-model terms: magnitudes documented in tofmetry.simulate.errors, tied to the paper."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.simulate import TERMS, ErrorModel
from tofmetry.simulate import errors as E


def test_switches():
    assert ErrorModel().enabled == frozenset(TERMS)
    assert ErrorModel.none().enabled == {"quantize"}
    assert ErrorModel.none(quantize=False).enabled == frozenset()
    assert ErrorModel.only("wiggling").enabled == {"wiggling", "quantize"}
    assert ErrorModel.only("wiggling", quantize=False).enabled == {"wiggling"}
    em = ErrorModel().without("noise", "flying")
    assert not em.on("noise") and not em.on("flying") and em.on("wiggling")
    assert em.with_terms("noise").on("noise")
    with pytest.raises(InputError, match="unknown error term"):
        ErrorModel().without("nosie")
    with pytest.raises(InputError, match="ambient"):
        ErrorModel(ambient=2.0)
    # JSON round trip
    em2 = ErrorModel.from_dict(em.to_dict())
    assert em2 == em


def test_wiggling_span_matches_paper_fig7a():
    em = ErrorModel()
    z = np.linspace(800, 4500, 3000)
    axis = np.zeros((len(z), 2))  # on the optical axis the ray length is Z: the study's Fig. 7a
    w = E.wiggling_mm(z, em, axis)
    # paper §4.2.2: -1.5 cm .. +7 mm between 0.8 and 4.5 m
    assert -15.5 < w.min() < -13.0
    assert 5.5 < w.max() < 7.5
    # not monotone / not a low-order shape: several sign changes of the slope
    assert np.count_nonzero(np.diff(np.sign(np.diff(w)))) >= 4
    # steep growth past 4.5 m
    assert E.wiggling_mm(5500.0, em, np.zeros(2)) - E.wiggling_mm(4500.0, em, np.zeros(2)) > 15.0


def test_deformation_shape_and_growth():
    from tofmetry.sensor import KINECT_V2

    em = ErrorModel()
    xy = np.asarray(KINECT_V2.depth.ray_table())
    d1 = E.deformation_mm(xy, np.full(xy.shape[:2], 1000.0), em)
    d3 = E.deformation_mm(xy, np.full(xy.shape[:2], 3000.0), em)
    corners1 = [d1[:10, :10].mean(), d1[:10, -10:].mean(), d1[-10:, :10].mean(), d1[-10:, -10:].mean()]
    assert d1[207, 256] < 0  # central disc negative
    assert min(corners1) > 10.0  # > +10 mm in the corners at 1 m
    assert np.ptp(corners1) > 0.5  # not exactly radial
    corners3 = d3[-10:, -10:].mean()
    assert 22.0 < corners3 < 40.0  # ~30 mm at 3 m


def test_amplitude_bias_black_12mm():
    em = ErrorModel()
    assert E.amplitude_bias_mm(1.0, em) == pytest.approx(0.0)
    assert E.amplitude_bias_mm(1 / 6, em) == pytest.approx(12.0)  # paper §3.3.1
    r = np.linspace(0.05, 1, 50)
    assert np.all(np.diff(E.amplitude_bias_mm(r, em)) < 0)  # monotone: darker reads longer


def test_noise_sigma_grows():
    em = ErrorModel()
    s1 = E.noise_sigma_mm(12000.0, 1000.0, em)
    assert 1.0 <= s1 <= 1.5  # ~1-1.5 mm white at 1 m centre
    assert E.noise_sigma_mm(12000.0 / 9, 3000.0, em) > 2.5 * s1 / 1.03
    assert E.noise_sigma_mm(2000.0, 1000.0, em) > s1


def test_warmup_curve():
    em = ErrorModel()
    t = np.arange(0, 5401, 15.0)
    w = E.warmup_mm(t, em)
    assert w[0] == pytest.approx(-5.0, abs=0.3)  # ~5 mm over the first 30 min
    assert np.abs(w[t >= 1800]).max() <= 1.0  # then stable within ~1 mm
    # kink at the fan start (20 min): the slope changes sign
    i = np.searchsorted(t, 1200)
    assert (w[i - 1] - w[i - 3]) > 0 and (w[i + 3] - w[i + 1]) < 0
