"""Consistency gate of the pose graph and the library amplitude reference (fast)."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.reconstruct import PairResult, PoseGraphBuilder, consistency_gate


def _rot_z(deg: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    a = np.radians(deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = t
    return T


def _circle(n: int, closure_error: np.ndarray) -> PoseGraphBuilder:
    """n views on a circle (45 deg apart), successive edges exact, the direct 0 -> n-1 edge off by ``closure_error``."""
    poses = [_rot_z(360.0 / n * k, (np.cos(2 * np.pi * k / n), np.sin(2 * np.pi * k / n), 0.0)) for k in range(n)]
    pg = PoseGraphBuilder(n, [f"{k:02d}" for k in range(n)])
    for i in range(n - 1):
        pg.add(PairResult(i, i + 1, np.linalg.inv(poses[i + 1]) @ poses[i], 0.9, 1.0, np.eye(6) * 1000, "test", True))
    T0n = np.linalg.inv(poses[n - 1]) @ poses[0]
    pg.add(PairResult(0, n - 1, T0n @ closure_error, 0.9, 1.0, np.eye(6) * 1000, "test", True))
    return pg


def test_cycle_closure_measures_the_injected_error():
    # a closure error of 0.5 deg / 3 mm injected on the direct edge is read back exactly
    E = _rot_z(0.5, (0.003, 0.0, 0.0))
    deg, mm, n = _circle(8, E).cycle_closure()
    assert n == 8 and deg == pytest.approx(0.5, abs=1e-9) and mm == pytest.approx(3.0, abs=1e-6)
    assert _circle(8, np.eye(4)).cycle_closure()[1] == pytest.approx(0.0, abs=1e-9)


def test_gate_passes_a_consistent_graph_and_flags_an_open_circle():
    ok = _circle(8, _rot_z(0.3, (0.002, 0, 0))).optimize(0.003)
    assert ok.consistency["reliable"], ok.consistency
    # 60 mm over 8 edges = 21 mm per edge > 10 mm: a circle that does not close (flip / scale error)
    bad = _circle(8, _rot_z(0.3, (0.06, 0, 0))).optimize(0.003)
    c = bad.consistency
    assert not c["reliable"] and any("does not close" in r for r in c["reasons"]), c
    assert c["cycle_closure_mm"] == pytest.approx(60.0, abs=1e-6)


def test_gate_on_kept_edge_residuals():
    edges = [{"source": "00", "target": "01", "accepted": True, "kept": True, "residual_rot_deg": 0.1,
              "residual_trans_mm": 12.0},
             {"source": "00", "target": "02", "accepted": True, "kept": False, "residual_rot_deg": 9.0,
              "residual_trans_mm": 80.0}]
    c = consistency_gate(edges, None, 2.0, 10.0)
    assert not c["reliable"] and "00->01" in c["reasons"][0] and c["n_pruned"] == 1
    # a pruned edge alone does not fail the gate (the solution does not use it)
    edges[0]["residual_trans_mm"] = 4.0
    assert consistency_gate(edges, None, 2.0, 10.0)["reliable"]


@pytest.fixture(scope="module")
def wall(tmp_path_factory):
    from tofmetry.simulate import datasets

    return datasets.wall_dataset(tmp_path_factory.mktemp("w") / "wall", distances_mm=(1000, 1500, 3000), n_frames=2, seed=0)


def test_white_map_from_wall_matches_the_station_formula(wall):
    """The library function = white_amplitude_map on the stations' mean IR / robust mean depth,
    with stations beyond max_mm left out."""
    from tofmetry.io import WallDataset
    from tofmetry.pointcloud import robust_mean_depth
    from tofmetry.pipelines.reconstruct import white_map_from_wall
    from tofmetry.reconstruct import white_amplitude_map

    calls = []
    wm = white_map_from_wall(wall, None, None, max_mm=2000.0, advance=lambda: calls.append(1))
    assert len(calls) == 2  # the 3000 mm station is beyond max_mm
    sts = [st for st in WallDataset(wall).stations if st.distance_mm <= 2000]
    caps = [st.open() for st in sts]
    ref = white_amplitude_map([c.ir_mean() for c in caps], [robust_mean_depth(c.depth_stack(), 3.0, 1) for c in caps],
                              caps[0].intrinsics()[0])
    np.testing.assert_allclose(wm, ref, equal_nan=True)
    assert wm.shape == (424, 512) and np.isfinite(wm).mean() > 0.9


def test_white_map_from_wall_needs_ir(wall, tmp_path):
    import shutil

    from tofmetry.pipelines.reconstruct import white_map_from_wall

    w2 = tmp_path / "wall"
    shutil.copytree(wall, w2)
    for d in w2.glob("*/ir"):
        shutil.rmtree(d)
    with pytest.raises(InputError, match="no IR"):
        white_map_from_wall(w2)
