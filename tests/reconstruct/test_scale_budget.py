"""The scale budget: depth-error patterns propagated to the model's scale on its own geometry."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.reconstruct._scale_budget import scale_budget, scale_response

from .test_adjust import _look_at


def _ellipsoid(n: int = 4000, axes=(0.2, 0.12, 0.08), seed: int = 0):
    """Points and outward normals of an ellipsoid (a sphere could not tell scale from offset)."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    a = np.asarray(axes)
    p = v * a
    nrm = p / a ** 2
    return p, nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def test_scale_response_recovers_a_scale_an_offset_and_ignores_a_rigid_motion():
    p, n = _ellipsoid()
    c = p.mean(0) + np.array([0.01, -0.02, 0.5])
    p = p + c
    s, o, _ = scale_response(p, n, 0.002 * (p - p.mean(0)))
    assert s == pytest.approx(0.002, abs=1e-9) and o == pytest.approx(0.0, abs=1e-9)
    s, o, _ = scale_response(p, n, 0.0007 * n)
    assert s == pytest.approx(0.0, abs=1e-9) and o == pytest.approx(0.0007, abs=1e-9)
    w = np.array([0.001, -0.002, 0.0015])
    s, o, _ = scale_response(p, n, np.cross(w, p - c) + [0.001, 0.0, -0.002])
    assert s == pytest.approx(0.0, abs=1e-9) and o == pytest.approx(0.0, abs=1e-9)


def test_a_plane_cannot_separate_scale_from_offset():
    rng = np.random.default_rng(1)
    p = np.c_[rng.uniform(-0.1, 0.1, (500, 2)), np.full(500, 1.0)]
    n = np.tile([0.0, 0.0, -1.0], (500, 1))
    s, o, _ = scale_response(p, n, 0.001 * n)
    assert np.isnan(s) and np.isnan(o)


def _views(n_views: int = 8, distance: float = 0.9):
    """An ellipsoid seen from a circle of cameras: each view's visible points in its camera frame."""
    p, n = _ellipsoid(12000)
    pts, nrm, poses = [], [], []
    for a in np.linspace(0, 2 * np.pi, n_views, endpoint=False):
        centre = np.array([distance * np.cos(a), distance * np.sin(a), 0.2])
        T = _look_at(centre, np.zeros(3))
        vis = np.einsum("ij,ij->i", n, centre - p) > 0.05 * distance  # facing the camera
        R, t = T[:3, :3], T[:3, 3]
        pts.append((p[vis] - t) @ R)
        nrm.append(n[vis] @ R)
        poses.append(T)
    return pts, nrm, np.array(poses)


def test_a_gain_about_the_camera_scales_a_single_view_by_the_gain():
    """Z -> Z (1 + g) scales a view about its camera centre: a scale g about the centroid plus a
    translation, whatever the shape."""
    pts, nrm, poses = _views(1)
    b = scale_budget(pts, nrm, poses, 0.0, None, 0.0, 0.001, None)
    assert b["gain"]["response"] == pytest.approx(1.0, rel=1e-6)
    assert b["sigma"] == pytest.approx(0.001, rel=1e-6)
    assert "amplitude" not in b and "not counted" in b["note"]


def test_the_terms_add_in_quadrature_and_a_constant_log_ratio_acts_as_an_offset():
    pts, nrm, poses = _views()
    L = [np.full(len(p), 0.7) for p in pts]
    b = scale_budget(pts, nrm, poses, 0.9, L, 0.5e-3, 0.002, 3e-3)
    assert b["amplitude"]["response"] == pytest.approx(0.7 * b["offset"]["response"], rel=1e-9)
    parts = [b[k]["sigma"] for k in ("offset", "gain", "amplitude")]
    assert b["sigma"] == pytest.approx(np.sqrt(np.sum(np.square(parts))), rel=1e-12)
    assert np.isfinite(b["sigma"]) and b["n_points"] > 1000
