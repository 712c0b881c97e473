"""Synthetic truth for the calibration tests (analytic, independent of the simulator's error shapes)."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.sensor import CameraIntrinsics

# A small camera keeps the tests fast; the algorithms do not depend on the resolution.
SMALL = CameraIntrinsics(128, 96, 92.0, 92.0, 63.7, 48.2, (0.08, -0.2, 0.0, 0.0, 0.05))


def range_error_mm(z):
    """Truth range error [mm] of measured-ish depth: offset + slope + one wiggle (not the simulator's)."""
    z = np.asarray(z, float)
    return -14.0 + 2.0 * (z / 1000.0) + 3.0 * np.sin(2 * np.pi * z / 1500.0 + 0.4)


def deformation_mm(intr, z):
    """Truth per-pixel deformation [mm]: an off-centre quartic bowl with a tilt term, growing with range."""
    r = intr.ray_table()
    x, y = r[..., 0] - 0.05, r[..., 1] + 0.03
    q = x * x + 1.2 * y * y
    return (0.4 + 0.6 * z / 1000.0) * (25.0 * q * q + 2.0 * x * y - 1.0)


def render_wall(intr, distance_mm, normal=None):
    """Measured (float) depth of a wall through (0, 0, D) with the truth errors (no noise)."""
    from tofmetry.calibrate import wall_reference

    z = wall_reference(intr, distance_mm, normal)
    return z + range_error_mm(z) + deformation_mm(intr, z)


@pytest.fixture(scope="session")
def small_intr():
    return SMALL


def ray_error_mm(intr, z):
    """Truth range error [mm] of a continuous-wave ToF camera: a function of the ray length
    ``r = z rho`` (offset, slope, a 600 mm wiggle and its harmonic), seen in Z divided by ``rho``."""
    rays = intr.ray_table()
    rho = np.sqrt(1.0 + rays[..., 0] ** 2 + rays[..., 1] ** 2)
    r = np.asarray(z, float) * rho
    w = -9.0 + 1.5 * (r / 1000.0) + 2.5 * np.sin(2 * np.pi * r / 600.0 + 1.1) + 0.8 * np.sin(4 * np.pi * r / 600.0)
    return w / rho


def render_wall_ray(intr, distance_mm, normal=None):
    """Measured (float) depth of a wall with the ray-length range error and the deformation (no noise)."""
    from tofmetry.calibrate import wall_reference

    z = wall_reference(intr, distance_mm, normal)
    return z + ray_error_mm(intr, z) + deformation_mm(intr, z)
