"""The virtual Kinect v2: static rendering once per pose, then per-frame errors.

>>> vk = VirtualKinect(errors=ErrorModel(), seed=0)                    # doctest: +SKIP
>>> frames = vk.capture(scenes.wall(1.0), n_frames=50)               # doctest: +SKIP
>>> frames.depth.shape, frames.depth.dtype                           # doctest: +SKIP
((50, 424, 512), dtype('uint16'))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics
from tofmetry.sensor.profiles import KINECT_V2
from tofmetry.simulate import errors as E
from tofmetry.simulate.render import Rendering, render
from tofmetry.simulate.surfaces import Scene


@dataclass
class Frame:
    """One simulated frame: depth (H, W) uint16 [mm] (float64 if quantisation is off),
    ir (H, W) uint16 (None when not asked for), flying (H, W) bool labels, timestamp_s (since power-on)."""

    depth: np.ndarray
    ir: np.ndarray
    flying: np.ndarray
    timestamp_s: float


@dataclass
class Frames:
    """A stack of simulated frames of one pose.

    Attributes
    ----------
    depth : (T, H, W) uint16 [mm], 0 = invalid (float64 when ``quantize`` is off)
    ir : (T, H, W) uint16 amplitude
    true_depth : (H, W) float64 [mm], Z of the true surface at each pixel centre, 0 = no hit
    flying : (T, H, W) bool, mixed/flying pixel labels
    timestamps_s : (T,) float64, time since power-on [s]
    labels : (H, W) int32 scene label per pixel (-1 = no hit); label_names : dict
    amplitude : (H, W) float64 noise-free amplitude
    pose : (4, 4) camera-to-world [m]
    """

    depth: np.ndarray
    ir: np.ndarray
    true_depth: np.ndarray
    flying: np.ndarray
    timestamps_s: np.ndarray
    labels: np.ndarray
    label_names: dict = field(default_factory=dict)
    amplitude: np.ndarray | None = None
    pose: np.ndarray | None = None

    def __len__(self) -> int:
        return self.depth.shape[0]


class VirtualKinect:
    """Simulated Kinect v2 depth/IR camera.

    Another sensor of the class (lens + errors) comes from the family:
    ``tofmetry.simulate.random_sensor(seed).camera(seed=0)``.

    Parameters
    ----------
    errors : ErrorModel, default ``ErrorModel()`` (all terms on)
    seed : int, makes every capture deterministic (captures are numbered in call order)
    intrinsics : CameraIntrinsics, default the typical Kinect v2 depth camera
    supersample : int, sub-rays per pixel per axis (anti-aliasing and flying pixels)
    """

    def __init__(self, errors: E.ErrorModel | None = None, seed: int = 0, intrinsics: CameraIntrinsics | None = None,
                 supersample: int = 3):
        self.errors = errors if errors is not None else E.ErrorModel()
        self.seed = int(seed)
        self.intrinsics = intrinsics if intrinsics is not None else KINECT_V2.depth
        self.supersample = int(supersample)
        self._n_captures = 0

    # ----------------------------------------------------------- static part
    def render(self, scene: Scene, pose: np.ndarray | None = None, supersample: int | None = None) -> Rendering:
        """Noise-free rendering (raycast once) of ``scene`` from ``pose`` (4x4 camera-to-world)."""
        pose = np.eye(4) if pose is None else pose
        return render(scene, self.intrinsics, pose, self.errors, supersample or self.supersample)

    def systematic_mm(self, rd: Rendering) -> np.ndarray:
        """Static systematic bias map (H, W) [mm] of a rendering: wiggling + deformation + amplitude bias."""
        em = self.errors
        z = rd.depth0
        bias = np.zeros_like(z)
        if em.on("wiggling"):
            bias += E.wiggling_mm(z, em, rd.xy)
        if em.on("deformation"):
            bias += E.deformation_mm(rd.xy, z, em)
        if em.on("amplitude_bias"):
            bias += np.where(z > 0, E.amplitude_bias_mm(rd.rel_reflectance, em), 0.0)
            if em.amp_bias_abs_mm_per_ln != 0.0:
                bias += np.where(z > 0, E.amplitude_bias_abs_mm(rd.amplitude, em), 0.0)
            bias += np.where(rd.reflective, rd.refl_bias_mm, 0.0)
        return bias

    # ----------------------------------------------------------- frames
    def iter_frames(self, scene: Scene, n_frames: int = 50, pose: np.ndarray | None = None, t0_s: float = 3600.0,
                    dt_s: float = 1.0, rendering: Rendering | None = None,
                    timestamps_s: np.ndarray | None = None, *, with_ir: bool = True) -> Iterator[Frame]:
        """Generate frames one by one (constant memory); see :meth:`capture`.

        ``with_ir=False`` leaves ``Frame.ir`` None (the IR noise is still drawn, so that the
        depth frames are the same as with IR). The arithmetic is done in place but is
        element for element the same as the plain expressions in the comments.
        """
        if n_frames < 1:
            raise InputError(f"capture: n_frames must be >= 1, found {n_frames}")
        rd = rendering if rendering is not None else self.render(scene, pose)
        em = self.errors
        ss = np.random.SeedSequence([self.seed, self._n_captures])
        self._n_captures += 1
        rng = np.random.default_rng(ss)
        ts = (t0_s + dt_s * np.arange(n_frames)) if timestamps_s is None else np.asarray(timestamps_s, float)
        if ts.shape != (n_frames,):
            raise InputError(f"capture: {ts.shape[0]} timestamps for {n_frames} frames")
        H, W = rd.depth0.shape
        hit = rd.depth0 > 0
        base = rd.depth0 + self.systematic_mm(rd)
        sigma = E.noise_sigma_mm(rd.amplitude, rd.depth0, em) if em.on("noise") else None
        amp_thr = em.min_amplitude + em.ambient * em.ambient_amp_threshold
        low_amp = rd.amplitude < amp_thr
        static_ok = hit & ~low_amp if em.on("invalid") else hit
        spray_p = None
        if em.on("flying") and em.ambient > 0:
            # outdoors: spurious flying pixels, more toward the edges of the field of view
            q = (rd.xy[..., 0] / 0.75) ** 2 + (rd.xy[..., 1] / 0.62) ** 2
            spray_p = np.clip(em.ambient * em.ambient_spray_prob * (0.25 + 1.5 * q ** 2), 0, 0.9)
        refl_idx = np.flatnonzero(rd.reflective & hit) if em.on("amplitude_bias") else np.zeros(0, np.int64)
        mix = rd.mixed_idx if em.on("flying") else np.zeros(0, np.int64)
        mz, ma = rd.mixed_z, rd.mixed_a
        mz0 = np.nan_to_num(mz)
        noise = np.empty((H, W))
        for k in range(n_frames):
            z = base.copy()
            flying = np.zeros((H, W), bool)
            zf = z.reshape(-1)
            if mix.size:
                w = ma * np.exp(em.flying_jitter * rng.standard_normal(ma.shape))
                zm = (w * mz0).sum(1) / np.maximum(w.sum(1), 1e-12)
                zf[mix] = zm + (base.reshape(-1)[mix] - rd.depth0.reshape(-1)[mix])
                gap = np.nanmin(np.abs(mz - zm[:, None]), axis=1)
                flying.reshape(-1)[mix] = gap > em.flying_label_mm
            if em.on("warmup"):
                z += float(E.warmup_mm(ts[k], em))
            if refl_idx.size:
                zf[refl_idx] += em.reflective_jitter_mm * rng.standard_normal(refl_idx.size)
            if sigma is not None:  # z += sigma * N(0, 1)
                rng.standard_normal(out=noise)
                noise *= sigma
                z += noise
            if spray_p is not None:
                spray = (rng.random((H, W)) < spray_p) & hit
                z = np.where(spray, z * rng.uniform(0.35, 0.95, (H, W)), z)
                flying |= spray
            valid = static_ok & (z >= em.min_range_mm) & (z <= em.max_range_mm) if em.on("invalid") else hit.copy()
            if em.on("quantize"):  # where(valid, clip(rint(z), 0, 65535), 0) as uint16
                valid &= z >= 0.5
                np.rint(z, out=z)
                np.clip(z, 0, 65535, out=z)
                depth = z.astype(np.uint16)
                depth[~valid] = 0
            else:
                depth = np.where(valid, z, 0.0)
            flying &= valid
            if em.on("noise"):  # a = amplitude * (1 + rel N(0, 1))
                rng.standard_normal(out=noise)
                noise *= em.amp_noise_rel
                noise += 1.0
                noise *= rd.amplitude
                a = noise
            else:
                a = rd.amplitude.copy()
            ir = None
            if with_ir:  # clip(rint(a), 0, 65535) as uint16
                np.rint(a, out=a)
                np.clip(a, 0, 65535, out=a)
                ir = a.astype(np.uint16)
            yield Frame(depth, ir, flying, float(ts[k]))

    def capture(self, scene: Scene, n_frames: int = 50, pose: np.ndarray | None = None, t0_s: float = 3600.0,
                dt_s: float = 1.0, progress: Callable[[int], None] | None = None,
                timestamps_s: np.ndarray | None = None) -> Frames:
        """Simulate ``n_frames`` frames of ``scene`` seen from ``pose``.

        Parameters
        ----------
        scene : Scene (world frame, metres)
        n_frames : int
        pose : (4, 4) camera-to-world [m], default identity
        t0_s, dt_s : float
            Time since power-on of the first frame and frame interval [s] (drives warm-up;
            3600 s = already warm).
        progress : optional ``advance(n)`` callable, called once per frame.
        timestamps_s : (n_frames,) optional explicit times since power-on (overrides t0/dt).

        Returns
        -------
        Frames
        """
        pose = np.eye(4) if pose is None else np.asarray(pose, float)
        rd = self.render(scene, pose)
        dtype = np.uint16 if self.errors.on("quantize") else np.float64
        H, W = rd.depth0.shape
        depth = np.empty((n_frames, H, W), dtype)
        ir = np.empty((n_frames, H, W), np.uint16)
        fly = np.empty((n_frames, H, W), bool)
        ts = np.empty(n_frames)
        for k, fr in enumerate(self.iter_frames(scene, n_frames, pose, t0_s, dt_s, rendering=rd,
                                                timestamps_s=timestamps_s)):
            depth[k], ir[k], fly[k], ts[k] = fr.depth, fr.ir, fr.flying, fr.timestamp_s
            if progress is not None:
                progress(1)
        return Frames(depth, ir, rd.true_depth, fly, ts, rd.labels, dict(scene.labels), rd.amplitude, pose)
