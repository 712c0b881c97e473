"""The public API: ``import tofmetry`` stays light, the names are functions, the results are the frame path's."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import tofmetry
from tofmetry.errors import InputError
from tofmetry.pipelines.frame_path import FramePath
from tofmetry.sensor import KINECT_V2


def test_import_tofmetry_loads_no_library():
    code = ("import sys, tofmetry; heavy = [m for m in ('numpy', 'numba', 'cv2', 'open3d', 'matplotlib', 'scipy') "
            "if m in sys.modules]; print(heavy); assert not heavy")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_api_names_are_callable_and_the_sub_packages_stay_modules():
    import tofmetry.evaluate._stats as stats  # module idioms keep working
    import tofmetry.reconstruct as rec
    from tofmetry.reconstruct import ReconstructionConfig

    for name in tofmetry.__all__:
        assert callable(getattr(tofmetry, name)), name
    assert rec is tofmetry.reconstruct and rec.ReconstructionConfig is ReconstructionConfig
    assert stats.deviation_stats is tofmetry.evaluate.deviation_stats
    for name in ("evaluate", "reconstruct"):  # the sub-package runs the API function of its name
        with pytest.raises(InputError):
            getattr(tofmetry, name)("no/such/folder", "no/such/file.ply")
    assert set(tofmetry.__all__) <= set(dir(tofmetry))
    with pytest.raises(AttributeError):
        tofmetry.no_such_name  # noqa: B018


def test_to_points_and_correct_are_the_frame_path():
    intr = KINECT_V2.depth
    d = np.full(intr.shape, 1500, np.uint16)
    d[::7, ::5] = 0
    pts = tofmetry.to_points(d, intrinsics=intr)
    np.testing.assert_array_equal(pts, FramePath(intr).points(d))
    buf = np.empty((d.size, 3), np.float32)
    assert np.shares_memory(tofmetry.to_points(d, intrinsics=intr, out=buf), buf)
    mean = np.where(d > 0, d + 0.25, 0.0)  # float depth (a temporal mean) keeps its fraction of a mm
    np.testing.assert_allclose(tofmetry.to_points(mean, intrinsics=intr)[:, 2], 1.50025)
    with pytest.raises(InputError, match="intrinsics"):
        tofmetry.to_points(d)
