"""Long recordings in chunks of frames: correction, noise and warm-up, one chunk per task.

Each chunk streams its frames (one or a few in memory at a time), so the memory of a worker
does not depend on the length of the recording. The chunks' results combine exactly:

* ``correct``: every chunk writes its corrected frames into the job's staging folder under their
  final names; the counts of valid and outside-the-support samples add up; the plausibility gate
  and ``capture.json`` are those of :func:`tofmetry.pipelines.correct.correct_capture`.
* noise: per-pixel moments merged with the parallel-variance formula (:mod:`.stats`); the block
  means of ``n`` frames never straddle two chunks (chunks are whole multiples of every block).
* warm-up: the patch-mean series is measured chunk by chunk and concatenated in frame order, then
  analysed once (:func:`tofmetry.assess.warmup_from_series`).

Chunk functions take paths and frame ranges (cheap to send to a worker) and return small results.
"""

from __future__ import annotations

import io
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.assess import NoiseResult, noise_result_from, select_patch, warmup_from_series
from tofmetry.assess.noise import DEFAULT_BLOCKS, DEFAULT_SUBSETS
from tofmetry.batch.stats import Moments, merge_moments
from tofmetry.errors import EstimationError, InputError
from tofmetry.io import Capture, CaptureMeta, atomic_write_bytes, atomic_write_json
from tofmetry.io.images import encode_png16
from tofmetry.pipelines.calibration_files import load_calibration
from tofmetry.pipelines.frame_path import FramePath
from tofmetry.pipelines.frame_stream import kernel_threads, stream_frames
from tofmetry.pipelines.plausibility import check_support, enforce


def frame_ranges(n_frames: int, chunk_frames: int, multiple: int = 1) -> list[tuple[int, int]]:
    """Split ``range(n_frames)`` into consecutive ``(start, stop)`` chunks.

    Parameters
    ----------
    n_frames : frames in the recording (>= 1)
    chunk_frames : wanted frames per chunk (>= 1); rounded up to a multiple of ``multiple``
    multiple : every chunk but the last is a whole multiple of this many frames

    Returns
    -------
    list of (start, stop), covering 0 .. n_frames - 1 once, in order
    """
    if n_frames < 1 or chunk_frames < 1 or multiple < 1:
        raise InputError(f"frame_ranges: n_frames, chunk_frames and multiple must be >= 1, found "
                         f"{n_frames}, {chunk_frames}, {multiple}")
    size = math.ceil(chunk_frames / multiple) * multiple
    return [(a, min(a + size, n_frames)) for a in range(0, n_frames, size)]


# ------------------------------------------------------------------------------------------ correct
def correct_chunk(capture: str, calibration: str, staging: str, start: int, stop: int,
                  float32: bool = False) -> dict:
    """Correct frames ``start .. stop - 1`` of a capture into ``staging/depth/`` (each file atomic).

    Returns
    -------
    dict ``frames``, ``outside`` (valid samples outside the calibration's support), ``valid``
    """
    cap = Capture(capture)
    cal = load_calibration(calibration)
    cal.check_compatible(sensor=cap.sensor, shape=cap.shape)
    path = FramePath(cal.intrinsics, cal)
    out = Path(staging) / "depth"
    out.mkdir(parents=True, exist_ok=True)
    counts = {"outside": 0, "valid": 0}

    def process(k: int, depth: np.ndarray) -> np.ndarray:
        counts["outside"] += path.outside_range(depth)
        counts["valid"] += int(np.count_nonzero(depth))
        if float32:
            return np.where(depth > 0, path.correct(depth), 0).astype(np.float32)
        return path.correct_u16(depth)

    def write(k: int, frame: np.ndarray) -> None:
        name = f"{start + k:06d}"
        if float32:
            buf = io.BytesIO()
            np.save(buf, frame)
            atomic_write_bytes(out / f"{name}.npy", buf.getvalue())
        else:
            atomic_write_bytes(out / f"{name}.png", encode_png16(frame))

    with kernel_threads(1):
        stream_frames(stop - start, lambda k: cap.depth(start + k), process, write, workers=2)
    return {"frames": stop - start, **counts}


def correct_finish(capture: str, calibration: str, staging: str, parts: list[dict], *,
                   accept_implausible: bool = False) -> dict:
    """Complete a chunked correction in ``staging``: check every frame is there, copy IR and colour,
    apply the plausibility gate and write ``capture.json`` (as :func:`~tofmetry.pipelines.correct.correct_capture`).

    Returns
    -------
    dict of key figures: ``n_frames``, ``outside_range``, ``valid``, ``outside_share``, ``plausibility``

    Raises
    ------
    ImplausibleResultError
        Every valid sample lies outside the calibration's support (unless accepted).
    EstimationError
        A chunk's frames are missing from the staging folder.
    """
    cap = Capture(capture)
    cal = load_calibration(calibration)
    staging = Path(staging)
    n = sum(p["frames"] for p in parts)
    written = {f.stem for f in (staging / "depth").iterdir() if not f.name.startswith(".")}
    if n != len(cap) or len(written) != len(cap):
        raise EstimationError(f"{staging}: {len(written)} corrected frames for the {len(cap)} of {capture}")
    outside, valid = sum(p["outside"] for p in parts), sum(p["valid"] for p in parts)
    lo, hi = cal.support_range_mm
    gate = enforce(check_support(outside, valid, (lo, hi), str(cap.path)), f"correcting {cap.path}", accept_implausible)
    extra = {**(cap.meta.extra or {}), "depth_calibration": str(calibration), "corrected_from": str(cap.path)}
    if gate["accepted"]:
        extra["plausibility"] = gate
    for kind, files in (("ir", cap.ir_files), ("color", cap.color_files)):
        if files:
            (staging / kind).mkdir(exist_ok=True)
            for f in files:
                shutil.copyfile(f, staging / kind / f.name)
    meta = CaptureMeta(sensor=cap.sensor, depth_unit_mm=1.0, intrinsics=cal.intrinsics,
                       timestamps_s=cap.meta.timestamps_s, extra=extra)
    atomic_write_json(staging / "capture.json", meta.to_dict())
    h, w = cap.shape
    return {"n_frames": n, "outside_range": outside, "valid": valid,
            "outside_share": outside / max(1, n * h * w), "valid_range_mm": [float(lo), float(hi)],
            "plausibility": gate}


# -------------------------------------------------------------------------------------------- noise
@dataclass
class NoisePart:
    """Noise statistics of one chunk (or of several merged): moments of the frames, of the block
    means per block length, and of the first ``n`` frames for each subset size the chunk reaches."""

    full: Moments
    blocks: dict = field(default_factory=dict)   # b -> Moments of the b-frame block means
    snaps: dict = field(default_factory=dict)    # n -> Moments of frames 0 .. n - 1


def noise_multiple(block_sizes=DEFAULT_BLOCKS) -> int:
    """Chunks are whole multiples of every block length (their least common multiple)."""
    return math.lcm(*[int(b) for b in block_sizes if int(b) >= 1]) if block_sizes else 1


def noise_chunk(capture: str, start: int, stop: int, subsets=DEFAULT_SUBSETS, block_sizes=DEFAULT_BLOCKS) -> NoisePart:
    """Noise statistics of frames ``start .. stop - 1`` (``start`` a multiple of every block length)."""
    cap = Capture(capture)
    wanted = sorted({int(n) for n in subsets if int(n) >= 2})
    blocks = sorted({int(b) for b in block_sizes if int(b) >= 1})
    if any(start % b for b in blocks):
        raise InputError(f"noise chunk start {start} is not a multiple of the block lengths {blocks}")
    shape = cap.shape
    part = NoisePart(Moments.empty(shape), {b: Moments.empty(shape) for b in blocks})
    acc = {b: [np.zeros(shape), np.zeros(shape, np.int32), 0] for b in blocks}
    for i in range(start, stop):
        f = cap.depth(i)
        part.full.update(f)
        if i + 1 in wanted and start == 0:
            part.snaps[i + 1] = Moments(part.full.count.copy(), part.full.mean.copy(), part.full.m2.copy(), i + 1)
        fv = f.astype(np.float64)
        for b in blocks:
            a = acc[b]
            a[0] += fv
            a[1] += fv > 0
            a[2] += 1
            if a[2] == b:   # block mean only where every frame of the block was valid (as assess_noise)
                part.blocks[b].update(np.where(a[1] == b, a[0] / b, 0.0))
                a[0][:] = 0
                a[1][:] = 0
                a[2] = 0
    return part


def merge_noise(a: NoisePart, b: NoisePart) -> NoisePart:
    """Two consecutive chunks' noise statistics taken together (exact)."""
    return NoisePart(merge_moments(a.full, b.full), {k: merge_moments(a.blocks[k], b.blocks[k]) for k in a.blocks},
                     {**a.snaps, **b.snaps})


def noise_result(part: NoisePart, subsets=DEFAULT_SUBSETS, row: int | None = None, min_gain: float = 0.15) -> NoiseResult:
    """The :class:`~tofmetry.assess.NoiseResult` of a whole recording from its merged statistics
    (the same figures as :func:`~tofmetry.assess.assess_noise` in one pass, up to rounding)."""
    n = part.full.n_frames
    if n < 2:
        raise InputError(f"noise analysis needs at least 2 frames of a static scene, found {n}")
    wanted = sorted({int(k) for k in subsets if int(k) >= 2})
    snaps = {k: m.std() for k, m in sorted(part.snaps.items())}
    block_stds = [(b, st.n_frames, st.std()[st.count == st.n_frames]) for b, st in sorted(part.blocks.items())
                  if st.n_frames >= 2]
    return noise_result_from(n, part.full.shape, part.full.to_temporal(), snaps, wanted, row, min_gain, block_stds)


# ------------------------------------------------------------------------------------------- warm-up
def warmup_patch(capture: str, patch: int = 10) -> dict:
    """The followed patch of a warm-up recording (from its first frame and mean IR, as
    :func:`~tofmetry.assess.assess_warmup`): ``{"patch": (u0, v0, size), "source": ..., "n_frames": T}``."""
    cap = Capture(capture)
    if cap.timestamps_s is None:
        raise InputError(f"{capture}: warm-up needs frame timestamps: capture.json has no 'timestamps_s' "
                         "(expected one time in seconds per depth frame)")
    ir = np.asarray(cap.ir_mean(20), np.float64) if cap.has_ir else None
    sel, src = select_patch(cap.depth(0), ir, patch)
    return {"patch": sel, "source": src, "n_frames": len(cap)}


def warmup_chunk(capture: str, start: int, stop: int, patch: tuple[int, int, int]) -> np.ndarray:
    """Mean depth of the patch in frames ``start .. stop - 1``: (stop - start,) float64 [mm], NaN
    where less than half of the patch is valid."""
    cap = Capture(capture)
    u0, v0, s = patch
    out = np.full(stop - start, np.nan)
    for k, i in enumerate(range(start, stop)):
        p = cap.depth(i)[v0:v0 + s, u0:u0 + s].astype(np.float64)
        good = p > 0
        if good.sum() >= max(1, p.size // 2):
            out[k] = p[good].mean()
    return out


def warmup_result(capture: str, plan: dict, series: list[np.ndarray], *, tolerance_mm: float = 1.0,
                  smooth_window_s: float | None = None, final_window_s: float = 600.0):
    """The :class:`~tofmetry.assess.WarmupResult` of a whole recording from its chunks' series (in order)."""
    cap = Capture(capture)
    ts = cap.timestamps_s
    dist = np.concatenate(series) if series else np.zeros(0)
    if ts is None or dist.size != ts.size:
        raise EstimationError(f"{capture}: {dist.size} patch means for {0 if ts is None else ts.size} timestamps")
    if ts.size < 3:
        raise InputError(f"warm-up needs at least 3 timestamped frames, found {ts.size}")
    if not np.all(np.isfinite(ts)) or np.any(np.diff(ts) <= 0):
        raise InputError(f"{capture}: timestamps_s must be finite and strictly increasing")
    notes = []
    if plan["source"] == "depth_min":
        notes.append("no IR amplitude available: followed the patch of smallest depth instead of highest IR")
    return warmup_from_series(ts, dist, plan["patch"], plan["source"], tolerance_mm=tolerance_mm,
                              smooth_window_s=smooth_window_s, final_window_s=final_window_s, notes=notes)
