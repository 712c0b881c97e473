"""Chunked statistics equal the one-pass ones: parallel-variance merge, noise and warm-up in chunks."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.assess import assess_noise, assess_warmup
from tofmetry.batch import chunked as C
from tofmetry.batch.stats import Moments, frame_moments, merge_all
from tofmetry.errors import InputError
from tofmetry.io import Capture
from tofmetry.simulate import datasets


def test_merge_equals_one_pass_for_any_split():
    rng = np.random.default_rng(3)
    frames = rng.normal(1500.0, 3.0, (37, 4, 5))
    frames[rng.random(frames.shape) < 0.2] = 0        # dropouts are not samples
    whole = frame_moments(frames, (4, 5))
    for cuts in ([10, 20], [1, 2, 36], [18]):
        parts = [frame_moments(p, (4, 5)) for p in np.split(frames, cuts)]
        merged = merge_all(parts)
        np.testing.assert_array_equal(merged.count, whole.count)
        np.testing.assert_allclose(merged.mean, whole.mean, rtol=0, atol=1e-10)
        np.testing.assert_allclose(merged.std(), whole.std(), rtol=0, atol=1e-10, equal_nan=True)
    x = np.where(frames > 0, frames, np.nan)
    np.testing.assert_allclose(whole.std(), np.nanstd(x, axis=0, ddof=1), rtol=1e-12)
    assert merged.n_frames == 37


def test_merge_refuses_other_sizes_and_nothing():
    with pytest.raises(InputError, match="different frame sizes"):
        merge_all([Moments.empty((2, 2)), Moments.empty((2, 3))])
    with pytest.raises(InputError, match="no chunk"):
        merge_all([])


def test_frame_ranges_cover_once():
    assert C.frame_ranges(120, 40) == [(0, 40), (40, 80), (80, 120)]
    assert C.frame_ranges(120, 60, 50) == [(0, 100), (100, 120)]
    with pytest.raises(InputError, match="chunk_frames"):
        C.frame_ranges(10, 0)


def _same(a, b, path=""):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _same(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, (list, tuple)) and not isinstance(a, str):
        assert len(a) == len(b), path
        for i, (u, v) in enumerate(zip(a, b)):
            _same(u, v, f"{path}[{i}]")
    elif isinstance(a, np.ndarray):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9, equal_nan=True, err_msg=path)
    elif isinstance(a, float):
        assert (a != a and b != b) or abs(a - b) <= 1e-9, (path, a, b)
    else:
        assert a == b, (path, a, b)


def test_noise_in_chunks_equals_one_pass(tmp_path):
    cap = str(datasets.noise(tmp_path / "noise", n_frames=120) / "capture")
    ref = assess_noise(Capture(cap))
    parts = [C.noise_chunk(cap, a, b) for a, b in C.frame_ranges(120, 100, C.noise_multiple())]
    assert len(parts) == 2
    res = C.noise_result(C.merge_noise(parts[0], parts[1]))
    _same(ref.to_dict(), res.to_dict())


def test_warmup_in_chunks_equals_one_pass(tmp_path):
    cap = str(datasets.warmup(tmp_path / "warm", duration_s=1200.0, interval_s=30.0) / "capture")
    ref = assess_warmup(Capture(cap))
    plan = C.warmup_patch(cap)
    series = [C.warmup_chunk(cap, a, b, plan["patch"]) for a, b in C.frame_ranges(plan["n_frames"], 7)]
    _same(ref.to_dict(), C.warmup_result(cap, plan, series).to_dict())
