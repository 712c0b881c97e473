"""Study configuration: TOML round trip, documented keys, clear errors."""

from __future__ import annotations

import pytest

from tofmetry.errors import InputError
from tofmetry.study import StudyConfig, config_to_toml, load_config


def test_defaults_round_trip_through_toml(tmp_path):
    cfg = StudyConfig()
    p = tmp_path / "study.toml"
    p.write_text(config_to_toml(cfg))
    assert load_config(p) == cfg


def test_every_key_is_documented():
    text = config_to_toml(StudyConfig())
    for section, model in StudyConfig():
        for name, field in type(model).model_fields.items():
            assert field.description, f"{section}.{name} has no description"
            assert field.description in text


def test_defaults_follow_the_study():
    s = StudyConfig().simulation
    assert s.wall_distances_mm[0] == 800 and s.wall_distances_mm[1:3] == [1000, 1250] and s.wall_distances_mm[-1] == 6000
    assert (s.wall_frames, s.noise_frames, s.scan_views, s.scan_frames) == (50, 100, 8, 10)
    assert s.warmup_duration_s == 5400 and s.warmup_interval_s == 15


@pytest.mark.parametrize("text, word", [
    ("[simulation]\nwall_frames = 0\n", "simulation.wall_frames"),
    ("[intrinsics]\nboard = 'nine'\n", "intrinsics.board"),
    ("[nope]\nx = 1\n", "nope"),
    ("[simulation\n", "invalid TOML"),
])
def test_bad_config_names_the_key(tmp_path, text, word):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(InputError, match=word.replace(".", r"\.")):
        load_config(p)


def test_missing_config_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_config(tmp_path / "none.toml")
