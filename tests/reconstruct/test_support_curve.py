"""The range error the support shows, removed before the fusion: a model's size no longer carries it.

A sensor whose only error (besides noise) is a range wiggle of 2.5 mm with a 0.47 m period, steepest
(3.3 %) where the object lies: uncalibrated, each view of a baluster is stretched by that gain along
its line of sight. The mat places the views; the support, seen from 0.5 to 1.6 m, shows the wiggle.
"""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry._shared.dot_mat import DotMat
from tofmetry.evaluate import distances_to_mesh, scale_from_reference
from tofmetry.io import read_json
from tofmetry.io.mesh import Geometry
from tofmetry.pipelines.reconstruct import reconstruct_scan
from tofmetry.reconstruct import ReconstructionConfig
from tofmetry.simulate import ErrorModel, datasets
from tofmetry.simulate.objects import make_object

PERIOD_MM = 470.0


def wiggle_sensor(z_steep_mm: float) -> ErrorModel:
    """Noise and a single range wiggle along Z, steepest at ``z_steep_mm``."""
    phase = -2 * np.pi * z_steep_mm / PERIOD_MM  # sin(2 pi z / P + phase) crosses zero, rising, at z_steep
    return ErrorModel.only("noise", "wiggling", wiggle_offset_mm=0.0, wiggle_slope_mm_per_m=0.0,
                           wiggle_amps_mm=(2.5,), wiggle_phases=(float(phase % (2 * np.pi)),),
                           wiggle_periods_m=(PERIOD_MM / 1e3,), wiggle_harmonics=(1,), wiggle_steep_mm=0.0,
                           range_variable="z", range_apply="z")


def object_points(res, mat: DotMat) -> np.ndarray:
    """The model's vertices in the truth's world (the model is in the mat's frame), the ground ring left out."""
    a = np.radians(mat.yaw_deg)
    mat_to_world = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    pts = res.mesh_vertices @ mat_to_world.T
    return pts[pts[:, 2] > 0.003]


def model_scale(res, scan, mat: DotMat, ref: Geometry) -> float:
    return float(scale_from_reference(object_points(res, mat), ref)["scale_error"])


def baluster_on_mat(tmp_path, errors: ErrorModel):
    """A 0.25 m baluster on a dot mat, 8 views at 0.85 m and 35 deg: (scan folder, mat, reference, config)."""
    obj = make_object("baluster", seed=3, size_m=0.25, painted=False)
    mat = DotMat(seed=7, yaw_deg=20.0)
    scan = datasets.scan(tmp_path / "scan", n_frames=3, mesh=(obj.vertices, obj.triangles), radius_m=0.85,
                         n_views=8, elevation_deg=35.0, errors=errors, seed=4, mat=mat)
    cfg = ReconstructionConfig()
    cfg.registration.mat = DotMat(seed=7).to_dict()
    return scan, mat, Geometry(obj.vertices, obj.triangles, source="reference"), cfg


@pytest.mark.slow
def test_a_range_wiggle_no_longer_scales_the_model(tmp_path):
    scan, mat, ref, base = baluster_on_mat(tmp_path, wiggle_sensor(850.0))
    off = base.model_copy(deep=True)
    off.preprocess.support_curve = False
    without = reconstruct_scan(scan, None, config=off)
    with_ = reconstruct_scan(scan, None, config=base)
    sc = with_.diagnostics["support_curve"]
    assert sc["applied"] and sc["span_mm"][0] < 700 and sc["span_mm"][1] > 1200, sc
    # the curve read at the object: the wiggle's slope there (3.3 % at 850 mm, less over the object's depths)
    assert sc["object_gain_pct"] > 1.0, sc
    s_off, s_on = model_scale(without, scan, mat, ref), model_scale(with_, scan, mat, ref)
    assert abs(s_off) > 0.5e-2, s_off  # half the gain, fused from all round
    assert abs(s_on) < 0.2e-2, (s_off, s_on)  # the scale target
    truth = read_json(scan / "truth.json")
    assert truth["views"] and with_.diagnostics["reliable"] is True


def crest_sensor(z_crest_mm: float) -> ErrorModel:
    """Noise and a single range wiggle along Z, at its crest (+2.5 mm) at ``z_crest_mm``."""
    phase = np.pi / 2 - 2 * np.pi * z_crest_mm / PERIOD_MM
    return ErrorModel.only("noise", "wiggling", wiggle_offset_mm=0.0, wiggle_slope_mm_per_m=0.0,
                           wiggle_amps_mm=(2.5,), wiggle_phases=(float(phase % (2 * np.pi)),),
                           wiggle_periods_m=(PERIOD_MM / 1e3,), wiggle_harmonics=(1,), wiggle_steep_mm=0.0,
                           range_variable="z", range_apply="z")


def mean_signed_mm(res, mat: DotMat, ref: Geometry) -> float:
    d = distances_to_mesh(object_points(res, mat), ref.points, ref.faces).distance
    return float(np.mean(d[np.abs(d) < 0.005])) * 1e3


@pytest.mark.slow
def test_the_curves_level_at_the_object_is_taken_off_it(tmp_path):
    """The wiggle's crest where the object lies: every view reads it 2.5 mm too far. The mat placed the
    views by their measured support planes, which the wiggle, averaged over 0.5-1.6 m of support, barely
    moves; so the object lies about 2.5 mm too far along every line of sight (its surface sunk by the
    share of that along its normals, about half). Levelled on the object (``calibration``), the curve
    leaves it there; taken off whole (``support``; the default takes it off where the calibration warns
    of its own error at the object's depths, and this scan has none), the surface comes back nearer the
    truth, but past it: the placements' planes, fitted on support that is partly at the crest's depths
    too, had taken a share of it already (measured: -0.66 -> +0.49 mm; what each view's plane took is the
    next refinement)."""
    scan, mat, ref, cfg = baluster_on_mat(tmp_path, crest_sensor(850.0))
    old = cfg.model_copy(deep=True)
    old.preprocess.support_curve_level = "calibration"
    cfg.preprocess.support_curve_level = "support"
    kept = reconstruct_scan(scan, None, config=old)
    taken = reconstruct_scan(scan, None, config=cfg)
    sc = taken.diagnostics["support_curve"]
    assert sc["applied"] and not sc["levelled"] and sc["object_offset_mm"] > 1.0, sc
    s_kept, s_taken = mean_signed_mm(kept, mat, ref), mean_signed_mm(taken, mat, ref)
    assert s_kept < -0.6, s_kept  # sunk by the share of 2.5 mm along the normals
    assert abs(s_taken) < abs(s_kept), (s_kept, s_taken)
