"""Shared simulated datasets for the assessment tests (small, session-scoped)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def sim_root(tmp_path_factory):
    return tmp_path_factory.mktemp("assess_sim")


@pytest.fixture(scope="session")
def warmup_ds(sim_root):
    from tofmetry.simulate import datasets

    # 90 min at one frame per minute (the study: every 15 s) keeps the test short
    return datasets.warmup(sim_root / "warmup", duration_s=5400.0, interval_s=60.0, seed=3)


@pytest.fixture(scope="session")
def grey_ds(sim_root):
    from tofmetry.simulate import datasets

    return datasets.materials(sim_root / "grey", board="grey", n_frames=4, seed=4)


@pytest.fixture(scope="session")
def samples_ds(sim_root):
    from tofmetry.simulate import datasets

    return datasets.materials(sim_root / "samples", board="samples", n_frames=4, seed=5)


@pytest.fixture(scope="session")
def noise_small_ds(sim_root):
    from tofmetry.simulate import datasets

    return datasets.noise(sim_root / "noise_small", n_frames=10, seed=6)
