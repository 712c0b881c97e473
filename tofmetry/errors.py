"""Exception types shared by the whole package.

Every error raised on bad input names the file or parameter, what was expected and what
was found, so that a user can fix it without reading the source.
"""

from __future__ import annotations


class TofmetryError(Exception):
    """Base class of all tofmetry errors."""


class InputError(TofmetryError, ValueError):
    """Bad input data or parameter: names what was expected and what was found."""


class FormatError(InputError):
    """A file that does not follow the expected format (bit depth, resolution, schema...)."""


class SensorMismatchError(InputError):
    """A calibration or dataset made for another sensor or resolution."""


class EstimationError(TofmetryError, RuntimeError):
    """An estimator could not produce a trustworthy result; the message says why."""


class ImplausibleResultError(EstimationError):
    """A result far outside what the sensor can be (a plausibility gate failed): the message names
    each finding, the threshold and where it comes from; ``--accept-implausible`` overrides it."""

    def __init__(self, message: str, findings: list[str] | None = None):
        super().__init__(message)
        self.findings = list(findings or [])


class DegenerateFitError(EstimationError):
    """A fit converged to values that describe no physical camera or sensor (a principal point far
    outside the image, a negative focal length ...): ``reason`` says which, ``rms`` is the fit's
    residual in its own unit, so that a caller can report both as plausibility findings."""

    def __init__(self, message: str, reason: str, rms: float):
        super().__init__(message)
        self.reason, self.rms = reason, float(rms)
