"""Point clouds projected on their local planes: noise out, shape kept, nearest-point bias gone."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.pointcloud import move_onto_points, project_to_local_planes


def _plane(rng, n=20000, sigma=1e-3, spacing=2.5e-3):
    side = np.sqrt(n) * spacing
    xy = rng.uniform(0, side, (n, 2))
    return np.column_stack([xy, rng.normal(size=n) * sigma])


def test_noise_along_the_normal_drops_where_the_sampling_is_wider_than_the_noise():
    """A plane sampled every ~2.5 mm (the ICP voxel) with 0.5 mm of noise along its normal: after
    projection on planes of 12 neighbours the noise is between sqrt(1 / 12) = 0.29 (the plane
    through 12 noisy points is off by sigma / sqrt(12) at their centroid) and sqrt(2 / 12) = 0.41
    of it (its tilt adds as much at a point one neighbourhood radius out); bound 0.42."""
    rng = np.random.default_rng(0)
    p = _plane(rng, sigma=0.5e-3)
    q = project_to_local_planes(p, 12)
    assert np.std(q[:, 2]) < 0.42 * np.std(p[:, 2]), (np.std(q[:, 2]), np.std(p[:, 2]))


def test_a_convex_surface_shrinks_by_half_the_sagitta():
    """A noise-free sphere of 50 mm radius, 2500 points (spacing s = sqrt(area / N) = 3.5 mm): the
    points move inward by ~k s^2 / (4 pi R) = 0.24 mm on average (the plane through a patch lies
    inside the sphere); within 0.5-1.5 of it. Random sampling makes some neighbourhoods lopsided:
    no point moves inward by more than 4 times it, or outward by more than half of it."""
    rng = np.random.default_rng(1)
    u = rng.normal(size=(2500, 3))
    R = 0.05
    p = R * u / np.linalg.norm(u, axis=1, keepdims=True)
    q = project_to_local_planes(p, 12)
    shift = np.linalg.norm(q, axis=1) - R
    expected = 12 * (4 * np.pi * R ** 2 / len(p)) / (4 * np.pi * R)
    assert 0.5 * expected < -shift.mean() < 1.5 * expected, (-shift.mean(), expected)
    assert -shift.min() < 4 * expected and shift.max() < 0.5 * expected, (shift.min(), shift.max(), expected)


def test_input_is_not_modified():
    rng = np.random.default_rng(3)
    p = _plane(rng, n=500)
    before = p.copy()
    project_to_local_planes(p, 8)
    np.testing.assert_array_equal(p, before)


def test_bad_input_is_named():
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        project_to_local_planes(np.zeros((10, 2)))
    with pytest.raises(InputError, match="k must be >= 3"):
        project_to_local_planes(np.zeros((10, 3)), 2)
    p = np.zeros((5, 3))
    assert project_to_local_planes(p, 12) is not None


def _edge(spacing=2.5e-3, half=0.06):
    """A noise-free convex 90-degree edge along y: the faces z = 0 (x < 0, normal +z) and x = 0
    (z < 0, normal +x), sampled on a grid of ``spacing``; points and their normals."""
    g = np.arange(-half, half + 1e-9, spacing)
    s = np.arange(-half, 0.0, spacing)
    top = np.array([[x, y, 0.0] for x in s for y in g])
    side = np.array([[0.0, y, z] for z in s for y in g])
    pts = np.vstack([top, side])
    nrm = np.vstack([np.tile([0.0, 0.0, 1.0], (len(top), 1)), np.tile([1.0, 0.0, 0.0], (len(side), 1))])
    return pts, nrm


def test_a_plane_through_an_edge_cuts_it_and_the_normal_gate_keeps_each_face():
    """Next to a convex edge, 12 neighbours span both faces, and the plane through them cuts the
    edge: the points within a neighbourhood of it move off their faces (at 2.5 mm spacing the edge's
    own points by 1.8 mm; bound 0.5 mm). With the points' normals and a 30-degree gate each
    plane is fitted to the point's own face, which is exact here: no point moves (1e-9 m)."""
    p, n = _edge()
    moved = np.linalg.norm(project_to_local_planes(p, 12) - p, axis=1)
    assert moved.max() > 0.5e-3, moved.max()
    kept = np.linalg.norm(project_to_local_planes(p, 12, n, 30.0) - p, axis=1)
    assert kept.max() < 1e-9, kept.max()


def test_the_normal_gate_still_takes_the_noise_out_of_a_face():
    """On a flat face every neighbour passes the gate: the noise drops as without it (bound as in
    the test above, 0.42 of it)."""
    rng = np.random.default_rng(4)
    p = _plane(rng, sigma=0.5e-3)
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    q = project_to_local_planes(p, 12, n, 30.0)
    assert np.std(q[:, 2]) < 0.42 * np.std(p[:, 2])


def test_normals_of_another_shape_are_named():
    with pytest.raises(InputError, match="normals must be"):
        project_to_local_planes(np.zeros((20, 3)), 12, np.zeros((10, 3)), 30.0)


def _sphere_points(n: int, radius: float, noise: float, rng) -> np.ndarray:
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    return u * (radius + rng.normal(0.0, noise, n))[:, None]


def test_a_surface_off_its_samples_is_moved_onto_them():
    """A sphere of 50 mm sampled at ~1 mm spacing with 0.3 mm of noise; the surface's vertices 0.5 mm
    outside. Moved with a 2 mm cylinder they lie on the samples: the median of ~12 samples (0.3 mm
    noise: 0.1 mm each, 0.002 mm over 2000 vertices) and the curvature's inward bias
    ``radius^2 / (4 R)`` = 0.02 mm."""
    rng = np.random.default_rng(0)
    R = 0.05
    pts = _sphere_points(40_000, R, 0.3e-3, rng)
    n = _sphere_points(2000, 1.0, 0.0, rng)
    V, move = move_onto_points(n * (R + 0.5e-3), n, pts, 2e-3, 2e-3)
    err = (np.linalg.norm(V, axis=1) - R) * 1e3
    assert np.isfinite(move).mean() > 0.99  # a vertex with fewer than 5 samples stays
    assert abs(err.mean() + 0.02) < 0.01, err.mean()
    assert np.percentile(np.abs(err), 95) < 0.3


def test_a_second_surface_in_the_band_does_not_pull_the_vertex():
    """Two parallel planes 1.5 mm apart, the far one sampled three times more sparsely; a vertex 0.2 mm
    off the near plane with a band (2 mm) reaching both: the median stays with the near plane's
    majority. A vertex with fewer samples than ``min_points`` stays where it is."""
    rng = np.random.default_rng(1)
    near = np.c_[rng.uniform(-0.01, 0.01, (3000, 2)), np.zeros(3000)]
    far = np.c_[rng.uniform(-0.01, 0.01, (1000, 2)), np.full(1000, -1.5e-3)]
    V, move = move_onto_points(np.array([[0.0, 0.0, 0.2e-3], [0.5, 0.5, 0.5]]), np.array([[0, 0, 1.0], [0, 0, 1.0]]),
                               np.r_[near, far], 1e-3, 2e-3)
    assert abs(V[0, 2]) < 1e-5 and np.isnan(move[1]) and np.allclose(V[1], 0.5)


def test_move_onto_points_names_a_bad_input():
    with pytest.raises(InputError, match="normals must be"):
        move_onto_points(np.zeros((3, 3)), np.zeros((2, 3)), np.zeros((5, 3)), 1e-3, 1e-3)
    with pytest.raises(InputError, match="radius and band"):
        move_onto_points(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((5, 3)), 0.0, 1e-3)
