"""The depth tilt from board poses: geometry -> render -> recover, folding into a calibration, file round trip."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.calibrate import fit_depth_tilt, with_depth_tilt
from tofmetry.calibrate.board import BoardSamples, constant_shift_calibration
from tofmetry.errors import EstimationError, InputError
from tofmetry.pipelines.depth_tilt import tilt_from_boards
from tofmetry.simulate import ErrorModel
from tofmetry.simulate.family import default_sensor

TRUE_TILT = (6.0, -9.0)  # mm per unit of x / z and y / z: 0.62 deg at 1 m


@pytest.fixture(scope="module")
def tilted_boards(tmp_path_factory):
    from tofmetry.simulate.board_datasets import board_dataset

    em = ErrorModel.only("deformation", "noise", deform_corner_mm_1m=0.0, deform_centre_mm_1m=0.0,
                         deform_skew_mm_1m=0.0, deform_tilt_mm_1m=TRUE_TILT, deform_range_kind="constant")
    return board_dataset(tmp_path_factory.mktemp("tilt") / "boards", n_poses=10, board="checkerboard", seed=3,
                         errors=em)


def test_the_tilt_of_a_sensor_is_recovered_from_its_board_poses(tilted_boards):
    intr = default_sensor().intrinsics
    run = tilt_from_boards(tilted_boards, intrinsics=intr)
    f = run.fit
    assert f.model == "constant"  # the simulated tilt does not change with distance
    assert len(f.view_z_mm) >= 8
    # the per-view tilts scatter by the board poses' rotation error (Z times its angle) and the
    # noise; the mean's standard error is that scatter over sqrt(views). 0.3 mm per unit (0.02 deg
    # at 1 m) allows for the 1 mm quantisation of the depth.
    err = np.abs(f.tilt_mm - TRUE_TILT)
    assert np.all(err <= np.maximum(4 * f.sigma_mm, 0.3)), (f.tilt_mm, f.sigma_mm)
    # the views' scatter and the systematic part added in quadrature (SYSTEMATIC_MM)
    from tofmetry.calibrate._tilt import SYSTEMATIC_MM

    assert SYSTEMATIC_MM <= f.sigma_mm.min() and f.sigma_mm.max() < np.hypot(1.0, SYSTEMATIC_MM)
    # held-out blocks of the recording: taking the tilt off lowers their board-plane error
    assert f.confirmed and f.held_out["rms_mm"] < f.held_out["rms_none_mm"]
    d = run.to_dict()["tilt"]
    assert d["angle_deg_at_1m"] == pytest.approx(np.degrees(np.hypot(*TRUE_TILT) / 1000), abs=0.05)


def test_a_turned_white_board_reads_longer_where_its_incidence_is_larger_and_that_is_not_a_tilt(tmp_path):
    """Amplitude-related bias ``k ln(A_white / A)``: a board turned by up to 35 deg returns ``cos`` of
    its incidence, which a white wall seen frontally does not; left in, it biased the views' mean
    tilt by 2.6-3.7 mm per unit on family sensors."""
    from tofmetry.simulate.board_datasets import board_dataset

    em = ErrorModel.only("deformation", "noise", "amplitude_bias", deform_corner_mm_1m=0.0, deform_centre_mm_1m=0.0,
                         deform_skew_mm_1m=0.0, deform_tilt_mm_1m=TRUE_TILT, deform_range_kind="constant",
                         amp_bias_mm_per_ln=8.0, amp_bias_abs_mm_per_ln=0.0)
    boards = board_dataset(tmp_path / "boards", n_poses=14, board="checkerboard", seed=4, errors=em)
    f = tilt_from_boards(boards, intrinsics=default_sensor().intrinsics).fit
    assert f.model.endswith("+ incidence") and 0 < f.incidence_k_mm < 16
    assert np.all(np.abs(f.tilt_mm - TRUE_TILT) <= np.maximum(4 * f.sigma_mm, 0.3)), (f.tilt_mm, f.sigma_mm)


def test_a_tilt_read_through_biased_board_orientations_is_not_folded_in(tilted_boards, tmp_path):
    """A principal point 12 px off turns the boards' planes solved from their IR corners: the views'
    tilts then disagree with their offsets across the image, and the tilt fitted on two blocks of the
    recording raises the board-plane error of the third (the check that refused the real Kinect v2
    recording's tilt)."""
    import dataclasses

    intr = default_sensor().intrinsics
    base = constant_shift_calibration(0.0, dataclasses.replace(intr, cy=intr.cy + 12.0))
    run = tilt_from_boards(tilted_boards, base)
    f = run.fit
    assert np.abs(f.tilt_mm - TRUE_TILT).max() > 4 * f.sigma_mm.max()  # what the biased views read
    assert not f.confirmed and f.held_out["rms_mm"] > f.held_out["rms_none_mm"]
    assert not run.folded and run.calibration.surfaces is base.surfaces
    assert run.calibration.diagnostics["tilt_not_folded"]["held_out"]["confirmed"] is False
    assert any("not folded in" in n and "board-plane error" in n for n in run.notes)
    assert run.to_dict()["folded"] is False
    # the refused fit travels with the calibration file, for the reader of its diagnostics
    from tofmetry.pipelines import load_calibration, save_calibration

    save_calibration(tmp_path / "cal.npz", run.calibration)
    back = load_calibration(tmp_path / "cal.npz").diagnostics
    assert back["tilt_not_folded"] == run.calibration.diagnostics["tilt_not_folded"] and not back.get("tilt")


def test_the_held_out_check_has_three_outcomes():
    """``held_out_check`` on per-view tilts and board pixels made to order (12 views, 400 pixels each,
    x, y over +-0.2, 1 mm of noise, the views' tilts scattering by 1 mm per unit as board poses
    make them): a tilt the pixels carry is confirmed; a tilt the views' slopes read but the pixels
    do not carry (the board orientations biased) raises the held-out error and is contradicted; a
    tilt of 0.05 mm per unit (plus the views' mean scatter) is too small for the share the pixels
    carry to matter: never contradicted (so foldable, shrunk), confirmed when it lowers their error
    and otherwise reported with its bound."""
    from tofmetry.calibrate import held_out_check

    V, N = 12, 400
    Z, G = np.linspace(700, 1300, V), np.zeros((V, 2))
    sig = np.array([0.3, 0.3])
    for seed in range(5):
        rng = np.random.default_rng(seed)
        xy = [rng.uniform(-0.2, 0.2, (N, 2)) for _ in range(V)]
        scatter = rng.normal(0, 1.0, (V, 2))  # each view's own tilt error (its board pose)

        def check(carried, read):
            pix = [np.column_stack([p, p @ (np.asarray(carried) + s) + rng.normal(0, 1.0, N)])
                   for p, s in zip(xy, scatter)]
            T = np.asarray(read, float) + scatter
            return held_out_check(T, Z, G, pix, False, False, T.mean(0), sig)

        ok = check((6.0, -9.0), (6.0, -9.0))
        assert ok["confirmed"] and ok["rms_mm"] < ok["rms_none_mm"] and ok["bound_mm"] is None
        assert ok["contradicted"] is False
        bad = check((0.0, 0.0), (6.0, -9.0))
        assert not bad["confirmed"] and bad["rms_mm"] > bad["rms_none_mm"] and bad["bound_mm"] is None
        assert bad["contradicted"] is True
        small = check((0.0, 0.0), (0.05, 0.05))
        assert small["contradicted"] is False
        assert small["confirmed"] or small["bound_mm"] is not None, small
        assert np.all(np.array(small["bound_mm"]) >= 0.6)


def test_a_folded_tilt_is_taken_off_every_frame_and_survives_the_file(tilted_boards, tmp_path):
    from tofmetry.calibrate import apply_depth_calibration
    from tofmetry.pipelines import load_calibration, save_calibration

    intr = default_sensor().intrinsics
    base = constant_shift_calibration(0.0, intr)
    run = tilt_from_boards(tilted_boards, base)
    cal = run.calibration
    assert cal.diagnostics["tilt_calibrated"] and cal.diagnostics["tilt"]["n_views"] == len(run.fit.view_z_mm)
    rays = intr.ray_table(True)
    z = np.full(intr.shape, 900.0)
    measured = z + TRUE_TILT[0] * rays[..., 0] + TRUE_TILT[1] * rays[..., 1]
    out = apply_depth_calibration(measured, cal)
    # what is left is the fit's own error over the image (|x|, |y| < 0.8)
    bound = 0.8 * np.sum(np.maximum(4 * run.fit.sigma_mm, 0.3))
    assert np.max(np.abs(out - z)) <= bound
    save_calibration(tmp_path / "cal.npz", cal)
    back = load_calibration(tmp_path / "cal.npz")
    assert back.diagnostics["tilt"] == cal.diagnostics["tilt"]
    np.testing.assert_allclose(apply_depth_calibration(measured, back), out, atol=1e-4)
    with pytest.raises(InputError, match="already has a tilt"):
        with_depth_tilt(back, run.fit)


def _plane_samples(intr, tilt, z0, rng, n=400):
    u = rng.integers(100, 400, n)
    v = rng.integers(80, 340, n)
    xy = intr.ray_table(True)[v, u]
    ref = np.full(n, z0)
    meas = ref + tilt[0] * xy[:, 0] + tilt[1] * xy[:, 1] + rng.normal(0, 1.0, n)
    white = np.ones(n, bool)
    return BoardSamples(u, v, meas, ref, white, ~white, 0.1, float("nan"))


def test_too_few_views_and_a_gross_view_are_said():
    intr = default_sensor().intrinsics
    rng = np.random.default_rng(0)
    with pytest.raises(EstimationError, match="3 usable board views, at least 4"):
        fit_depth_tilt([_plane_samples(intr, (5, 5), 900, rng) for _ in range(3)], intr)
    views = [_plane_samples(intr, (5, 5), 800 + 40 * k, rng) for k in range(8)]
    views.append(_plane_samples(intr, (60, 5), 900, rng))  # a board pose 3 deg off
    f = fit_depth_tilt(views, intr)
    assert "view008" in [n for n, _ in f.skipped] and len(f.view_z_mm) == 8
    assert np.allclose(f.tilt_mm, (5, 5), atol=4 * f.sigma_mm.max() + 0.1)


def _fit(tilt, sigma, held_out):
    from tofmetry.calibrate import TiltFit

    return TiltFit(np.array(tilt, float), np.zeros(2), np.array(sigma, float), 1000.0, (700.0, 1300.0), "constant",
                   np.zeros((6, 2)), np.full(6, 1000.0), tuple("abcdef"), np.ones(2), {}, [], 0.0, held_out)


def test_a_fit_is_folded_shrunk_by_its_signal_to_noise_unless_contradicted():
    """``w = t^2 / (t^2 + sigma^2)`` per axis: a fit at 1 sigma goes in at half, one at 5 sigma at
    26 / 27; the calibration's surfaces take ``w t . (x, y)``. Contradicted, or not checked (too few
    views), it is not foldable."""
    checked = {"rms_mm": 2.0, "rms_none_mm": 1.9, "confirmed": False, "contradicted": False}
    f = _fit((1.2, -6.0), (1.2, 1.2), checked)
    assert f.foldable and not f.confirmed
    np.testing.assert_allclose(f.shrink, [0.5, 25 / 26])
    cal = constant_shift_calibration(0.0, default_sensor().intrinsics)
    out = with_depth_tilt(cal, f)
    rays = cal.intrinsics.ray_table(True)
    expect = 0.5 * 1.2 * rays[..., 0] - 25 / 26 * 6.0 * rays[..., 1]
    np.testing.assert_allclose(out.surfaces[0] - cal.surfaces[0], expect, atol=1e-4)
    assert out.diagnostics["tilt"]["shrink"] == [0.5, round(25 / 26, 3)]
    assert not _fit((1.2, -6.0), (1.2, 1.2), checked | {"contradicted": True}).foldable
    assert not _fit((1.2, -6.0), (1.2, 1.2), {"rms_mm": None, "confirmed": False, "contradicted": False}).foldable
