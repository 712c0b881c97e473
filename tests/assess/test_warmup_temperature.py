"""Warm-up drift against the sensor temperature the recording holds (virtual device's thermal model)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from tofmetry.assess import assess_warmup, capture_temperature, drift_temperature_slope
from tofmetry.devices.virtual import VirtualDevice, virtual_temperature_c
from tofmetry.errors import InputError
from tofmetry.io import Capture
from tofmetry.pipelines.assess import write_assessment
from tofmetry.record import WarmupSession, run_recording
from tofmetry.simulate import scenes


@pytest.fixture(scope="module")
def cold_recording(tmp_path_factory):
    """A warm-up recorded by ``tofmetry record warmup`` on a cold virtual sensor (one frame every 30 s)."""
    out = tmp_path_factory.mktemp("warm") / "cold"
    dev = VirtualDevice(scenes.wall(1.36, (1.5, -2.0)), fps=1 / 30, realtime=False, t0_s=0.0)
    run_recording(dev, WarmupSession(out, interval_s=30), lambda r: None, max_frames=400)
    return out, dev.errors


def test_drift_per_degree_matches_the_virtual_sensor(cold_recording, tmp_path):
    path, em = cold_recording
    cap = Capture(path)
    res = assess_warmup(cap)
    assert res.temperature_name == "sensor" and res.temperature_c.shape == res.time_s.shape
    # the simulator: drift = k (state - level), temperature = ambient + 16 °C x state -> k / 16 mm/°C
    truth = em.warmup_mm / em.warmup_fan_level / 16.0
    f = res.temperature_fit
    assert f["n"] == len(cap) and f["temperature_range_c"][1] - f["temperature_range_c"][0] > 10
    assert abs(f["slope_mm_per_c"] - truth) < 3 * f["slope_se_mm_per_c"]
    assert f["slope_se_mm_per_c"] < 0.02 and f["r2"] > 0.95
    lo, hi = f["slope_ci95_mm_per_c"]
    assert lo < f["slope_mm_per_c"] < hi
    # written: JSON with the fit and the series, one figure with the temperature panel
    files = write_assessment(res, tmp_path / "out", "warmup.json")
    d = json.loads(files["json"].read_text())
    assert d["temperature"]["fit"]["slope_mm_per_c"] == pytest.approx(f["slope_mm_per_c"])
    assert len(d["series"]["temperature_c"]) == len(cap)
    (png,) = files["figures"]
    with Image.open(png) as im:
        wide = im.size
    plain = assess_warmup(cap, temperature_c=np.full(len(cap), np.nan))   # no usable temperature
    with Image.open(write_assessment(plain, tmp_path / "plain", "w.json")["figures"][0]) as im:
        assert wide[0] > 1.3 * im.size[0]                                # the second panel


def test_recording_without_temperature_gives_no_fit(cold_recording, tmp_path):
    path, _ = cold_recording
    cap = Capture(path)
    del cap.meta.extra["temperature_c"]
    res = assess_warmup(cap)
    assert res.temperature_c is None and res.temperature_fit is None and res.to_dict()["temperature"] is None
    steady = assess_warmup(cap, temperature_c=np.full(len(cap), 30.0))
    assert steady.temperature_fit is None and any("temperature varied by 0.00 °C" in n for n in steady.notes)


def test_bad_temperature_lists_are_named(cold_recording):
    cap = Capture(cold_recording[0])
    cap.meta.extra["temperature_c"] = {"sensor": [30.0, 31.0]}
    with pytest.raises(InputError, match=r"capture.json 'temperature_c'.*2 values"):
        capture_temperature(cap, len(cap))
    cap.meta.extra["temperature_c"] = {"sensor": [None] * (len(cap) - 1) + ["hot"]}
    with pytest.raises(InputError, match="not a number"):
        capture_temperature(cap, len(cap))


def test_serially_correlated_residuals_widen_the_error():
    # a straight line plus slowly wandering (AR(1), rho 0.5) residuals: the corrected interval covers
    # the truth about as often as promised, the independent-frames interval does not
    rng = np.random.default_rng(3)
    n, draws, cover, cover_ols = 120, 300, 0, 0
    temp = virtual_temperature_c(np.arange(n) * 30.0, VirtualDevice(realtime=False).errors)
    for _ in range(draws):
        e = np.zeros(n)
        for i in range(1, n):
            e[i] = 0.5 * e[i - 1] + rng.normal(0, 0.1)
        f = drift_temperature_slope(temp, 0.45 * temp + e)
        lo, hi = f["slope_ci95_mm_per_c"]
        cover += lo < 0.45 < hi
        cover_ols += abs(f["slope_mm_per_c"] - 0.45) < 1.96 * f["slope_se_ols_mm_per_c"]
    assert cover / draws > 0.85 and cover_ols / draws < cover / draws - 0.1
    with pytest.raises(InputError, match="3 temperatures for 4 distances"):
        drift_temperature_slope(np.ones(3), np.ones(4))
