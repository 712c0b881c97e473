"""The sensor's amplitude-bias coefficient k from grey-level boards (pipelines.amplitude_slope)."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.pipelines.amplitude_slope import (
    amplitude_slope_from_boards,
    combine_slopes,
)
from tofmetry.simulate import datasets
from tofmetry.simulate.family import random_sensor


def test_combine_slopes_weights_and_inflates_by_the_boards_scatter():
    k, s = combine_slopes(np.array([6.0, 8.0]), np.array([0.1, 0.2]))
    assert k == pytest.approx((6.0 / 0.01 + 8.0 / 0.04) / (1 / 0.01 + 1 / 0.04))
    se = 1.0 / np.sqrt(1 / 0.01 + 1 / 0.04)
    chi2 = (6.0 - k) ** 2 / 0.01 + (8.0 - k) ** 2 / 0.04
    assert s == pytest.approx(se * np.sqrt(chi2))   # Birge ratio, 1 degree of freedom
    k1, s1 = combine_slopes(np.array([7.0, 7.0, 7.0]), np.array([0.3, 0.3, 0.3]))
    assert (k1, s1) == pytest.approx((7.0, 0.3 / np.sqrt(3)))   # boards that agree: never deflated
    with pytest.raises(InputError, match="standard errors"):
        combine_slopes(np.array([7.0]), np.array([0.0]))


@pytest.mark.parametrize("seed", [3, 17])
def test_boards_recover_the_sensors_effective_k(tmp_path, seed):
    # A family sensor without the per-pixel deformation and range wiggling (what a depth calibration
    # removes), so raw depth stands for corrected depth. The object sees k + k_abs (the absolute
    # term changes with the amplitude just as the relative one does); the boards must read that.
    draw = random_sensor(seed)
    em = draw.errors.without("deformation", "wiggling")
    draw = draw.with_errors(em)
    k_true = em.amplitude_slope_mm_per_ln()
    boards = [datasets.materials(tmp_path / f"b{z}", n_frames=6, distance_m=z, sensor=draw, seed=seed + i)
              for i, z in enumerate((0.8, 1.2))]
    res = amplitude_slope_from_boards(boards)
    assert len(res.boards) == 2 and not res.calibrated
    assert any("not corrected" in n for n in res.notes)
    # 20 squares spanning ln 6 of amplitude: a few tenths of a mm per ln unit at most
    assert 0 < res.sigma_boards_mm_per_ln < 0.5 and res.sigma_mm_per_ln >= 0.15
    assert abs(res.k_mm_per_ln - k_true) < 3 * res.sigma_boards_mm_per_ln + 0.05
    assert [b["distance_mm"] for b in res.boards] == pytest.approx([800, 1200], abs=60)


def test_board_inputs_are_checked(tmp_path):
    with pytest.raises(InputError, match="at least one"):
        amplitude_slope_from_boards([])
    with pytest.raises(InputError, match="not a folder"):
        amplitude_slope_from_boards([tmp_path / "missing"])
