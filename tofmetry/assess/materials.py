"""Materials and intensity: amplitude-related depth bias (study §3.3.1, Figure 4).

A board of samples (or a grey-level checkerboard) is seen frontally. The temporal mean
depth is compared with a plane fitted on the reference (white) regions; each region gets
its mean IR amplitude, its depth bias relative to that plane, and its spatial/temporal
std. The relation ``bias = slope * ln(A_ref / A) + intercept`` is fitted (study: black,
1/6 of the white amplitude, reads about +12 mm, i.e. slope ~ 6.7 mm per ln unit).
``A_ref`` is the reference amplitude *at the region's position*: the IR amplitude falls off
toward the image borders, modelled as ``cos(theta)^e`` of the off-axis angle.
Samples whose bias is erratic (reflective: high spatial spread, or far off the fit) are
flagged and left out of the fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from tofmetry._shared.study_constants import BLACK_AMPLITUDE_RATIO
from tofmetry.assess._source import capture_ir, check_frame, frame_iter
from tofmetry.assess.regions import Region, auto_grey_board_regions
from tofmetry.errors import EstimationError, InputError
from tofmetry.pointcloud import RunningDepthStats
from tofmetry.sensor.intrinsics import CameraIntrinsics


@dataclass
class RegionStats:
    """Statistics of one sample region (depth values [mm], amplitude in sensor units)."""

    name: str
    rect: tuple[int, int, int, int]
    reference: bool
    n_pixels: int
    amplitude: float
    ln_amp_ratio: float         # ln(A_ref at this position / A)
    bias_mm: float              # median of (mean depth - reference plane)
    spatial_std_mm: float       # std of (mean depth - plane) inside the region
    temporal_std_mm: float      # median per-pixel temporal std
    fit_residual_mm: float = float("nan")
    erratic: bool = False
    reason: str = ""
    level: int | None = None

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        d["rect"] = list(self.rect)
        return d


@dataclass
class MaterialsResult:
    """Result of :func:`assess_materials`.

    Attributes
    ----------
    regions : list of RegionStats
    slope_mm_per_ln, slope_se_mm_per_ln, intercept_mm : fit of bias against ln(A_ref / A)
    deviation_mm : (H, W) float64, mean depth - reference plane [mm] (NaN where invalid)
    amplitude : (H, W) float64, mean IR amplitude
    plane_inv_z : (a, b, c) of 1/Z = a x + b y + c [1/mm] with (x, y) normalised ray coordinates
    falloff_exponent : e of the amplitude falloff cos(theta)^e used for A_ref
    """

    regions: list
    slope_mm_per_ln: float
    slope_se_mm_per_ln: float
    intercept_mm: float
    fit_rms_mm: float
    n_fit: int
    deviation_mm: np.ndarray
    amplitude: np.ndarray
    plane_inv_z: tuple
    falloff_exponent: float
    n_frames: int
    auto_info: dict | None = None
    notes: list = field(default_factory=list)

    def predicted_bias_mm(self, amp_ratio: float) -> float:
        """Bias [mm] predicted for an amplitude ``amp_ratio`` times lower than the reference."""
        return self.slope_mm_per_ln * math.log(amp_ratio) + self.intercept_mm

    def to_dict(self) -> dict:
        return {
            "analysis": "materials", "n_frames": self.n_frames,
            "fit": {"model": "bias_mm = slope * ln(A_ref / A) + intercept", "slope_mm_per_ln": self.slope_mm_per_ln,
                    "slope_se_mm_per_ln": self.slope_se_mm_per_ln, "intercept_mm": self.intercept_mm,
                    "rms_mm": self.fit_rms_mm, "n_regions": self.n_fit,
                    "bias_at_amplitude_ratio_6_mm": self.predicted_bias_mm(BLACK_AMPLITUDE_RATIO)},
            "falloff_exponent": self.falloff_exponent, "plane_inv_z": list(self.plane_inv_z),
            "regions": [r.to_dict() for r in self.regions], "erratic": [r.name for r in self.regions if r.erratic],
            "auto_regions": self.auto_info, "notes": list(self.notes),
        }


def fit_reference_plane(mean_depth: np.ndarray, rays: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fit the plane through the masked pixels; return (coefficients, plane depth image).

    A plane ``n . X = d`` seen through rays ``X = Z (x, y, 1)`` satisfies
    ``1/Z = a x + b y + c`` exactly, so the fit is linear in 1/Z.

    Parameters
    ----------
    mean_depth : (H, W) float [mm], 0/NaN invalid
    rays : (H, W, 2) normalised (x, y)
    mask : (H, W) bool pixels on the plane

    Returns
    -------
    coef : (3,) [1/mm];  plane_z : (H, W) float64 [mm]
    """
    z = np.asarray(mean_depth, np.float64)
    m = mask & np.isfinite(z) & (z > 0)
    if m.sum() < 3:
        raise EstimationError("reference plane: fewer than 3 valid pixels in the reference regions")
    x, y = rays[..., 0], rays[..., 1]
    A = np.column_stack([x[m], y[m], np.ones(m.sum())])
    coef, *_ = np.linalg.lstsq(A, 1.0 / z[m], rcond=None)
    inv = coef[0] * x + coef[1] * y + coef[2]
    with np.errstate(divide="ignore"):
        plane = np.where(inv > 0, 1.0 / inv, np.nan)
    return coef, plane


def _line_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float, np.ndarray]:
    """Least-squares y = s x + b: (s, se(s), b, rms, residuals)."""
    A = np.column_stack([x, np.ones_like(x)])
    (s, b), *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - (s * x + b)
    dof = max(len(x) - 2, 1)
    sig2 = (res ** 2).sum() / dof
    sxx = ((x - x.mean()) ** 2).sum()
    se = math.sqrt(sig2 / sxx) if sxx > 0 else float("inf")
    return float(s), se, float(b), float(math.sqrt((res ** 2).mean())), res


def assess_materials(source, regions: list[Region] | None = None, *, intr: CameraIntrinsics | None = None,
                     ir: np.ndarray | None = None, auto_grey_board: bool = False, erratic_factor: float = 3.0,
                     erratic_floor_mm: float = 2.0, progress: Callable[[], None] | None = None) -> MaterialsResult:
    """Amplitude-related depth bias of sample regions.

    Parameters
    ----------
    source : Capture or (T, H, W) depth frames [mm] (streamed)
    regions : list of Region, or None with ``auto_grey_board=True``
    intr : CameraIntrinsics (capture's if omitted)
    ir : (H, W) IR amplitude (the capture's mean IR if omitted); required
    auto_grey_board : find the squares of a grey-level checkerboard from the IR image
    erratic_factor, erratic_floor_mm : a region is erratic when its spatial std exceeds
        ``max(erratic_factor * median spatial std, erratic_floor_mm)``, or its fit residual
        exceeds ``max(erratic_factor * robust residual scale, erratic_floor_mm)``.

    Returns
    -------
    MaterialsResult
    """
    if regions is None and not auto_grey_board:
        raise InputError("materials: give sample regions (--regions regions.json) or ask for --auto-grey-board")
    notes: list[str] = []
    if intr is None:
        if hasattr(source, "intrinsics"):
            intr, src = source.intrinsics()
            if "not calibrated" in src:
                notes.append(f"intrinsics: {src}")
        else:
            raise InputError("materials: pass the camera intrinsics (intr=...) with array input")
    a = capture_ir(source, ir, max_frames=1000)
    if a is None:
        raise InputError("materials: needs the IR amplitude (capture has no ir/ frames)")
    rs = None
    for i, frame in enumerate(frame_iter(source, progress)):
        f = check_frame(frame, intr.shape, i, "materials")
        if rs is None:
            rs = RunningDepthStats(f.shape)
        rs.update(f)
    if rs is None:
        raise InputError("materials: no frames")
    st = rs.result()
    if a.shape != st.mean.shape:
        raise InputError(f"materials: IR shape {a.shape} differs from the depth shape {st.mean.shape}")
    mean = st.mean_depth_mm()
    rays = intr.ray_table(True)
    auto_info = None
    expo = None
    if regions is None:
        regions, auto_info = auto_grey_board_regions(a, mean, rays)
        expo = auto_info["falloff_exponent"]
    h, w = mean.shape
    for r in regions:
        u0, v0, u1, v1 = r.rect
        if not (0 <= u0 < u1 <= w and 0 <= v0 < v1 <= h):
            raise InputError(f"region {r.name!r} rect {list(r.rect)} is outside the {w}x{h} image")
    ref_mask = np.zeros((h, w), bool)
    for r in regions:
        if r.reference:
            ref_mask[r.slices] = True
    if not ref_mask.any():
        raise InputError("materials: no reference region")
    coef, plane = fit_reference_plane(mean, rays, ref_mask)
    dev = np.where(mean > 0, mean - plane, np.nan)
    lncos_img = -0.5 * np.log1p((rays ** 2).sum(axis=2))
    stats = []
    for r in regions:
        sl = r.slices
        d = dev[sl]
        ok = np.isfinite(d)
        if ok.sum() < 3:
            raise EstimationError(f"region {r.name!r}: fewer than 3 valid pixels")
        tstd = st.std[sl][ok]
        stats.append(RegionStats(
            name=r.name, rect=r.rect, reference=r.reference, n_pixels=int(ok.sum()),
            amplitude=float(a[sl][ok].mean()), ln_amp_ratio=float("nan"), bias_mm=float(np.median(d[ok])),
            spatial_std_mm=float(d[ok].std()), temporal_std_mm=float(np.nanmedian(tstd)) if np.isfinite(tstd).any() else float("nan"),
            level=r.level))
    # reference amplitude field ln A_ref = c + e ln cos(theta)
    lncos = np.array([float(lncos_img[r.slices].mean()) for r in regions])
    lnA = np.log(np.maximum([s.amplitude for s in stats], 1e-9))
    ref = np.array([r.reference for r in regions])
    if expo is None:
        expo = 0.0
        if ref.sum() >= 3 and np.ptp(lncos[ref]) > 0.01:
            e, _, _, _, _ = _line_fit(lncos[ref], lnA[ref])
            expo = float(np.clip(e, 0.0, 12.0))
    c = float(np.mean(lnA[ref] - expo * lncos[ref]))
    ratio = c + expo * lncos - lnA
    for s, x in zip(stats, ratio):
        s.ln_amp_ratio = float(x)
    # erratic samples: spatial spread, then fit residual
    sp = np.array([s.spatial_std_mm for s in stats])
    lim_sp = max(erratic_factor * float(np.median(sp)), erratic_floor_mm)
    use = np.ones(len(stats), bool)
    for k, s in enumerate(stats):
        if s.spatial_std_mm > lim_sp:
            s.erratic, s.reason = True, f"spatial std {s.spatial_std_mm:.1f} mm > {lim_sp:.1f} mm"
            use[k] = False
    bias = np.array([s.bias_mm for s in stats])
    slope = se = icpt = rms = float("nan")
    if use.sum() >= 3 and np.ptp(ratio[use]) > 0.05:
        for _ in range(3):
            slope, se, icpt, rms, _ = _line_fit(ratio[use], bias[use])
            res = bias - (slope * ratio + icpt)
            scale = 1.4826 * float(np.median(np.abs(res[use])))
            lim = max(erratic_factor * scale, erratic_floor_mm)
            bad = use & (np.abs(res) > lim) & ~ref
            if not bad.any() or use.sum() - bad.sum() < 3:
                break
            for k in np.flatnonzero(bad):
                stats[k].erratic, stats[k].reason = True, f"bias {res[k]:+.1f} mm off the amplitude fit (> {lim:.1f} mm)"
            use &= ~bad
        slope, se, icpt, rms, _ = _line_fit(ratio[use], bias[use])
        for s, rr in zip(stats, bias - (slope * ratio + icpt)):
            s.fit_residual_mm = float(rr)
    else:
        notes.append("amplitude-bias fit skipped: need >= 3 usable regions spanning different amplitudes")
    return MaterialsResult(
        regions=stats, slope_mm_per_ln=slope, slope_se_mm_per_ln=se, intercept_mm=icpt, fit_rms_mm=rms,
        n_fit=int(use.sum()), deviation_mm=dev, amplitude=a, plane_inv_z=tuple(float(v) for v in coef),
        falloff_exponent=float(expo), n_frames=st.n_frames, auto_info=auto_info, notes=notes,
    )
