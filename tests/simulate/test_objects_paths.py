"""The object and path families of the scan simulations (issue 16): shapes, placement, poses, draws."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.simulate.objects import PROCEDURAL, REAL_MESHES, make_object, place_object, random_object
from tofmetry.simulate.paths import distance_bounds, handheld, random_path, turntable, two_rings


def _closed_and_outward(v, f):
    """Every edge is shared by exactly two triangles and the signed volume is positive."""
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    return bool(np.all(counts == 2)), vol


@pytest.mark.parametrize("name", sorted(PROCEDURAL))
def test_procedural_objects_are_closed_placed_and_sized(name):
    o = make_object(name, seed=3)
    closed, vol = _closed_and_outward(o.vertices, o.triangles)
    assert closed and vol > 0, (name, closed, vol)
    assert abs(o.vertices[:, 2].min()) < 1e-12  # on the ground
    c = (o.vertices.min(0) + o.vertices.max(0)) / 2
    assert abs(c[0]) < 1e-9 and abs(c[1]) < 1e-9  # centred on the z axis
    lo, hi = PROCEDURAL[name][1]
    assert lo <= o.size_m <= hi
    assert o.extent_m.max() <= o.size_m * 1.42 + 1e-9  # a yaw can widen the box by at most sqrt(2)


def test_draws_are_deterministic_and_span_the_family():
    a, b = random_object(11), random_object(11)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    names = {random_object(s).name for s in range(60)}
    assert names == set(PROCEDURAL)  # without the mesh folder: procedural only


def test_real_mesh_needs_its_folder(tmp_path):
    with pytest.raises(InputError, match="mesh_dir"):
        make_object("bunny", 0)
    with pytest.raises(InputError, match="not found"):
        make_object("bunny", 0, mesh_dir=tmp_path)
    assert set(REAL_MESHES) == {"bunny", "igea", "rocker-arm", "fandisk"}


def test_real_meshes_stand_on_their_base(shared_data):
    o = make_object("rocker-arm", 0, size_m=0.3, yaw_deg=0.0, mesh_dir=shared_data / "scan-meshes")
    assert abs(o.extent_m.max() - 0.3) < 1e-9 and o.extent_m[2] < 0.15  # lies flat


def test_place_object_turns_up_to_z():
    v = np.array([[0, 0, 0], [0, 2.0, 0], [1.0, 0, 0], [0, 0, 0.5]])
    p = place_object(v, up=(0, 1, 0), size_m=0.4)
    assert np.isclose(p[:, 2].max(), 0.4)  # the former y (longest) is now the height


def test_turntable_and_handheld_look_at_the_object():
    t = np.array([0.0, 0.0, 0.1])
    for path in (turntable(8, 1.0, 30.0, t), handheld(9, 1.0, 30.0, t, np.random.default_rng(0))):
        for T in path.poses:
            d = np.linalg.norm(T[:3, 3] - t)
            assert 0.85 <= d <= 1.15
            fwd = T[:3, 2]
            to_t = (t - T[:3, 3]) / d
            assert fwd @ to_t > np.cos(np.radians(5.0))  # aims at the object (hand-held: within the jitter)
            np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    hh = handheld(9, 1.0, 30.0, t, np.random.default_rng(0))
    assert max(abs(r) for r in hh.params["roll_deg"]) <= 15.0 and len(set(np.round(hh.params["roll_deg"], 3))) > 1


def test_random_path_bounds():
    for s in range(20):
        p = random_path(s, (0, 0, 0.1), 0.3)
        lo, hi = distance_bounds(0.3)
        assert 6 <= p.n_views <= 16 and lo <= p.distance_m <= hi and 15 <= p.elevation_deg <= 45
    assert distance_bounds(0.5)[0] >= 0.5 + 0.75 * 0.5 - 1e-12
    assert len(two_rings(8, 3, 1.0, 30.0, 65.0, (0, 0, 0.1)).poses) == 11


def test_scan_takes_explicit_poses(tmp_path):
    from tofmetry.io import ScanDataset, read_json
    from tofmetry.simulate import ErrorModel, datasets

    o = make_object("box", 1, size_m=0.25)
    path = turntable(2, 0.9, 30.0, o.centre_m)
    out = datasets.scan(tmp_path / "s", n_frames=1, mesh=(o.vertices, o.triangles), poses=path.poses,
                        errors=ErrorModel.none().with_terms("quantize"), info={"object": o.to_dict()})
    t = read_json(out / "truth.json")
    assert len(ScanDataset(out)) == 2 and t["info"]["object"]["name"] == "box"
    np.testing.assert_allclose(t["views"][1]["camera_to_world"], path.poses[1])
    with pytest.raises(InputError, match="poses"):
        datasets.scan(tmp_path / "bad", n_frames=1, mesh=(o.vertices, o.triangles), poses=[np.eye(3)])
