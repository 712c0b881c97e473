"""The support curve as a function of the measured ray length (``flat_support_curve(..., variable="radial")``).

A continuous-wave ToF camera measures the phase of the light's path, so its range error wiggles in the ray
length ``r = Z rho`` (``rho = sqrt(1 + x^2 + y^2)``), not in Z. On a floor, the points at an object's depth
are seen on the rows below it, where ``rho`` reaches 1.1: at one Z their error is the wiggle's at a ray
length up to 10 % longer. Geometry -> range error in the ray length -> recover at the image's centre.
"""

import numpy as np
import pytest

from tests.calibrate.test_flat_support import floor_depths, nonlinear_part, wiggle_mm
from tofmetry.calibrate import flat_support_curve
from tofmetry.errors import InputError

CAMERAS = [(0.30, 20, 0), (0.40, 28, 3), (0.50, 35, -2), (0.35, 45, 1), (0.60, 60, 0), (0.45, 25, -4)]


def rho(xy: np.ndarray) -> np.ndarray:
    return np.sqrt(1.0 + xy[:, 0] ** 2 + xy[:, 1] ** 2)


def views_with_a_ray_wiggle(noise_mm: float = 1.0, seed: int = 2):
    """Floor views whose depth is off by ``wiggle_mm`` of the true ray length (the error taken in Z)."""
    rng = np.random.default_rng(seed)
    Z, XY = [], []
    for h, p, r in CAMERAS:
        z, xy = floor_depths(h, p, r)
        Z.append(z + wiggle_mm(z * rho(xy)) + rng.normal(0, noise_mm, len(z)))
        XY.append(xy)
    return Z, XY


def test_a_wiggle_in_the_ray_length_comes_back_at_the_image_centre():
    Z, XY = views_with_a_ray_wiggle()
    radial = flat_support_curve(Z, XY, variable="radial")
    single = flat_support_curve(Z, XY)
    z = np.linspace(600.0, 1500.0, 46)  # where an object stands (the support's far end holds few points)
    axis = np.zeros((len(z), 2))  # on the optical axis the ray length is Z: the same truth for both curves
    # (each its part orthogonal to 1, Z and Z^2 over its own span)
    # a curve in Z reads the wiggle where the floor is seen, at rays 2-10 % longer: a 470 mm sine of 2.5 mm
    # comes back shifted in phase by up to 0.1 m at 1 m, millimetres off at the centre
    assert np.max(np.abs(single.error_mm(z) - nonlinear_part(wiggle_mm, *single.span_mm, z))) > 1.0
    # in the ray length it comes back as a wiggle in Z does (0.1 mm, test_flat_support)
    assert np.max(np.abs(radial.error_mm(z, axis) - nonlinear_part(wiggle_mm, *radial.span_mm, z))) < 0.1
    # the gain an object at the centre sees: the sine's slope (up to 3.3 %) within 0.1 %; in Z, 1-3 % off
    zz = np.array([700.0, 800.0, 900.0])

    def slope(span):
        return (nonlinear_part(wiggle_mm, *span, zz + 1) - nonlinear_part(wiggle_mm, *span, zz - 1)) / 2

    g, s = radial.gain(zz, np.zeros((3, 2)))
    assert np.max(np.abs(g - slope(radial.span_mm))) < 1e-3 and np.all(s < 1e-3)
    assert np.max(np.abs(single.gain(zz)[0] - slope(single.span_mm))) > 1e-2
    # off the axis the same curve is read at the point's own ray length, its slope in Z times rho
    xy = np.tile([[0.3, 0.4]], (3, 1))
    g_off, _ = radial.gain(zz, xy)
    g_at, _ = radial.gain(zz * rho(xy), np.zeros((3, 2)))
    assert np.allclose(g_off, g_at * rho(xy), rtol=1e-9)
    d = radial.to_dict()
    assert d["variable"] == "radial" and "ray length" in d["model"]


def test_a_wiggle_in_z_is_still_read_by_a_curve_in_z():
    """The variable is a choice, not a fix: where the range error is a function of Z, a curve in Z is right
    and one in the ray length is off by the phase shift the other way."""
    rng = np.random.default_rng(4)
    Z, XY = [], []
    for h, p, r in CAMERAS:
        z, xy = floor_depths(h, p, r)
        Z.append(z + wiggle_mm(z) + rng.normal(0, 1.0, len(z)))
        XY.append(xy)
    single = flat_support_curve(Z, XY)
    radial = flat_support_curve(Z, XY, variable="radial")
    z = np.linspace(600.0, 1500.0, 46)
    assert np.max(np.abs(single.error_mm(z) - nonlinear_part(wiggle_mm, *single.span_mm, z))) < 0.1
    assert np.max(np.abs(radial.error_mm(z, np.zeros((len(z), 2)))
                         - nonlinear_part(wiggle_mm, *radial.span_mm, z))) > 0.5


def test_a_radial_curve_needs_the_rays_and_a_known_variable():
    Z, XY = views_with_a_ray_wiggle()
    radial = flat_support_curve(Z, XY, variable="radial")
    with pytest.raises(InputError, match="ray length"):
        radial.error_mm(np.array([800.0]))
    with pytest.raises(InputError, match="variable must be one of"):
        flat_support_curve(Z, XY, variable="range")
