"""The support plane as one plane: the global adjustment's term holding the views' tilts."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tofmetry.reconstruct import global_adjust
from tofmetry.reconstruct._adjust_support import moved_about_vertical, support_plane_terms, world_planes
from tofmetry.reconstruct._adjust_terms import AdjustView

from .test_adjust import _look_at


def _ring(n_views: int = 6, distance: float = 0.9, height: float = 0.5):
    """Cameras on a circle above the plane z = 0, looking at the origin; each view's plane in its frame."""
    poses, planes = [], []
    for a in np.linspace(0, 2 * np.pi, n_views, endpoint=False):
        T = _look_at(np.array([distance * np.cos(a), distance * np.sin(a), height]), np.zeros(3))
        R, t = T[:3, :3], T[:3, 3]
        n_c = R.T @ np.array([0.0, 0.0, 1.0])  # the world's up in the camera frame
        planes.append(np.r_[n_c, t[2]])  # up . (R p + t) = 0  <=>  (R' up) . p + t_z = 0
        poses.append(T)
    return np.array(poses), planes


def _tilted(T, deg, axis=(1.0, 0.0, 0.0), shift=(0.0, 0.0, 0.0)):
    E = np.eye(4)
    E[:3, :3] = Rotation.from_rotvec(np.radians(deg) * np.asarray(axis)).as_matrix()
    E[:3, 3] = shift
    return E @ T


def test_the_true_poses_put_every_view_on_one_plane_and_feel_no_pull():
    poses, planes = _ring()
    idx, n, d = world_planes(poses, planes)
    assert len(idx) == 6 and np.allclose(n, [0, 0, 1], atol=1e-12) and np.allclose(d, 0, atol=1e-12)
    H, b, info = support_plane_terms(poses, planes, np.radians(0.1), 5e-4, 1.0)
    assert np.abs(np.linalg.lstsq(H, b, rcond=1e-10)[0]).max() < 1e-12 and info["spread_deg"] < 1e-6  # no step
    assert H.shape == (30, 30) and np.allclose(H, H.T)


def test_a_step_of_the_term_takes_a_tilted_and_lifted_view_back_to_the_plane():
    """The camera poses as seen, view 3 tilted 0.8 deg and 2 mm too high: one Gauss-Newton step of
    the term alone (its null space, the turn about the vertical and the shifts along the plane, left
    alone) puts its plane back on the others'."""
    poses, planes = _ring()
    bad = poses.copy()
    bad[3] = _tilted(poses[3], 0.8, (0.6, 0.8, 0.0), (0.0, 0.0, 0.002))
    H, b, info = support_plane_terms(bad, planes, np.radians(0.1), 5e-4, 1.0)
    assert info["spread_deg"] > 0.6 and info["spread_mm"] > 1.0
    dx = -np.linalg.lstsq(H, b, rcond=1e-10)[0]
    step = np.eye(4)
    step[:3, :3] = Rotation.from_rotvec(dx[12:15]).as_matrix()
    step[:3, 3] = dx[15:18]
    fixed = bad.copy()
    fixed[3] = step @ bad[3]
    _, n, d = world_planes(fixed, planes)
    assert np.degrees(np.arccos(np.clip(n[3] @ n[0], -1, 1))) < 0.01
    assert abs(d[3] - d[0]) < 2e-5
    assert np.allclose(dx[:12], 0, atol=1e-9) and np.allclose(dx[18:], 0, atol=1e-9)  # the others stay


def test_views_without_a_plane_are_left_out_of_the_term():
    poses, planes = _ring(3)
    planes[1] = None
    H, b, info = support_plane_terms(poses, planes, np.radians(0.1), 5e-4, 1.0)
    assert info["n_views"] == 2 and np.allclose(H[:6, :6], 0)
    H, b, info = support_plane_terms(poses, [planes[0], None, None], np.radians(0.1), 5e-4, 1.0)
    assert info == {"n_views": 1} and not H.any()


def test_the_terms_weigh_like_a_prior_of_the_given_sigmas():
    """Two views: the term on view 1 is the difference of two planes, each within sigma: its
    information on the height is weight / (2 sigma^2) per unit of n . dt."""
    poses, planes = _ring(2)
    H, _, _ = support_plane_terms(poses, planes, np.radians(0.2), 1e-3, 4.0)
    assert H[3:6, 3:6] == pytest.approx(4.0 / (2 * 1e-6) * np.outer([0, 0, 1], [0, 0, 1]), abs=1e-3)


def _dome_views(poses, rng, n=20000, radius=0.1, centre=(0.0, 0.0, 0.06), noise_m=5e-4):
    """Each view's own samples of the part of a sphere above the plane z = 5 mm that it faces, in
    its camera frame, with depth noise: a dome whose points leave every rotation about its centre
    free. (The term weighs against the points' residual variance: noise-free points would outweigh it.)"""
    out = []
    c0 = np.asarray(centre)
    for T in poses:
        u = rng.normal(size=(n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        out.append(_seen_from(T, c0 + radius * u, u, rng, noise_m))
    return out


def _seen_from(T, p, nrm, rng, noise_m):
    """The surface samples ``p`` (outward normals ``nrm``, world [m]) above z = 5 mm that the camera at
    ``T`` faces, in its camera frame with depth noise along the rays: an AdjustView (every 4th as source)."""
    vis = (p[:, 2] > 0.005) & (np.einsum("ij,ij->i", nrm, T[:3, 3] - p) > 0.2)
    Ti = np.linalg.inv(T)
    pc, nc = p[vis] @ Ti[:3, :3].T + Ti[:3, 3], nrm[vis] @ Ti[:3, :3].T
    pc *= 1 + rng.normal(scale=noise_m, size=(len(pc), 1)) / pc[:, 2:3]
    return AdjustView(pc[::4], nc[::4], pc, nc)


def test_on_a_dome_the_planes_hold_the_tilts_its_points_leave_free():
    """Views of a dome started with their tilts 0.6 deg off about its centre: its points leave every
    rotation about the centre nearly free (measured: the fit without the term walks 9-36 deg away
    on the noise's pull). With the support planes held to one plane within 0.1 deg, every view ends
    within 0.35 deg of its true tilt (measured 0.11-0.24 deg: the planes' spread ends at 0.14 deg,
    the noise pulling them about one sigma apart), and within 0.01 deg with 0.01 deg."""
    rng = np.random.default_rng(4)
    poses, planes = _ring(6, 0.8, 0.45)
    centre = np.array([0.0, 0.0, 0.06])
    views = _dome_views(poses, rng)
    start = [poses[0]]
    for k, T in enumerate(poses[1:]):
        about = np.eye(4)
        about[:3, 3] = centre
        axis = np.cross([0.0, 0.0, 1.0], rng.normal(size=3))
        start.append(about @ _tilted(np.linalg.inv(about) @ T, 0.6, axis / np.linalg.norm(axis)))
    start = np.array(start)

    def tilt_error(P):
        up = np.array([0.0, 0.0, 1.0])
        return max(np.degrees(np.arccos(np.clip((Q[:3, :3] @ np.linalg.inv(T[:3, :3]) @ up) @ up, -1, 1)))
                   for Q, T in zip(P, poses))

    free = global_adjust(views, start, 0.8, estimate_gain=False)
    held = global_adjust(views, start, 0.8, estimate_gain=False, support_planes=planes, support_sigma=(0.1, 5e-4))
    tight = global_adjust(views, start, 0.8, estimate_gain=False, support_planes=planes, support_sigma=(0.01, 5e-5))
    assert tilt_error(free.poses) > 5.0
    assert tilt_error(held.poses) < 0.35 and tilt_error(tight.poses) < 0.01
    assert held.support_plane["used"] and held.support_plane["start"]["spread_deg"] > 0.3
    assert held.support_plane["end"]["spread_deg"] < 0.2
    assert free.support_plane == {"used": False, "note": "not asked for"}


def test_a_move_is_split_into_its_turn_about_the_vertical_and_its_tilt():
    """View 2 turned 0.3 deg about the vertical through the origin and tilted 0.5 deg: the part
    about the vertical is 0.3 deg; a view upside down is left out of the common plane."""
    poses, planes = _ring(4)
    end = poses.copy()
    end[2] = _tilted(_tilted(poses[2], 0.3, (0.0, 0.0, 1.0)), 0.5, (1.0, 0.0, 0.0))
    turn = moved_about_vertical(poses, end, planes)
    assert turn[2] == pytest.approx(0.3, abs=0.01) and np.allclose(turn[[0, 1, 3]], 0.0, atol=1e-9)
    flipped = end.copy()
    flipped[3] = _tilted(poses[3], 180.0, (1.0, 0.0, 0.0))
    _, _, info = support_plane_terms(flipped, planes, np.radians(0.1), 5e-4, 1.0)
    assert info["off_plane"] == [3] and info["n_views"] == 3
