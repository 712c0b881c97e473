"""The IR pattern places the edges a symmetric object's geometry turned over (issue 16)."""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct import RegistrationConfig
from tofmetry.reconstruct._pattern_search import pattern_hypothesis, search_by_pattern
from tofmetry.reconstruct._register import PairResult
from tofmetry.reconstruct._regview import RegView

R_M, H_M, Z_M, TABLE_Y_M = 0.06, 0.15, 1.0, 0.1  # a cylinder standing on a table 1 m ahead (y down)
BLOBS = np.array([[20.0, 0.03], [95.0, 0.10], [160.0, 0.05], [230.0, 0.12], [300.0, 0.07]])  # azimuth deg, height m


def _albedo(phi_deg: np.ndarray, h: np.ndarray, painted: bool) -> np.ndarray:
    """Log albedo of the cylinder's surface at object azimuth ``phi_deg`` and height ``h`` [m]: dark
    blobs 25 mm in radius on a light ground, or plain."""
    if not painted:
        return np.zeros_like(h)
    out = np.zeros_like(h)
    for az, hb in BLOBS:
        arc = R_M * np.radians((phi_deg - az + 180.0) % 360.0 - 180.0)
        out -= 0.8 * (np.hypot(arc, h - hb) < 0.025)
    return out


def _view(rng, turn_deg: float, painted: bool, n: int = 6000) -> RegView:
    """The cylinder (axis vertical, 1 m ahead) seen by a camera turned ``turn_deg`` about its axis:
    the half facing the camera with its log albedo plus noise, and a ring of the table around it."""
    phi = rng.uniform(-80.0, 80.0, n) + turn_deg
    local = np.radians(phi - turn_deg)
    h = rng.uniform(0.0, H_M, n)
    pts = np.c_[R_M * np.sin(local), TABLE_Y_M - h, Z_M - R_M * np.cos(local)] + rng.normal(0, 3e-4, (n, 3))
    nrm = np.c_[np.sin(local), np.zeros(n), -np.cos(local)]
    ir = _albedo(phi, h, painted) + rng.normal(0, 0.03, n)
    m = 3000  # the table ring: 70-200 mm from the axis, the half the camera sees
    ang, rad = np.radians(rng.uniform(-90.0, 90.0, m)), rng.uniform(0.07, 0.2, m)
    ring = np.c_[rad * np.sin(ang), np.full(m, TABLE_Y_M), Z_M - rad * np.cos(ang)]
    ring_n = np.tile([0.0, -1.0, 0.0], (m, 1))
    icp_p, icp_n = np.r_[pts, ring], np.r_[nrm, ring_n]
    icp_ir = np.r_[ir, rng.normal(0, 0.03, m)]
    plane = np.array([0.0, -1.0, 0.0, TABLE_Y_M])  # normal up (-y), height 0 on the table
    return RegView(f"{turn_deg:g}", icp_p, icp_n, pts, pts[::4], nrm[::4], coarse_points=icp_p[::3],
                   coarse_normals=icp_n[::3], plane=plane, mid_points=icp_p[::2], mid_normals=icp_n[::2],
                   obj_normals=nrm, obj_ir=ir, icp_ir=icp_ir)


def _turn(deg: float) -> np.ndarray:
    """Source camera -> target camera of two cameras turned by ``deg`` about the cylinder's axis."""
    a = np.radians(deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    c = np.array([0.0, 0.0, Z_M])
    T[:3, 3] = c - T[:3, :3] @ c
    return T


def _check_turn(T_src_to_tgt: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    E = np.linalg.inv(true) @ T_src_to_tgt
    c = np.array([0.0, TABLE_Y_M - H_M / 2, Z_M])
    return rotation_angle_deg(E), float(np.linalg.norm(E[:3, :3] @ c + E[:3, 3] - c)) * 1e3


def test_the_pattern_finds_the_turn_a_surface_of_revolution_leaves_free():
    # two views 40 deg apart round a painted cylinder: every yaw matches the geometry; the pattern's
    # sweep over the whole turn finds the right one, within its 1 deg refinement step
    rng = np.random.default_rng(5)
    src, tgt = _view(rng, 40.0, True), _view(rng, 0.0, True)
    true = _turn(-40.0)  # a point at object azimuth phi: source camera angle phi - 40 -> target's phi
    h = pattern_hypothesis(src, tgt, 0, 1, RegistrationConfig())
    assert h is not None and h.accepted and h.method == "pattern-yaw"
    deg, mm = _check_turn(h.transform, true)
    assert deg < 1.0 and mm < 2.0 and h.ir_corr > 0.8, (deg, mm, h.ir_corr)


def test_a_plain_object_gives_the_pattern_nothing_to_find():
    rng = np.random.default_rng(6)
    src, tgt = _view(rng, 40.0, False), _view(rng, 0.0, False)
    assert pattern_hypothesis(src, tgt, 0, 1, RegistrationConfig()) is None


def _edge(i, j, T, fit, ir) -> PairResult:
    return PairResult(i, j, T, fit, 1.5, np.eye(6), "plane-yaw+icp", True, ir_corr=ir)


def test_an_edge_the_pattern_contradicts_is_searched_again_and_placed_by_it():
    # views 0 (turned 40 deg) and 1 (0 deg) of a painted cylinder, and a third view: edge 1->2
    # lines the pattern up (0.9), edge 0->1 was registered at a yaw the geometry could not tell
    # (no turn at all, agreement near 0): it is searched again and the pattern's pose comes first,
    # the geometric one its alternative; the edge that lined the pattern up is left alone
    rng = np.random.default_rng(7)
    regs = [_view(rng, 40.0, True), _view(rng, 0.0, True), _view(rng, -40.0, True)]
    cfg = RegistrationConfig()
    geometric = _edge(0, 1, np.eye(4), 1.0, 0.05)
    good = _edge(1, 2, _turn(-40.0), 0.99, 0.9)
    pairs, report = search_by_pattern([geometric, good], regs, cfg, ["00", "01", "02"])
    assert report["searched"] == ["00->01"] and list(report["found"]) == ["00->01"], report
    assert pairs[1] is good
    placed = pairs[0]
    assert placed.method == "pattern-yaw" and len(placed.alternatives) == 1
    assert np.allclose(placed.alternatives[0].transform, np.eye(4))
    deg, mm = _check_turn(placed.transform, _turn(-40.0))
    assert deg < 1.0 and mm < 2.0, (deg, mm)


def test_a_scan_that_shows_no_pattern_is_left_as_it_is():
    rng = np.random.default_rng(8)
    regs = [_view(rng, 40.0, False), _view(rng, 0.0, False)]
    pairs = [_edge(0, 1, np.eye(4), 1.0, 0.05)]
    out, report = search_by_pattern(pairs, regs, RegistrationConfig(), ["00", "01"])
    assert report is None and out == pairs
