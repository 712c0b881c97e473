"""The fusion's per-pixel weights: a weighted mean of the views' signed distances, the count of views unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from tests.reconstruct.test_fusion_noise import INTR, RAYS
from tofmetry.reconstruct import TSDFFusion
from tofmetry.reconstruct._fusion import incidence_weight

RANGE_MM = 700.0


def fused_plane_z_mm(readings: list[tuple[float, float | None]]) -> tuple[float, int]:
    """A frontal wall at 0.7 m (a disc of it) integrated from the identity pose once per (offset [mm], weight or None)
    in ``readings`` (the depth read ``offset`` long); (the median Z [mm] of the fused vertices within
    0.1 m of the axis, their count)."""
    f = TSDFFusion(INTR, voxel_mm=1.2, trunc_mm=6.0, behind_per_edge=3.0)
    r = np.hypot(RAYS[..., 0], RAYS[..., 1])
    for off, w in readings:
        depth = np.where(r < 0.2, RANGE_MM + off, 0.0)  # a disc of 0.14 m radius on the wall
        f.integrate(depth, np.eye(4), weight=None if w is None else np.full(INTR.shape, w))
    V = f.extract(1.0)[0]
    core = V[np.hypot(V[:, 0], V[:, 1]) < 0.1]
    return 1e3 * float(np.median(core[:, 2])), len(core)


def test_the_fused_surface_is_the_weighted_mean_of_the_readings():
    """Two readings of a wall 3 mm apart: weighted 1 and 0.5 the surface lies at their weighted mean,
    1 mm from the first (the TSDF is linear in depth within the truncation, so its zero level is the
    weighted mean of the readings); unweighted at 1.5 mm, as before weights. Tolerance 0.02 mm: the
    vertices' float32 interpolation on a 1.2 mm grid."""
    z_w, _ = fused_plane_z_mm([(0.0, 1.0), (3.0, 0.5)])
    z_1, _ = fused_plane_z_mm([(0.0, None), (3.0, None)])
    assert z_w == pytest.approx(RANGE_MM + 1.0, abs=0.02)
    assert z_1 == pytest.approx(RANGE_MM + 1.5, abs=0.02)


def test_a_surface_one_view_sees_is_kept_whatever_its_weight():
    """The extraction counts views, not weights: one reading weighted 0.05 gives the same surface as
    one weighted 1."""
    z_low, n_low = fused_plane_z_mm([(2.0, 0.05)])
    z_one, n_one = fused_plane_z_mm([(2.0, None)])
    assert n_low == n_one > 1000, (n_low, n_one)
    assert z_low == pytest.approx(z_one, abs=1e-6)


def test_incidence_weight():
    """cos(i) ** power, the cosine floored (a grazing sample still counts a little), 1 at power 0."""
    c = np.array([1.0, 0.5, 0.01])
    np.testing.assert_allclose(incidence_weight(c, 1.0), [1.0, 0.5, 0.05])
    np.testing.assert_allclose(incidence_weight(c, 2.0), [1.0, 0.25, 0.0025])
    np.testing.assert_allclose(incidence_weight(c, 0.0), [1.0, 1.0, 1.0])
