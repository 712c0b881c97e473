"""The one frame path: uint16 depth frame -> corrected depth [mm] -> undistorted points [m].

Every command and pipeline that turns frames into corrected depth or points goes through
:class:`FramePath`, which prepares the calibration's kernels once per capture:

* corrected depth of a uint16 frame: the uint16 kernel behind
  :func:`tofmetry.calibrate.apply_depth_calibration` (range table + per-pixel linear form);
* points of a uint16 frame: :class:`tofmetry.calibrate.FrameCorrector`, the fused correct +
  undistort + back-project kernel (0.2-0.4 ms per 512x424 frame, see ``bench/``). Without a
  calibration the same kernel runs with :func:`identity_calibration`, so calibrated and raw
  clouds share one code path;
* points of a *float* depth map (a temporal mean: sub-millimetre values that rounding to the
  uint16 kernel's integer-mm tables would lose, 0.29 mm RMS): the same ray table, in numpy
  (:func:`tofmetry.pointcloud.depth_to_points`), once per capture rather than per frame.

Pure on arrays: no files, no printing.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from tofmetry.calibrate import (
    DepthCalibration,
    FrameCorrector,
    apply_depth_calibration,
    correct_and_backproject,
    count_outside_range,
)
from tofmetry.errors import InputError
from tofmetry.pointcloud import depth_to_points
from tofmetry.sensor import CameraIntrinsics


@lru_cache(maxsize=8)
def identity_calibration(intrinsics: CameraIntrinsics) -> DepthCalibration:
    """A calibration that corrects nothing: ``corrected(d) = d`` exactly, for every depth.

    Lets a raw frame take the calibrated frame's kernel (:class:`FrameCorrector`). Zero range
    curve, one zero surface; cached per intrinsics (its tables take about 7 MB for 512x424).

    Parameters
    ----------
    intrinsics : CameraIntrinsics of the depth camera (gives the image size and the rays)

    Returns
    -------
    DepthCalibration with ``provenance == {"identity": True}``
    """
    h, w = intrinsics.shape
    return DepthCalibration(
        sensor="unknown", intrinsics=intrinsics, range_knots=np.array([1.0, 1.0, 65535.0, 65535.0]),
        range_coeffs=np.zeros(2), range_degree=1, range_data_mm=np.array([1.0, 65535.0]),
        valid_range_mm=np.array([1.0, 65535.0]), node_mm=np.array([1.0]), surfaces=np.zeros((1, h, w), np.float32),
        offset_mm=0.0, surface_model="none", provenance={"identity": True})


def _check_u16(depth: np.ndarray, shape: tuple[int, int], what: str) -> np.ndarray:
    if not isinstance(depth, np.ndarray) or depth.dtype != np.uint16 or depth.shape != tuple(shape):
        raise InputError(f"{what}: depth must be a {shape} uint16 image [mm], found "
                         f"{getattr(depth, 'shape', None)} {getattr(depth, 'dtype', type(depth).__name__)}")
    return depth


class FramePath:
    """Prepared per-capture frame path: correction, undistortion and back-projection.

    Parameters
    ----------
    intrinsics : CameraIntrinsics of the depth camera (its rays back-project the points)
    calibration : DepthCalibration or None (raw depth: the identity calibration's kernel)
    undistort : use the undistorted ray table (default) or the plain pinhole one

    Attributes
    ----------
    calibrated : bool, a calibration was given
    shape : (H, W)

    Notes
    -----
    One instance per consumer thread: :meth:`points` with ``out`` given reuses that buffer.
    """

    def __init__(self, intrinsics: CameraIntrinsics, calibration: DepthCalibration | None = None,
                 undistort: bool = True) -> None:
        if calibration is not None:
            calibration.check_compatible(shape=intrinsics.shape)
        self.intrinsics = intrinsics
        self.calibration = calibration
        self.calibrated = calibration is not None
        self.undistort = bool(undistort)
        self.shape = intrinsics.shape
        self._cal = calibration if calibration is not None else identity_calibration(intrinsics)
        self._rays = np.ascontiguousarray(intrinsics.ray_table(self.undistort), dtype=np.float32)
        self._corrector = FrameCorrector(self._cal, self._rays)

    # ------------------------------------------------------------------ depth
    def correct(self, depth: np.ndarray) -> np.ndarray:
        """Corrected depth of one raw frame.

        Parameters
        ----------
        depth : (H, W) uint16 [mm] (0 = invalid), or float [mm] (0/NaN = invalid)

        Returns
        -------
        (H, W) float32 [mm] for uint16 input (the uint16 kernel), float64 [mm] for float input;
        invalid pixels stay 0 (NaN); depths outside the calibration's support get its fallback
        (:meth:`outside_range` counts them). Without a calibration: the depth itself, as float.
        """
        if not self.calibrated:
            d = np.asarray(depth)
            return d.astype(np.float32 if d.dtype == np.uint16 else np.float64)
        return apply_depth_calibration(depth, self._cal)

    def correct_u16(self, depth: np.ndarray) -> np.ndarray:
        """Corrected depth of one uint16 frame, rounded to a uint16 frame [mm]: invalid (0) pixels
        stay 0, valid ones are clipped to 1..65535 mm so that none becomes invalid."""
        depth = _check_u16(depth, self.shape, "correct_u16")
        c = self.correct(depth)
        return np.where(depth > 0, np.clip(np.rint(c), 1, 65535), 0).astype(np.uint16)

    def outside_range(self, depth: np.ndarray) -> int:
        """Number of valid pixels outside the calibration's support (given its fallback, or left
        uncorrected by a calibration without a support map); 0 without calibration."""
        return count_outside_range(depth, self._cal) if self.calibrated else 0

    # ------------------------------------------------------------------ points
    def points(self, depth: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Points of one raw uint16 frame: corrected, undistorted, back-projected in one kernel.

        Parameters
        ----------
        depth : (H, W) uint16 [mm], 0 = invalid
        out : optional (>= H*W, 3) float32 C-contiguous buffer reused across frames; the result is
            then a view of its first N rows. Default: a new (N, 3) array.

        Returns
        -------
        (N, 3) float32 [m], camera frame, one point per valid pixel in row-major order
        (:meth:`index` gives their pixels).
        """
        depth = _check_u16(depth, self.shape, "points")
        if out is not None:
            return self._corrector(depth, out)
        return correct_and_backproject(depth, self._cal, self._rays)

    @staticmethod
    def index(depth: np.ndarray) -> np.ndarray:
        """(N,) int64 flat pixel index of each point :meth:`points` returns for ``depth``."""
        return np.flatnonzero(np.asarray(depth).reshape(-1))

    def backproject(self, depth_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points of a depth map that is already corrected (or raw, without calibration), e.g. a
        temporal mean whose sub-millimetre values the uint16 kernel would round.

        Parameters
        ----------
        depth_mm : (H, W) float or uint16 [mm], 0/NaN = invalid

        Returns
        -------
        points : (N, 3) float64 [m]; index : (N,) int64 flat pixel index
        """
        return depth_to_points(depth_mm, self.intrinsics, undistort=self.undistort, return_index=True)


@lru_cache(maxsize=4)
def frame_path(intrinsics: CameraIntrinsics, calibration: DepthCalibration | None = None,
               undistort: bool = True) -> FramePath:
    """A cached :class:`FramePath` (the per-call path of :func:`tofmetry.to_points`).

    Keyed on the calibration object itself (not its file): the last 4 are kept, about 20 MB each
    for 512x424 and 8 surface nodes (tables, rays, the kernel's buffer)."""
    return FramePath(intrinsics, calibration, undistort)
