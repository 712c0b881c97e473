"""The scale budget: depth-error patterns propagated to the model's scale on its own geometry."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.reconstruct._scale_budget import PoseUncertainty, pose_scale_response, scale_budget, scale_response

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


def _placed(pts, nrm, poses):
    view = np.repeat(np.arange(len(pts)), [len(p) for p in pts])
    P, N = np.concatenate(pts), np.concatenate(nrm)
    R, t = poses[view, :3, :3], poses[view, :3, 3]
    return np.einsum("nij,nj->ni", R, P) + t, np.einsum("nij,nj->ni", R, N), view


def test_the_pose_response_is_the_scale_of_the_moves_a_pose_increment_makes():
    """Each view's increment (w, t) moves its points by w x p + t; the response, linear in the
    increments, gives the scale :func:`scale_response` fits to those moves, and the views that see
    the +x end moved along +x (those of the -x end along -x) lengthen the model."""
    pts, nrm, poses = _views()
    Pw, Nw, view = _placed(pts, nrm, poses)
    a = pose_scale_response(Pw, Nw, view, len(pts))
    rng = np.random.default_rng(3)
    inc = np.zeros((len(pts), 6))
    inc[1:] = rng.normal(scale=[1e-3] * 3 + [1e-3] * 3, size=(len(pts) - 1, 6))
    moves = np.cross(inc[view, :3], Pw) + inc[view, 3:]
    assert a @ inc[1:].ravel() == pytest.approx(scale_response(Pw, Nw, moves)[0], rel=1e-9, abs=1e-12)
    centre_x = np.array([T[0, 3] for T in poses])
    inc = np.zeros((len(pts), 6))
    inc[:, 3] = 1e-3 * np.sign(centre_x) * (np.abs(centre_x) > 0.1)
    inc[0] = 0.0
    assert a @ inc[1:].ravel() > 0


def test_the_poses_term_counts_their_noise_and_the_field_they_follow():
    """The noise term is ``sqrt(a' C a)``; a field that moves no pose adds nothing but its direct
    moves; the budget's total adds the poses' term in quadrature."""
    pts, nrm, poses = _views()
    Pw, Nw, view = _placed(pts, nrm, poses)
    V = len(pts)
    a = pose_scale_response(Pw, Nw, view, V)
    C = np.diag(np.tile([1e-6] * 3 + [4e-8] * 3, V - 1))
    free = PoseUncertainty(C, np.zeros((6 * (V - 1), 1)), np.array([1e-3]), lambda p: np.ones((len(p), 1)))
    b = scale_budget(pts, nrm, poses, 0.9, None, 1e-3, 0.0, None, max_points=10 ** 6, poses_free=free)
    assert b["poses"]["noise"] == pytest.approx(np.sqrt(a @ C @ a), rel=1e-9)
    assert b["poses"]["field"] == pytest.approx(0.0, abs=1e-15)
    assert b["poses"]["field_total"] == pytest.approx(b["offset"]["sigma"], rel=1e-9)  # a constant field: the offset
    assert b["poses"]["sigma"] == pytest.approx(b["poses"]["noise"], rel=1e-12)
    assert b["sigma"] == pytest.approx(np.hypot(b["sigma_poses_held"], b["poses"]["sigma"]), rel=1e-12)
    assert b["sigma_poses_held"] == pytest.approx(b["offset"]["sigma"], rel=1e-12)
