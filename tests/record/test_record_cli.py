"""``tofmetry record`` through the CLI on the virtual device (the README's commands)."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.io import WallDataset


def test_record_wall_cli(tmp_path):
    out = tmp_path / "wall"
    r = CliRunner().invoke(app, ["record", "wall", "-o", str(out), "--station-mm", "1000", "--station-mm", "1500",
                                 "--distance-mm", "1001", "--distance-mm", "1499", "--frames", "3"])
    assert r.exit_code == 0, r.output
    assert [s.distance_mm for s in WallDataset(out).stations] == [1001.0, 1499.0]
    r2 = CliRunner().invoke(app, ["record", "wall", "-o", str(out)])
    assert r2.exit_code != 0 and "already exists" in str(r2.exception)


@pytest.mark.parametrize("device,extra", [("azure", "azure"), ("orbbec", "orbbec"), ("kinect2", "kinect2")])
def test_missing_extra_is_named(tmp_path, device, extra):
    import importlib.util

    mod = {"azure": "pyk4a", "orbbec": "pyorbbecsdk", "kinect2": "pylibfreenect2"}[device]
    if importlib.util.find_spec(mod) is not None:
        pytest.skip(f"{mod} is installed")
    r = CliRunner().invoke(app, ["record", "wall", "-o", str(tmp_path / "x"), "--device", device])
    assert r.exit_code != 0 and f"pip install tofmetry[{extra}]" in str(r.exception)
    assert not (tmp_path / "x").exists()
