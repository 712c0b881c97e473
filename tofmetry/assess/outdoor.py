"""Strong light and flying pixels (study §3.3.2, Figure 5).

For each frame: the valid fraction against the full sensor (H x W = 217 088 pixels for the
Kinect v2) and the flying pixels found by :func:`~tofmetry.assess.flying.detect_flying_pixels`
with their share of the point cloud (study, sunny day: ~20 % valid, ~2 % flying).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from tofmetry.assess._source import check_frame, frame_iter
from tofmetry.assess.flying import FlyingPixelParams, detect_flying_pixels
from tofmetry.errors import InputError
from tofmetry.pointcloud import amplitude_colors
from tofmetry.sensor.intrinsics import CameraIntrinsics


@dataclass
class OutdoorResult:
    """Result of :func:`assess_outdoor`.

    Attributes
    ----------
    n_max : int, H * W (maximal number of points of one cloud)
    valid : (T,) int, valid pixels per frame
    flying : (T,) int, flying pixels per frame
    frame : int, index of the frame kept for the figures/cloud
    depth : (H, W) depth of that frame [mm]; flying_mask : (H, W) bool; ir : (H, W) or None
    """

    n_max: int
    valid: np.ndarray
    flying: np.ndarray
    frame: int
    depth: np.ndarray
    flying_mask: np.ndarray
    ir: np.ndarray | None
    params: FlyingPixelParams
    notes: list = field(default_factory=list)

    @property
    def valid_fraction(self) -> float:
        """Mean fraction of valid pixels over the frames."""
        return float(self.valid.mean() / self.n_max)

    @property
    def flying_share(self) -> float:
        """Flying pixels as a share of the valid points (mean over frames)."""
        return float(self.flying.sum() / max(self.valid.sum(), 1))

    def to_dict(self) -> dict:
        return {
            "analysis": "outdoor", "n_frames": int(len(self.valid)), "n_max_points": self.n_max,
            "valid_points_mean": float(self.valid.mean()), "valid_fraction": self.valid_fraction,
            "flying_points_mean": float(self.flying.mean()), "flying_share_of_cloud": self.flying_share,
            "figure_frame": self.frame, "detector": self.params.to_dict(),
            "per_frame": {"valid": self.valid, "flying": self.flying}, "notes": list(self.notes),
        }


def assess_outdoor(source, *, intr: CameraIntrinsics | None = None, params: FlyingPixelParams | None = None,
                   frame: int = 0, max_frames: int | None = None, ir: np.ndarray | None = None,
                   progress: Callable[[], None] | None = None) -> OutdoorResult:
    """Valid fraction and flying pixels of (strong-light) captures.

    Parameters
    ----------
    source : Capture or (T, H, W) depth frames [mm] (streamed)
    intr : CameraIntrinsics (capture's if omitted; needed for the focal length)
    params : FlyingPixelParams of the detector
    frame : index of the frame kept for the figures and the exported cloud
    max_frames : analyse at most this many frames
    ir : (T, H, W) or (H, W) IR amplitude (the capture's IR frames if omitted); used by the
        detector's noise term (per frame) and to colour the cloud. Without IR the noise is
        scaled with depth only (noted in the result).

    Returns
    -------
    OutdoorResult
    """
    p = params or FlyingPixelParams()
    if intr is None and hasattr(source, "intrinsics"):
        intr, _ = source.intrinsics()
    valid, flying = [], []
    keep = None
    notes = []
    cap_ir = ir is None and getattr(source, "has_ir", False)
    if ir is None and not cap_ir:
        notes.append("no IR amplitude: flying-pixel noise threshold scaled with depth only")
    for i, f in enumerate(frame_iter(source, progress)):
        if max_frames is not None and i >= max_frames:
            break
        f = check_frame(f, None if intr is None else intr.shape, i, "outdoor")
        a = source.ir(i) if cap_ir else (None if ir is None else (ir[i] if np.ndim(ir) == 3 else ir))
        m = detect_flying_pixels(f, intr, p, ir=a)
        valid.append(int((f > 0).sum()))
        flying.append(int(m.sum()))
        if i == frame:
            keep = (f.copy(), m, a)
    if not valid:
        raise InputError("outdoor: no frames")
    if keep is None:
        raise InputError(f"outdoor: frame {frame} outside 0..{len(valid) - 1}")
    return OutdoorResult(n_max=int(keep[0].size), valid=np.array(valid), flying=np.array(flying), frame=frame,
                         depth=keep[0], flying_mask=keep[1], ir=None if keep[2] is None else np.asarray(keep[2]),
                         params=p, notes=notes)


def flying_cloud(result: OutdoorResult, points: np.ndarray,
                 index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kept frame's cloud coloured for display: flying pixels red, others grey (IR amplitude).

    Parameters
    ----------
    result : OutdoorResult
    points : (N, 3) float [m], the back-projection of ``result.depth`` (camera frame)
    index : (N,) int, flat pixel index of each point in ``result.depth``

    Returns
    -------
    points : (N, 3) [m], as given; colors : (N, 3) uint8; is_flying : (N,) bool
    """
    pts, idx = np.asarray(points), np.asarray(index)
    if len(pts) != len(idx):
        raise InputError(f"flying_cloud: {len(pts)} points for {len(idx)} pixel indices")
    fly = result.flying_mask.ravel()[idx]
    if result.ir is not None:
        cols = amplitude_colors(result.ir.ravel()[idx])
    else:
        cols = np.full((len(idx), 3), 170, np.uint8)
    cols[fly] = (255, 0, 0)
    return pts, cols, fly
