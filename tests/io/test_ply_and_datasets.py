"""PLY round trips (ours and Open3D's reader) and dataset folder validation."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import FormatError, InputError
from tofmetry.io import WallDataset, read_intrinsics, read_ply, write_capture, write_intrinsics, write_ply, write_stations_csv
from tofmetry.sensor import KINECT_V2


def test_ply_round_trip_with_colors_normals_faces_scalars(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(100, 3))
    nrm = rng.normal(size=(100, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    col = rng.integers(0, 255, size=(100, 3), dtype=np.uint8)
    faces = rng.integers(0, 100, size=(30, 3))
    dev = rng.normal(size=100)
    write_ply(tmp_path / "a.ply", pts, colors=col, normals=nrm, faces=faces, scalars={"deviation_mm": dev})
    r = read_ply(tmp_path / "a.ply")
    assert np.allclose(r["points"], pts, atol=1e-6)  # float32 storage
    assert np.allclose(r["normals"], nrm, atol=1e-6)
    assert np.array_equal(r["colors"], col)
    assert np.array_equal(r["faces"], faces)
    assert np.allclose(r["deviation_mm"], dev, atol=1e-5)


def test_ply_is_read_by_open3d(tmp_path):
    o3d = pytest.importorskip("open3d")
    pts = np.random.default_rng(1).uniform(size=(50, 3))
    col = np.tile(np.array([[255, 0, 0]], np.uint8), (50, 1))
    write_ply(tmp_path / "c.ply", pts, colors=col, normals=np.tile([0, 0, 1.0], (50, 1)))
    pc = o3d.io.read_point_cloud(str(tmp_path / "c.ply"))
    assert len(pc.points) == 50 and pc.has_normals() and pc.has_colors()
    assert np.allclose(np.asarray(pc.points), pts, atol=1e-6)
    assert np.allclose(np.asarray(pc.colors)[0], [1, 0, 0])


def test_ply_bad_file(tmp_path):
    (tmp_path / "x.ply").write_bytes(b"not a ply")
    with pytest.raises(FormatError, match="not a PLY"):
        read_ply(tmp_path / "x.ply")


def test_intrinsics_json_round_trip(tmp_path):
    write_intrinsics(tmp_path / "i.json", KINECT_V2.depth, sensor="kinect_v2")
    assert read_intrinsics(tmp_path / "i.json") == KINECT_V2.depth


def _wall(tmp_path, rows):
    for name, _ in rows:
        if not (tmp_path / name).exists():
            write_capture(tmp_path / name, [np.full((424, 512), 1000, np.uint16)])
    write_stations_csv(tmp_path / "stations.csv", rows)
    return tmp_path


def test_wall_dataset_ok(tmp_path):
    ds = WallDataset(_wall(tmp_path, [("s0800", 800), ("s1000", 1000)]), min_stations=2)
    assert ds.distances_mm == [800, 1000] and len(ds) == 2 and len(ds[0].open()) == 1


def test_wall_dataset_duplicate_station(tmp_path):
    with pytest.raises(InputError, match="twice"):
        WallDataset(_wall(tmp_path, [("s0800", 800), ("s0800", 900)]))


def test_wall_dataset_out_of_order(tmp_path):
    with pytest.raises(InputError, match="increasing"):
        WallDataset(_wall(tmp_path, [("a", 1000), ("b", 800)]))


def test_wall_dataset_missing_station_folder(tmp_path):
    _wall(tmp_path, [("a", 800)])
    (tmp_path / "stations.csv").write_text("capture,distance_mm\na,800\nb,1000\n")
    with pytest.raises(InputError, match="missing"):
        WallDataset(tmp_path)


def test_wall_dataset_one_station_only(tmp_path):
    with pytest.raises(InputError, match="at least 2"):
        WallDataset(_wall(tmp_path, [("a", 800)]), min_stations=2)


def _poly_ply(binary: bool) -> bytes:
    """A square (quad) and a triangle, faces with an extra property after the index list."""
    verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)]
    faces = [[0, 1, 2, 3], [1, 4, 2]]
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", "element vertex 5",
            "property float x", "property float y", "property float z", "element face 2",
            "property list uchar int vertex_indices", "property uchar flags", "end_header"]
    out = ("\n".join(head) + "\n").encode()
    if binary:
        out += np.array(verts, "<f4").tobytes()
        for f in faces:
            out += np.uint8(len(f)).tobytes() + np.array(f, "<i4").tobytes() + np.uint8(7).tobytes()
    else:
        out += "".join(f"{x} {y} {z}\n" for x, y, z in verts).encode()
        out += "".join(f"{len(f)} {' '.join(map(str, f))} 7\n" for f in faces).encode()
    return out


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "ascii"])
def test_ply_polygons_of_mixed_sizes_are_fanned(tmp_path, binary):
    from tofmetry.io.mesh import read_geometry
    from tofmetry.io.ply import read_ply

    f = tmp_path / "poly.ply"
    f.write_bytes(_poly_ply(binary))
    faces = read_ply(f)["faces"]
    assert sorted(map(tuple, faces.tolist())) == [(0, 1, 2), (0, 2, 3), (1, 4, 2)]
    g = read_geometry(f, "model")
    assert g.is_mesh and len(g.faces) == 3
    # a truncated polygon list is refused with the file named, not handed to another parser
    f.write_bytes(_poly_ply(binary)[:-6])
    with pytest.raises(InputError, match="poly.ply"):
        read_geometry(f, "model")
