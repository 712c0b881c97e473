"""The support plane moved onto the support at the object's depths (tofmetry.reconstruct._mat_level)."""

import numpy as np

from tofmetry.reconstruct._mat_level import plane_at_depth


def _floor(h_m: float, error_mm, seed: int = 0) -> np.ndarray:
    """A level floor ``h_m`` below the camera (camera frame, y down), seen over 0.5-2 m, each point moved
    along its ray by ``error_mm(Z)`` [mm] (a range error that changes with depth), with 0.5 mm of noise."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.5, 2.0, 200_000)
    x = rng.uniform(-0.6, 0.6, z.size) * z
    p = np.c_[x, np.full(z.size, h_m), z]
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    return p + 1e-3 * (error_mm(z) + rng.normal(0.0, 0.5, z.size))[:, None] * u


def test_offset_read_at_the_depth():
    # a range error growing with depth: +0.5 mm at 1 m, +2.5 mm at 2 m (the floor's fit would carry its slope)
    h = 0.45
    pts = _floor(h, lambda z: 0.5 + 2.0 * (z - 1.0))
    plane = np.array([0.0, -1.0, 0.0, h])  # the true plane, normal toward the camera
    out, moved, n = plane_at_depth(plane, pts, 1.0, 0.1)
    # at Z = 1 m the rays meet the floor at |p| ~ sqrt(1 + h^2 + x^2): the error's part along the normal is
    # 0.5 mm times h / |p|, away from the camera; the band's +-0.1 m of depth spreads it by +-0.2 mm
    expected = -0.5 * h / np.sqrt(1.0 + h ** 2 + 0.12)
    assert n > 1000
    assert abs(moved - expected) < 0.08
    np.testing.assert_allclose(out[:3], plane[:3])
    assert abs(1e3 * (out[3] - plane[3]) + moved) < 1e-9


def test_too_few_points_leave_the_plane():
    pts = _floor(0.45, lambda z: 0.0 * z)
    plane = np.array([0.0, -1.0, 0.0, 0.45])
    out, moved, n = plane_at_depth(plane, pts[:100], 1.0, 0.1)
    assert moved == 0.0 and n < 500
    np.testing.assert_array_equal(out, plane)
