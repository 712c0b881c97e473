"""The model's scale on a dot mat: the joint fit's scale weighed against the placements' (_mat_scale)."""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct._mat_locate import MatFix
from tofmetry.reconstruct._mat_scale import (ScaleHold, apply_increments, hold_scale, left_increments,
                                             placed_scale, placement_covariance)
from tofmetry.reconstruct._scale_budget import scale_response, view_scale_rows
from tofmetry.simulate.poses import look_at


def _bust_views(n_views: int = 8, distance: float = 0.7, elevation_deg: float = 30.0):
    """A bust (a ball of radius 70 mm, a head of 40 mm on it, 20 mm off its axis, and a knot of 20 mm) standing on z = 0
    (mat frame), seen by a ring of views: (poses (V, 4, 4), world points (N, 3), outward normals
    (N, 3), view (N,))."""
    rng = np.random.default_rng(3)
    balls = [(np.array([0.0, 0.0, 0.07]), 0.07, 6000), (np.array([0.02, 0.0, 0.18]), 0.04, 3000),
             (np.array([0.03, 0.045, 0.12]), 0.02, 1000)]  # body, head, a shoulder's knot
    u = rng.normal(size=(sum(b[2] for b in balls), 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    pts = np.concatenate([u[sum(b[2] for b in balls[:k]):][:n] * r + c for k, (c, r, n) in enumerate(balls)])
    inside = np.zeros(len(pts), bool)
    for c, r, _ in balls:
        inside |= np.linalg.norm(pts - c, axis=1) < r - 1e-9
    pts, nrm = pts[~inside], u[~inside]
    centre = np.array([0.0, 0.0, 0.1])
    el = np.radians(elevation_deg)
    poses, P, N, V = [], [], [], []
    for k in range(n_views):
        az = 2 * np.pi * k / n_views
        cam = centre + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        seen = np.einsum("ij,ij->i", nrm, cam - pts) > 0.2 * np.linalg.norm(cam - pts, axis=1)
        poses.append(look_at(cam, centre))
        P.append(pts[seen])
        N.append(nrm[seen])
        V.append(np.full(seen.sum(), k))
    return np.array(poses), np.concatenate(P), np.concatenate(N), np.concatenate(V)


def _fix(sigma_deg: float, sigma_mm: float, tilt_deg: float) -> MatFix:
    return MatFix(True, n_dots=20, n_matched=20, sigma_deg=sigma_deg, sigma_mm=sigma_mm, how="dots",
                  tilt_sigma_deg=tilt_deg, centre_xy=np.array([0.05, -0.02]))


def test_increments_round_trip():
    poses, *_ = _bust_views()
    rng = np.random.default_rng(0)
    xi = np.c_[rng.normal(0, 0.003, (len(poses), 3)), rng.normal(0, 0.002, (len(poses), 3))]
    np.testing.assert_allclose(left_increments(poses, apply_increments(poses, xi)), xi, atol=1e-12)


def test_a_placement_turned_about_its_dots_moves_them_only_by_its_shift():
    fix = _fix(0.05, 0.2, 0.1)
    C = placement_covariance(fix, 0.5, 0.4e-3)
    # a turn about the vertical through the dots' centroid moves the centroid by nothing: the
    # covariance of the centroid's move (w x c + t) is the shift's alone
    c = np.r_[fix.centre_xy, 0.0]
    J = np.c_[-np.array([[0, -c[2], c[1]], [c[2], 0, -c[0]], [-c[1], c[0], 0]]), np.eye(3)]
    np.testing.assert_allclose(J @ C @ J.T, np.diag([0.2e-3 ** 2, 0.2e-3 ** 2, 0.4e-3 ** 2]), atol=1e-15)
    # a view the dots did not place: the fallback along every axis
    np.testing.assert_allclose(np.diag(placement_covariance(None, 0.5, 3e-3))[3:], [9e-6] * 3)


def test_the_held_scale_is_the_weighted_mean_of_fit_and_placements_with_the_sigma_it_claims():
    """Placements drawn with their covariances, a fit drawn with an error of its own (as a
    calibration residual bends it, independently of the dots): over 400 draws the held scale's
    error has the RMS the hold claims (a chi-square of 400 draws: within +-10 % at about 3 sigma),
    and is smaller than the fit's."""
    truth, P, N, view = _bust_views()
    V = len(truth)
    rows = view_scale_rows(P, N, view, V)
    fixes = [_fix(0.05, 0.25, 0.08) for _ in range(V)]
    covs = np.array([placement_covariance(f, 0.5, 0.4e-3) for f in fixes])
    fit_cov = np.diag(np.tile([np.radians(0.1) ** 2] * 3 + [(0.5e-3) ** 2] * 3, V - 1))
    a = rows[1:].ravel()
    fit_sigma = float(np.sqrt(a @ fit_cov @ a))
    rng = np.random.default_rng(7)
    err_fit, err_held, claimed = [], [], []
    for _ in range(400):
        xi_mat = np.array([rng.multivariate_normal(np.zeros(6), c) for c in covs])
        start = apply_increments(truth, xi_mat)
        xi_fit = np.r_[np.zeros((1, 6)), rng.multivariate_normal(np.zeros(6 * (V - 1)), fit_cov).reshape(-1, 6)]
        fitted = apply_increments(truth, xi_fit)
        held, h = hold_scale(rows, start, fitted, covs, fit_sigma, fit_cov)
        err_fit.append(np.sum(rows * left_increments(truth, fitted)))
        err_held.append(np.sum(rows * left_increments(truth, held)))
        claimed.append(h.held_sigma)
    rms_held, rms_fit = np.sqrt(np.mean(np.square(err_held))), np.sqrt(np.mean(np.square(err_fit)))
    assert abs(rms_fit / fit_sigma - 1) < 0.1
    assert abs(rms_held / np.median(claimed) - 1) < 0.1
    assert rms_held < 0.8 * rms_fit


def test_a_fit_the_placements_cannot_check_is_left_as_it_is():
    truth, P, N, view = _bust_views()
    V = len(truth)
    rows = view_scale_rows(P, N, view, V)
    covs = np.array([placement_covariance(None, 0.5, 3e-3) for _ in range(V)])  # no view placed by dots
    xi = np.r_[np.zeros((1, 6)), np.tile([0, 0, 0, 2e-4, 0, 0], (V - 1, 1))]
    fitted = apply_increments(truth, xi)
    held, h = hold_scale(rows, truth, fitted, covs, 1e-4, None)
    assert abs(h.applied) < 0.05 * abs(h.fit_scale)  # the fit's 0.01 % against placements' far larger sigma
    got, h2 = hold_scale(None, truth, fitted, covs, 1e-4, None)
    assert got is fitted and h2.note and isinstance(h2, ScaleHold)


def test_a_placement_with_no_dots_centroid_has_a_finite_covariance_about_the_sheets_middle():
    """A view placed by the whole pattern has sigmas but no matched dots; a NaN centre there had made
    the whole scan's scale hold 'unknown' (every rocker arm seen by a low ring)."""
    fix = MatFix(True, n_dots=0, n_matched=0, sigma_deg=0.3, sigma_mm=1.5, how="pattern")
    C = placement_covariance(fix, 0.5, 0.4e-3)
    assert np.all(np.isfinite(C))
    np.testing.assert_allclose(np.diag(C)[3:], [1.5e-3 ** 2, 1.5e-3 ** 2, 0.4e-3 ** 2], rtol=1e-12)


def _in_cameras(poses, P, N, view):
    """Per view the world points ``P`` and normals ``N`` (N, 3) of ``view`` (N,) in its camera ``poses`` (V, 4, 4)."""
    inv = np.linalg.inv(poses)
    return ([P[view == k] @ inv[k, :3, :3].T + inv[k, :3, 3] for k in range(len(poses))],
            [N[view == k] @ inv[k, :3, :3].T for k in range(len(poses))])


def test_unrefined_placements_scale_the_model_by_the_sigma_they_claim():
    """Placements drawn with their covariances and kept as the poses: the model's scale, fitted on
    the points they carry against the true surface (rigid motion and normal offset removed, the
    exact moves, not the linear rows), has over 400 draws the RMS :func:`placed_scale` predicts (a
    chi-square of 400 draws: within +-10 % at about 3 sigma)."""
    truth, P, N, view = _bust_views()
    V = len(truth)
    fixes = [_fix(0.05, 0.25, 0.08) if k % 3 else _fix(0.15, 0.6, 0.2) for k in range(V)]
    covs = np.array([placement_covariance(f, 0.5, 0.4e-3) for f in fixes])
    Pc, Nc = _in_cameras(truth, P, N, view)
    h = placed_scale(Pc, Nc, truth, fixes, 0.5, 0.4e-3)
    assert isinstance(h, ScaleHold) and h.applied == 0.0 and np.isfinite(h.mat_sigma) and h.mat_sigma > 0
    rng = np.random.default_rng(11)
    got = []
    for _ in range(400):
        placed = apply_increments(truth, np.array([rng.multivariate_normal(np.zeros(6), c) for c in covs]))
        moved = np.concatenate([Pc[k] @ placed[k, :3, :3].T + placed[k, :3, 3] for k in range(V)])
        got.append(scale_response(P, N, moved - P)[0])
    assert abs(np.sqrt(np.mean(np.square(got))) / h.mat_sigma - 1) < 0.1


def test_placements_on_a_ball_have_no_scale_of_their_own():
    """On a ball scale and offset are one mode: no sigma, and the note says why."""
    rng = np.random.default_rng(5)
    u = rng.normal(size=(4000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    P, N = 0.1 * u + [0, 0, 0.1], u
    poses = np.array([np.eye(4)] * 2)
    h = placed_scale([P[:2000], P[2000:]], [N[:2000], N[2000:]], poses, [_fix(0.05, 0.25, 0.08)] * 2, 0.5, 4e-4)
    assert np.isnan(h.mat_sigma) and "separable" in h.note
    assert "no object points" in placed_scale([P[:3]], [N[:3]], poses[:1], [None], 0.5, 4e-4).note
