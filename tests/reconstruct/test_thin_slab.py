"""The thin-slab check (:mod:`tofmetry.reconstruct._thin_slab`): views of a slab's two faces that share
only its rim leave its thickness free; views that share a face, or a corner's three faces, do not."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.path import Path

from tofmetry.reconstruct._thin_slab import slab_reason, split_along, thin_slab_check, translation_stiffness
from tofmetry.reconstruct._regview import RegView

STEP = 0.0025  # sample spacing of the surfaces [m], the ICP voxel


def _outline(n: int = 400) -> np.ndarray:
    """An irregular closed outline (200 x 150 mm, bumps of 8 %), (n, 2) [m]."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 1 + 0.08 * np.cos(3 * t + 0.4) + 0.05 * np.cos(5 * t + 1.3)
    return np.stack([0.10 * r * np.cos(t), 0.075 * r * np.sin(t)], 1)


def _slab(thick_m: float = 0.03):
    """Points and outward normals of a slab swept along z: front face z = 0, back face z = thick, and
    its rim. Returns (front, rim, back), each ((N, 3), (N, 3)) [m]."""
    o = _outline()
    xs = np.arange(-0.12, 0.12, STEP)
    X, Y = np.meshgrid(xs, xs)
    inside = Path(o).contains_points(np.c_[X.ravel(), Y.ravel()])
    f = np.c_[X.ravel()[inside], Y.ravel()[inside]]
    front = (np.c_[f, np.zeros(len(f))], np.tile([0.0, 0.0, -1.0], (len(f), 1)))
    back = (np.c_[f, np.full(len(f), thick_m)], np.tile([0.0, 0.0, 1.0], (len(f), 1)))
    seg = np.roll(o, -1, 0) - o
    length = np.cumsum(np.linalg.norm(seg, axis=1))
    s = np.arange(0, length[-1], STEP)
    k = np.searchsorted(length, s)
    edge = o[k % len(o)]
    nrm = np.c_[seg[k % len(o), 1], -seg[k % len(o), 0]]
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    zs = np.arange(0, thick_m + 1e-9, STEP)
    rim = (np.array([[x, y, z] for (x, y) in edge for z in zs]),
           np.array([[a, b, 0.0] for (a, b) in nrm for _ in zs]))
    return front, rim, back


def _view(name, *parts) -> RegView:
    p = np.vstack([a for a, _ in parts])
    n = np.vstack([b for _, b in parts])
    return RegView(name, p, n, p, p, n, obj_normals=n)


def _corner_views():
    """Two views of a cube corner's three faces (100 mm), overlapping on all three."""
    g = np.arange(0, 0.1, STEP)
    A, B = np.meshgrid(g, g)
    a, b = A.ravel(), B.ravel()
    z = np.zeros_like(a)
    faces = [(np.c_[a, b, z], [0, 0, -1.0]), (np.c_[a, z, b], [0, -1.0, 0]), (np.c_[z, a, b], [-1.0, 0, 0])]
    parts = [(p, np.tile(n, (len(p), 1))) for p, n in faces]
    return _view("c0", *parts), _view("c1", *parts)


Z = np.array([0.0, 0.0, 1.0])
I4 = np.eye(4)


def _slab_views(*kinds):
    front, rim, back = _slab()
    parts = {"f": (front, rim), "b": (back, rim), "e": (rim,)}
    return [_view(f"{k}{n}", *parts[k]) for n, k in enumerate(kinds)]


def test_views_of_a_slabs_two_faces_are_tied_by_its_rim_alone():
    views = _slab_views("f", "f", "b", "b")
    split = split_along(views, np.stack([I4] * 4), Z, 0.003)
    # the front face's normals point to -z (toward its cameras), the back's to +z
    assert split["groups"] == [[0, 1], [2, 3]]
    # the rim is swept along z: across it, the thickness is held by the corners' points only
    assert split["ratio"] < 0.02
    # a pair that shares a face is stiff along its normal: z is its stiffest translation
    S = translation_stiffness(views[0], views[1], I4, 0.003)
    assert abs(np.linalg.eigh(S)[1][2, -1]) > 0.9


def test_the_check_finds_the_slab_and_its_axis():
    views = _slab_views("f", "f", "b", "b")
    pts = np.vstack([v.obj_points for v in views])
    check = thin_slab_check(pts, views, np.stack([I4] * 4), 0.003)
    assert check["slab"]
    assert abs(check["axis"][2]) > 0.99
    # 30 mm thick, about 200 x 150 mm
    assert check["extents_mm"][0] == pytest.approx(30.0, abs=1.0)
    assert check["thickness_share"] < 0.25
    reason = slab_reason(check, ["f0", "f1", "b0", "b1"])
    assert "{f0, f1}" in reason and "{b0, b1}" in reason and "30 mm thick" in reason


def test_views_of_one_face_and_of_the_rim_make_no_slab():
    # edge-on views see only the swept rim: on neither side (they slide along it with their surface);
    # the front face's views are all on one side: nothing to tie
    views = _slab_views("f", "f", "e", "e")
    split = split_along(views, np.stack([I4] * 4), Z, 0.003)
    assert split["groups"] == [[0, 1], []] and split["ratio"] == np.inf
    pts = np.vstack([v.obj_points for v in views])
    assert not thin_slab_check(pts, views, np.stack([I4] * 4), 0.003)["slab"]


def test_a_block_seen_from_both_sides_is_not_a_slab():
    # 200 mm thick: the same faces and rim, but the object is not thin
    front, rim, back = _slab(thick_m=0.2)
    views = [_view("f", front, rim), _view("b", back, rim)]
    pts = np.vstack([v.obj_points for v in views])
    check = thin_slab_check(pts, views, np.stack([I4] * 2), 0.003)
    assert not check["slab"] and check["thickness_share"] > 0.5


def test_views_that_share_three_faces_are_held_in_every_direction():
    c0, c1 = _corner_views()
    for d in np.eye(3):
        # both views see the face toward -d: the same side, no tie to judge; the pair itself holds d
        assert split_along([c0, c1], np.stack([I4] * 2), d, 0.003)["groups"][1] == []
        S = translation_stiffness(c0, c1, I4, 0.003)
        # no translation is free (with the rotations left free, which take up part of each translation
        # at a corner, they are not equally stiff: measured 0.49 at the weakest)
        w = np.linalg.eigvalsh(S)
        assert w[0] / w[-1] > 0.25


def test_sides_no_pair_joins_are_not_tied_at_all():
    front, _, back = _slab()
    far = np.eye(4)
    far[:3, 3] = [1.0, 0.0, 0.0]
    split = split_along([_view("f", front), _view("b", back)], np.stack([I4, far]), Z, 0.003)
    assert split["ratio"] == 0.0 and split["pairs"] == 0
