"""Sensor assessment (study §3): warm-up, temporal noise, materials, strong light / flying pixels.

Each analysis is a function on a capture (or plain frame arrays) returning a result object
with ``to_dict()``; :mod:`tofmetry.assess.figures` draws them (``save_figures(result, out_dir)``).
"""

from tofmetry.assess.figures import save_figures
from tofmetry.assess.flying import FlyingPixelParams, detect_flying_pixels, neighbour_support, remove_flying_pixels
from tofmetry.assess.materials import MaterialsResult, RegionStats, assess_materials, fit_reference_plane
from tofmetry.assess.noise import (
    NoiseResult, StdSummary, assess_noise, noise_result_from, recommend_n, sigma_from_stds, summarize_std_map,
)
from tofmetry.assess.outdoor import OutdoorResult, assess_outdoor, flying_cloud
from tofmetry.assess.regions import Region, auto_grey_board_regions, regions_from_dict, regions_to_dict
from tofmetry.assess.warmup import (WarmupResult, assess_warmup, capture_temperature, drift_temperature_slope,
                                    local_linear_smooth, select_patch, warmup_from_series)


__all__ = [
    "FlyingPixelParams", "detect_flying_pixels", "neighbour_support", "remove_flying_pixels",
    "MaterialsResult", "RegionStats", "assess_materials", "fit_reference_plane",
    "NoiseResult", "StdSummary", "assess_noise", "noise_result_from", "recommend_n", "sigma_from_stds", "summarize_std_map",
    "OutdoorResult", "assess_outdoor", "flying_cloud",
    "Region", "auto_grey_board_regions", "regions_from_dict", "regions_to_dict",
    "WarmupResult", "assess_warmup", "capture_temperature", "drift_temperature_slope", "local_linear_smooth", "select_patch", "save_figures", "warmup_from_series",
]
