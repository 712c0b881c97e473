"""The IR albedo as a term of the global adjustment: it fixes the rotation a surface of revolution leaves free."""

from __future__ import annotations

import numpy as np

from tofmetry.errors import EstimationError
from tofmetry.reconstruct import global_adjust, rotation_angle_deg
from tofmetry.reconstruct._adjust_albedo import albedo_gradients, weak_bases

from .test_adjust import _look_at
from .test_adjust_prior import _about_axis, _views


def _painted(centres: np.ndarray, width_m: float):
    """Log albedo of a vase painted with dark blobs (-1.1, a factor 3 darker) of ``width_m`` at ``centres``."""
    def albedo(p: np.ndarray) -> np.ndarray:
        d2 = ((p[:, None, :] - centres[None]) ** 2).sum(-1)
        return -1.1 * np.exp(-d2 / (2 * width_m ** 2)).max(1)
    return albedo


def _painted_scan(rng, albedo, noise_m=0.5e-3, albedo_noise=0.05, n=30000):
    """Five views of the vase 40 deg apart (test_adjust_prior's), each point with the log albedo of where it lies
    (its median removed per view, as :func:`log_albedo` does) plus noise."""
    ang = np.radians([0, 40, 80, 120, 160])
    poses = np.array([_look_at(np.array([0.9 * np.cos(a), 0.9 * np.sin(a), 0.45]), np.array([0, 0, 0.12]))
                      for a in ang])
    views = _views(poses, rng, noise_m, n)
    for v, T in zip(views, poses):
        a = albedo(v.target @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, albedo_noise, len(v.target))
        v.target_ir = a - np.median(a)
        v.source_ir = v.target_ir[::3]  # the source cloud is every third target point
    rel = np.array([np.linalg.inv(poses[0]) @ T for T in poses])
    return views, rel, poses[0]


def test_gradient_of_a_linear_albedo_lies_in_the_tangent_plane():
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-0.05, 0.05, (2000, 2)), np.zeros(2000)]  # the plane z = 0
    n = np.tile([0.0, 0.0, 1.0], (2000, 1))
    g_true = np.array([8.0, -3.0, 5.0])  # per m; its normal part (5) is not seen on the plane
    g = albedo_gradients(p, n, p @ g_true)
    assert np.allclose(g[:, :2], g_true[:2], atol=1e-6) and np.allclose(g[:, 2], 0.0, atol=1e-9)


def test_the_albedo_holds_the_rotation_about_the_axis_that_the_geometry_leaves_free():
    """Five noisy views of a painted vase (0.5 mm depth noise, 0.05 albedo noise, 12 dark blobs 20 mm
    wide), started at the truth except views 2 and 4, turned 1.5 and -2 deg about the vase's axis.

    Geometry alone walks off: a surface of revolution matches itself at any turn, and the noise's
    pull decides (measured 45-60 deg from the truth on three seeds, or so far that the views part).
    With the albedo term every view ends within 1.5 deg, on all six degrees of freedom and about the
    vertical only: measured 0.38-1.01 and 0.46-1.32 deg on three seeds (0.70 deg about the vertical
    on this one). That is 2-5 times the predicted standard error (0.14-0.25 deg with the inflation
    of 5): the nearest-neighbour correspondences of noisy depth pull along the free direction, and
    the albedo term, weighed at its own noise, holds against that pull only so far (0.05-0.09 deg
    with an albedo noise of 0.02; 0.04 deg without depth noise). A bound, not a precision.
    """
    rng = np.random.default_rng(7)
    h = rng.uniform(0.03, 0.22, 12)
    t = rng.uniform(0, 2 * np.pi, 12)
    r = 0.08 + 0.02 * np.sin(h * 25.0)
    albedo = _painted(np.c_[r * np.cos(t), r * np.sin(t), h], 0.02)
    views, rel, T0 = _painted_scan(rng, albedo)
    to_vase = np.linalg.inv(T0)
    start = rel.copy()
    start[2] = to_vase @ _about_axis(T0 @ rel[2], 1.5)
    start[4] = to_vase @ _about_axis(T0 @ rel[4], -2.0)
    alb = global_adjust(views, start, 0.9, estimate_gain=False, sigma_inflation=5.0, albedo=True)
    err = [rotation_angle_deg(np.linalg.inv(rel[k]) @ P) for k, P in enumerate(alb.poses)]
    assert max(err) < 1.5, err
    # the same about the vertical only (the vase's axis, world z, in view 0's frame)
    yaw = global_adjust(views, start, 0.9, estimate_gain=False, sigma_inflation=5.0, albedo=True,
                        up=to_vase[:3, :3] @ np.array([0.0, 0.0, 1.0]))
    err = [rotation_angle_deg(np.linalg.inv(rel[k]) @ P) for k, P in enumerate(yaw.poses)]
    assert max(err) < 1.5, err
    # only along the directions where the albedo tells more than the geometry: the turn about the axis
    weak = global_adjust(views, start, 0.9, estimate_gain=False, sigma_inflation=5.0, albedo=True, albedo_weak_ratio=1.0)
    err = [rotation_angle_deg(np.linalg.inv(rel[k]) @ P) for k, P in enumerate(weak.poses)]
    assert max(err) < 1.5, err
    assert weak.albedo["weak_directions"] == [0, 1, 1, 1, 1]
    assert alb.albedo["used"] and alb.albedo["n"] > 1000
    assert alb.to_dict([f"{k:02d}" for k in range(5)])["albedo"]["used"]
    try:
        geo = global_adjust(views, start, 0.9, estimate_gain=False, sigma_inflation=5.0)
    except EstimationError:  # walked so far that the views no longer overlap
        return
    assert not geo.albedo["used"]
    assert max(rotation_angle_deg(np.linalg.inv(rel[k]) @ P) for k, P in enumerate(geo.poses)) > 5.0


def test_views_without_albedo_leave_the_term_off():
    rng = np.random.default_rng(1)
    views, rel, _ = _painted_scan(rng, lambda p: np.zeros(len(p)), n=8000)
    views[1].source_ir = None
    res = global_adjust(views, rel, 0.9, estimate_gain=False, albedo=True)
    assert not res.albedo["used"] and "no albedo" in res.albedo["note"]


def test_the_weak_direction_of_a_surface_of_revolution_is_the_turn_about_its_axis():
    """Point-to-plane rows of a vase (radius 0.1 + 0.03 sin(20 h) m, axis z through c) leave one direction
    free, the turn about that axis: (w, t) = (z, -z x c) as a left increment. An albedo term of a thousandth
    of the geometry's information on all six degrees of freedom tells more than the geometry there only."""
    rng = np.random.default_rng(3)
    c = np.array([0.05, 0.02, 1.0])
    a, h = rng.uniform(0, 2 * np.pi, 5000), rng.uniform(-0.1, 0.1, 5000)
    radial = np.c_[np.cos(a), np.sin(a), np.zeros(5000)]
    p = c + (0.1 + 0.03 * np.sin(20 * h))[:, None] * radial + np.c_[np.zeros((5000, 2)), h]
    n = radial - np.c_[np.zeros((5000, 2)), 0.6 * np.cos(20 * h)]  # (cos a, sin a, -dr/dh)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    J = np.c_[np.cross(p, n), n]
    H = np.zeros((7, 7))
    H[:6, :6] = J.T @ J
    g = np.cross(n, rng.normal(size=(5000, 3)))  # albedo gradients in the tangent planes
    Ja = np.c_[np.cross(p, g), g]
    Ha = np.zeros((7, 7))
    Ha[:6, :6] = 1e-3 * np.trace(H) / np.trace(Ja.T @ Ja) * (Ja.T @ Ja)
    bases = weak_bases(H, 2, c, 0.1, 1.0, Ha)
    assert bases[0] is None
    G, Q = bases[1]
    assert G.shape == (6, 1) and Q.shape == (6, 1)
    turn = np.r_[0.0, 0.0, 1.0, -np.cross([0.0, 0.0, 1.0], c)]
    cos = abs(G[:, 0] @ turn) / np.linalg.norm(G[:, 0]) / np.linalg.norm(turn)
    assert cos > 0.999, cos
    assert np.isclose(float(Q[:, 0] @ G[:, 0]), 1.0)  # a = Q^T G a
