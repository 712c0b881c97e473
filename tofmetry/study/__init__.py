"""The whole study (assessment -> calibration -> validation -> model -> accuracy) and the demo."""

from tofmetry.study.config import StudyConfig, config_to_toml, load_config
from tofmetry.study.demo import run_demo

__all__ = ["StudyConfig", "config_to_toml", "load_config", "run_demo"]
