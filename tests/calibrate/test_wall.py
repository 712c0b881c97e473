"""Wall helpers: streamed station statistics against the reference accumulator; robust plane fit."""

from __future__ import annotations

import numpy as np

from tofmetry.calibrate import fit_plane, station_statistics, wall_reference
from tofmetry.pointcloud import temporal_stats


def test_station_statistics_matches_reference(small_intr):
    rng = np.random.default_rng(0)
    frames = rng.normal(1500, 3, (7, *small_intr.shape)).round().astype(np.uint16)
    frames[rng.random(frames.shape) < 0.2] = 0
    st = station_statistics(iter(frames), small_intr.shape, small_intr.cx, small_intr.cy, min_valid_fraction=0.0)
    ref = temporal_stats(frames)
    ok = ref.count > 0
    np.testing.assert_allclose(st.mean_mm[ok], ref.mean[ok], atol=1e-9)
    ok2 = ref.count > 1
    np.testing.assert_allclose(st.std_mm[ok2], ref.std[ok2], atol=1e-9)
    assert st.n_frames == 7 and st.frame_center_mm.shape == (7,)
    # pixels valid in fewer than half of the frames are NaN with the default threshold
    st2 = station_statistics(iter(frames), small_intr.shape, small_intr.cx, small_intr.cy)
    assert np.all(np.isnan(st2.mean_mm[ref.count < 3.5]))


def test_plane_fit_recovers_tilt_and_rejects_outliers(small_intr):
    t = np.deg2rad(7.0)
    n = np.array([np.sin(t), -0.5 * np.sin(t), np.cos(t)])
    n /= np.linalg.norm(n)
    z = wall_reference(small_intr, 2000.0, n)
    z[:5, :5] = 900.0  # a foreground object: gross outliers
    pf = fit_plane(z, small_intr)
    assert np.degrees(np.arccos(min(1.0, abs(pf.normal @ n)))) < 0.01
    assert not pf.inliers[:5, :5].any() and pf.std_mm < 1e-6


def test_validation_separates_noise_of_the_mean(small_intr):
    """A perfectly corrected station whose mean still carries noise of known std error:
    the after-RMS is that noise and its systematic part is ~0."""
    from tofmetry.calibrate import evaluate_wall_station
    from tofmetry.calibrate.board import constant_shift_calibration

    rng = np.random.default_rng(1)
    sem = 0.5  # [mm] standard error of the temporal mean per pixel
    truth = wall_reference(small_intr, 1500.0)
    mean = truth + 3.0 + rng.normal(0, sem, truth.shape)  # constant 3 mm bias + noise
    cal = constant_shift_calibration(-3.0, small_intr)  # corrected = measured - 3
    rep, _ = evaluate_wall_station(mean, 1500.0, cal, small_intr, mean_sem_mm=np.full(truth.shape, sem))
    n = truth.size * 0.81  # pixels in the central 90 % x 90 %
    assert abs(rep.rms_noise_mm - sem) < 1e-9
    assert abs(rep.rms_after_mm - sem) < 5 * sem / np.sqrt(2 * n)  # sampling error of an RMS
    assert rep.rms_after_systematic_mm < 0.1 * sem
    assert abs(rep.rms_raw_before_mm - np.hypot(3.0, sem)) < 0.05
    assert "rms_after_systematic_mm" in rep.to_dict()
