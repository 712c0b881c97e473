"""The support of a depth calibration: which image regions and which depths it was fitted on.

A calibration is only trustworthy where it saw data. The support records, per image cell
(``cell_px`` x ``cell_px`` pixels) and per bin of measured depth Z (``bin_mm``), how many
calibration samples fell there. From it:

* a per-pixel depth interval ``[lo, hi]`` [mm]: the hull of the supported depth bins of the
  pixel's cell (interpolating between two wall stations counts as supported; going past the
  nearest or the farthest does not). Pixels of a cell without any sample get ``lo = hi = 0``:
  no depth there is supported.
* :meth:`CalibrationSupport.inside`: whether measured depths lie in the support, used by the
  correction kernels to switch to the conservative fallback and to count extrapolated pixels.

Pure arrays; stored in the calibration file by :mod:`tofmetry.io.calibration_file`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofmetry.errors import InputError


@dataclass(frozen=True, eq=False)
class CalibrationSupport:
    """Where a calibration was fitted (see the module docstring).

    Attributes
    ----------
    shape : (H, W) of the depth images [px]
    cell_px : int, side of an image cell [px]
    range_edges_mm : (Nr + 1,) float64, edges of the measured-depth bins [mm]
    counts : (Gv, Gu, Nr) float64, samples (pixels) per cell and bin
    min_count : float, a cell/bin with at least this many samples is supported
    lo_mm, hi_mm : (H, W) float32, per-pixel supported depth interval [mm] (0, 0: none)
    data_range_mm : (2,) float64, the depths [mm] spanned by all samples: where the correction is
        evaluated (beyond it a calibration's fallback holds it or replaces it)
    """

    shape: tuple
    cell_px: int
    range_edges_mm: np.ndarray
    counts: np.ndarray
    min_count: float
    lo_mm: np.ndarray
    hi_mm: np.ndarray
    data_range_mm: np.ndarray

    @classmethod
    def from_samples(cls, u: np.ndarray, v: np.ndarray, z_mm: np.ndarray, shape: tuple[int, int], *,
                     cell_px: int = 16, bin_mm: float = 100.0, max_mm: float = 8000.0,
                     min_count: float | None = None, margin_mm: float = 0.0) -> "CalibrationSupport":
        """Support of calibration samples at pixels ``(u, v)`` with measured depth ``z_mm``.

        Parameters
        ----------
        u, v : (N,) int or float pixel coordinates [px]
        z_mm : (N,) float measured depth Z [mm]
        shape : (H, W) of the images
        cell_px, bin_mm, max_mm : cell size [px], depth bin width [mm] and last bin edge [mm]
        min_count : samples needed in a cell/bin (default: 1/32 of a cell's pixels, 8 for 16 px cells:
            sparse data such as a board's white squares still count)
        margin_mm : widen each per-pixel interval by this much on both sides [mm]
        """
        h, w = (int(s) for s in shape)
        if cell_px < 1 or not bin_mm > 0 or not max_mm > bin_mm:
            raise InputError(f"support: need cell_px >= 1 and 0 < bin_mm < max_mm, found {cell_px}, {bin_mm}, {max_mm}")
        u = np.asarray(u, float).ravel()
        v = np.asarray(v, float).ravel()
        z = np.asarray(z_mm, float).ravel()
        if not (u.shape == v.shape == z.shape):
            raise InputError(f"support: u, v, z_mm must have the same length, found {u.shape}, {v.shape}, {z.shape}")
        ok = np.isfinite(z) & (z > 0) & (u >= -0.5) & (u < w - 0.5) & (v >= -0.5) & (v < h - 0.5)
        gu, gv = -(-w // cell_px), -(-h // cell_px)
        edges = np.arange(0.0, max_mm + bin_mm / 2, bin_mm)
        nr = len(edges) - 1
        iu = np.clip((np.rint(u[ok]) // cell_px).astype(int), 0, gu - 1)
        iv = np.clip((np.rint(v[ok]) // cell_px).astype(int), 0, gv - 1)
        ir = np.clip((z[ok] // bin_mm).astype(int), 0, nr - 1)
        counts = np.bincount((iv * gu + iu) * nr + ir, minlength=gv * gu * nr).reshape(gv, gu, nr).astype(float)
        mc = float(max(1.0, cell_px * cell_px / 32) if min_count is None else min_count)
        lo_c, hi_c = _cell_intervals(counts, edges, mc, z, ok, iu, iv, gu)
        lo = np.where(lo_c > 0, np.maximum(lo_c - margin_mm, 1.0), 0.0)
        hi = np.where(hi_c > 0, hi_c + margin_mm, 0.0)
        lo_px = np.repeat(np.repeat(lo, cell_px, 0), cell_px, 1)[:h, :w].astype(np.float32)
        hi_px = np.repeat(np.repeat(hi, cell_px, 0), cell_px, 1)[:h, :w].astype(np.float32)
        zz = z[ok]
        span = np.array([zz.min(), zz.max()]) if zz.size else np.array([np.nan, np.nan])
        return cls((h, w), int(cell_px), edges, counts, mc, lo_px, hi_px, span)

    @classmethod
    def everywhere(cls, shape: tuple[int, int], lo_mm: float, hi_mm: float) -> "CalibrationSupport":
        """Support of the whole image over ``[lo_mm, hi_mm]`` (e.g. a constant shift)."""
        h, w = (int(s) for s in shape)
        edges = np.array([0.0, 65536.0])
        return cls((h, w), max(h, w), edges, np.ones((1, 1, 1)), 1.0, np.full((h, w), lo_mm, np.float32),
                   np.full((h, w), hi_mm, np.float32), np.array([lo_mm, hi_mm], float))

    def inside(self, depth_mm: np.ndarray) -> np.ndarray:
        """(H, W) bool: valid depth (> 0) within its pixel's supported interval."""
        d = np.asarray(depth_mm)
        if d.shape != tuple(self.shape):
            raise InputError(f"support: depth shape {d.shape} differs from the calibration's {tuple(self.shape)}")
        with np.errstate(invalid="ignore"):
            return (d > 0) & (d >= self.lo_mm) & (d <= self.hi_mm)

    def count_outside(self, depth_mm: np.ndarray) -> int:
        """Number of valid pixels (depth > 0) outside the support."""
        d = np.asarray(depth_mm)
        with np.errstate(invalid="ignore"):
            return int(np.count_nonzero((d > 0) & ~self.inside(d)))

    @property
    def covered_fraction(self) -> float:
        """Fraction of the image's pixels with any supported depth."""
        return float(np.mean(self.hi_mm > 0))

    @property
    def range_mm(self) -> tuple[float, float]:
        """Depths [mm] spanned by the samples (the correction's overall range)."""
        return float(self.data_range_mm[0]), float(self.data_range_mm[1])

    def summary(self) -> dict:
        """JSON-able description (for reports and ``tofmetry info``)."""
        lo, hi = self.range_mm
        sup = self.counts >= self.min_count
        return {"cell_px": self.cell_px, "bin_mm": float(self.range_edges_mm[1] - self.range_edges_mm[0]),
                "covered_fraction": self.covered_fraction, "range_mm": [lo, hi],
                "supported_cells_bins": int(sup.sum()), "min_count": self.min_count}

    def to_arrays(self) -> dict:
        """Arrays for the calibration file (see :meth:`from_arrays`)."""
        return {"support_counts": self.counts.astype(np.float32), "support_edges_mm": self.range_edges_mm,
                "support_lo_mm": self.lo_mm, "support_hi_mm": self.hi_mm,
                "support_meta": np.array([self.cell_px, self.min_count, *self.data_range_mm], np.float64)}

    @classmethod
    def from_arrays(cls, a: dict, shape: tuple[int, int]) -> "CalibrationSupport":
        meta = np.asarray(a["support_meta"], float)
        lo, hi = np.asarray(a["support_lo_mm"], np.float32), np.asarray(a["support_hi_mm"], np.float32)
        if lo.shape != tuple(shape) or hi.shape != tuple(shape):
            raise InputError(f"support: interval maps {lo.shape}/{hi.shape} do not match the shape {tuple(shape)}")
        cov = hi > 0
        span = meta[2:4] if len(meta) >= 4 else (np.array([lo[cov].min(), hi[cov].max()]) if cov.any() else
                                                    np.array([np.nan, np.nan]))
        return cls(tuple(shape), int(meta[0]), np.asarray(a["support_edges_mm"], float),
                   np.asarray(a["support_counts"], float), float(meta[1]), lo, hi, np.asarray(span, float))


def _cell_intervals(counts, edges, min_count, z, ok, iu, iv, gu):
    """Per-cell hull [lo, hi] [mm] of the supported bins, tightened to the samples' own extent."""
    gv_, gu_, nr = counts.shape
    sup = counts >= min_count
    lo = np.zeros((gv_, gu_))
    hi = np.zeros((gv_, gu_))
    anyb = sup.any(axis=2)
    first = np.argmax(sup, axis=2)
    last = nr - 1 - np.argmax(sup[:, :, ::-1], axis=2)
    # tighten to the samples' actual min / max depth inside the first / last supported bin
    zz = z[ok]
    cell = iv * gu + iu
    zmin = np.full(gv_ * gu_, np.inf)
    zmax = np.full(gv_ * gu_, -np.inf)
    np.minimum.at(zmin, cell, zz)
    np.maximum.at(zmax, cell, zz)
    zmin, zmax = zmin.reshape(gv_, gu_), zmax.reshape(gv_, gu_)
    lo[anyb] = np.maximum(edges[first[anyb]], zmin[anyb])
    hi[anyb] = np.minimum(edges[last[anyb] + 1], zmax[anyb])
    return lo, hi
