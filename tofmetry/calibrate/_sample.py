"""A depth-calibration sample: one averaged depth image with its reference depth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class DepthSample:
    """One calibration sample.

    Attributes
    ----------
    measured_mm : (H, W) float [mm], NaN or 0 = invalid (e.g. a temporal mean)
    reference_mm : (H, W) float [mm], NaN where the true depth is unknown
    weight : (H, W) float >= 0 or None (uniform); 0 = pixel not used
    name : str
    sem_mm : (H, W) float [mm] or None, standard error of ``measured_mm`` (temporal std /
        sqrt(frames)): weights the fit and separates noise in the metrics
    free_tilt : bool, the reference plane's orientation is uncertain (a wall): a tilt is fitted
        per sample and tilt-like deformation is not calibrated
    """

    measured_mm: np.ndarray
    reference_mm: np.ndarray
    weight: np.ndarray | None = None
    name: str = ""
    sem_mm: np.ndarray | None = None
    free_tilt: bool = False
