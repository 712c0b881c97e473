"""Small virtual-sensor datasets shared by the CLI tests (built once per session)."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

SMALL_WALL_MM = (800, 1300, 1800, 2300, 2800)


@pytest.fixture(scope="session")
def small_wall(tmp_path_factory) -> Path:
    """A wall dataset of 5 stations x 3 frames (the default Kinect v2 of the simulator)."""
    from tofmetry.simulate import ErrorModel, datasets

    root = tmp_path_factory.mktemp("cli-data")
    em = ErrorModel().with_(wiggle_amps_mm=(4.5, 0.0, 0.0))
    return datasets.wall_dataset(root / "wall", distances_mm=list(SMALL_WALL_MM), n_frames=3, errors=em, seed=1)


@pytest.fixture(scope="session")
def small_cal(small_wall, tmp_path_factory) -> Path:
    """A calibration file fitted on :func:`small_wall`."""
    from tofmetry.pipelines import calibrate_depth_dataset, save_calibration

    out = tmp_path_factory.mktemp("cli-cal") / "cal.npz"
    return save_calibration(out, calibrate_depth_dataset(small_wall).calibration)


@pytest.fixture(scope="session")
def one_capture(small_wall) -> Path:
    """The 1800 mm station's capture folder."""
    from tofmetry.io import WallDataset

    return WallDataset(small_wall).stations[2].path


def tree_hash(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (relative path -> digest), plus each folder's listing."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        rel = os.path.relpath(dirpath, root)
        out[f"{rel}/"] = ",".join(sorted(dirnames + filenames))
        for f in filenames:
            p = Path(dirpath) / f
            out[os.path.join(rel, f)] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out
