"""Surfaces of simulated scenes and their ray intersection.

:class:`PlaneSurface` is intersected analytically (float64); all :class:`MeshSurface` of a
:class:`Scene` are cast together in one Open3D ``RaycastingScene``. Rays are ``o + t d``
with ``d`` not normalised, so ``t`` is in units of ``|d|`` (the renderer uses camera
directions ``(x, y, 1)``: ``t`` is then the depth Z).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np


@dataclass
class Hits:
    """Nearest hits of N rays ``o + t d`` (d not normalised: t is in units of |d|).

    Attributes: t (N,) float64 (inf = miss); cos_inc (N,) |cos| of the incidence angle;
    albedo (N,); label (N,) int32; refl_bias_mm (N,) static bias of reflective samples [mm];
    reflective (N,) bool.
    """

    t: np.ndarray
    cos_inc: np.ndarray
    albedo: np.ndarray
    label: np.ndarray
    refl_bias_mm: np.ndarray
    reflective: np.ndarray

    @classmethod
    def empty(cls, n: int) -> "Hits":
        return cls(np.full(n, np.inf), np.zeros(n), np.zeros(n), np.zeros(n, np.int32), np.zeros(n), np.zeros(n, bool))

    def merge(self, other: "Hits") -> None:
        """Keep, per ray, the nearer of ``self`` and ``other`` (in place)."""
        m = other.t < self.t
        for f in ("t", "cos_inc", "albedo", "label", "refl_bias_mm", "reflective"):
            getattr(self, f)[m] = getattr(other, f)[m]


#: texture(s, t) -> (albedo (N,), label (N,) int, reflective (N,) bool, refl_bias (N,) mm-fraction 0..1)
Texture = Callable[[np.ndarray, np.ndarray], tuple]


def _uniform_texture(albedo: float, label: int) -> Texture:
    def tex(s, t):
        n = s.shape[0]
        return np.full(n, albedo), np.full(n, label, np.int32), np.zeros(n, bool), np.zeros(n)
    return tex


@dataclass
class PlaneSurface:
    """Planar patch ``p = origin + s e1 + t e2`` with ``s, t`` inside ``extent`` (None = infinite).

    Attributes
    ----------
    origin : (3,) [m]; e1, e2 : (3,) orthonormal in-plane axes;
    extent : (s0, s1, t0, t1) [m] or None; texture : see :data:`Texture`.
    reflective_max_mm : float, scale of the ``refl_bias`` fraction returned by the texture.
    """

    origin: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    extent: tuple | None
    texture: Texture
    reflective_max_mm: float = 60.0

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.e1, self.e2)
        return n / np.linalg.norm(n)

    def intersect(self, o: np.ndarray, d: np.ndarray) -> Hits:
        n = self.normal
        dn = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.origin - o) @ n) / dn
        ok = np.isfinite(t) & (t > 1e-9)
        h = Hits.empty(d.shape[0])
        idx = np.flatnonzero(ok)
        p = o + d[idx] * t[idx, None] - self.origin
        s, tt = p @ self.e1, p @ self.e2
        if self.extent is not None:
            s0, s1, t0, t1 = self.extent
            inside = (s >= s0) & (s <= s1) & (tt >= t0) & (tt <= t1)
            idx, s, tt = idx[inside], s[inside], tt[inside]
        alb, lab, refl, rb = self.texture(s, tt)
        dd = d[idx]
        h.t[idx] = t[idx]
        h.cos_inc[idx] = np.abs(dn[idx]) / np.sqrt(np.einsum("ij,ij->i", dd, dd))
        h.albedo[idx] = alb
        h.label[idx] = lab
        h.reflective[idx] = refl
        h.refl_bias_mm[idx] = rb * self.reflective_max_mm
        return h


@dataclass
class MeshSurface:
    """Triangle mesh (world frame, metres) with one albedo and label, raycast by Open3D.

    All meshes of a :class:`Scene` are cast together in one ``RaycastingScene``.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    albedo: float = 0.7
    label: int = 1


class _MeshGroup:
    """One Open3D ``RaycastingScene`` holding several :class:`MeshSurface`."""

    def __init__(self, meshes: list):
        import open3d as o3d

        self.meshes = meshes
        self.scene = o3d.t.geometry.RaycastingScene()
        ids = []
        for m in meshes:
            tm = o3d.t.geometry.TriangleMesh()
            tm.vertex.positions = o3d.core.Tensor(np.ascontiguousarray(m.vertices, np.float32))
            tm.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(m.triangles, np.int32))
            ids.append(self.scene.add_triangles(tm))
        n = max(ids) + 1
        self.albedo = np.zeros(n + 1)
        self.label = np.zeros(n + 1, np.int32)
        for gid, m in zip(ids, meshes):
            self.albedo[gid], self.label[gid] = m.albedo, m.label

    def intersect(self, o: np.ndarray, d: np.ndarray) -> Hits:
        import open3d as o3d

        rays = np.empty((d.shape[0], 6), np.float32)
        rays[:, :3] = o
        rays[:, 3:] = d
        ans = self.scene.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy()
        h = Hits.empty(d.shape[0])
        idx = np.flatnonzero(np.isfinite(t))
        gid = ans["geometry_ids"].numpy()[idx].astype(np.int64)
        nrm = ans["primitive_normals"].numpy()[idx].astype(np.float64)
        dd = d[idx]
        h.t[idx] = t[idx]
        h.cos_inc[idx] = np.abs(np.einsum("ij,ij->i", dd, nrm)) / np.sqrt(np.einsum("ij,ij->i", dd, dd))
        h.albedo[idx] = self.albedo[gid]
        h.label[idx] = self.label[gid]
        return h


@dataclass
class Scene:
    """A set of surfaces plus ground-truth description.

    Attributes
    ----------
    name : str
    surfaces : list of PlaneSurface / MeshSurface
    labels : dict int -> str, region / sample names of the label ids
    info : dict, JSON-able truth (geometry parameters, albedos, reflective flags)
    smooth : bool, True when the scene has no depth or albedo edges (a bare uniform plane):
        the renderer then needs no supersampling.
    """

    name: str
    surfaces: list
    labels: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    smooth: bool = False
    _group: object = field(default=None, repr=False, compare=False)

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> Hits:
        """Nearest hits of rays ``origin + t dirs``: origin (3,) [m], dirs (N, 3)."""
        o = np.asarray(origin, np.float64).reshape(3)
        d = np.asarray(dirs, np.float64).reshape(-1, 3)
        h = None
        for s in self.surfaces:
            if isinstance(s, PlaneSurface):
                hs = s.intersect(o, d)
                h = hs if h is None else (h.merge(hs) or h)
        meshes = [s for s in self.surfaces if isinstance(s, MeshSurface)]
        if meshes:
            if self._group is None:
                self._group = _MeshGroup(meshes)
            hs = self._group.intersect(o, d)
            h = hs if h is None else (h.merge(hs) or h)
        return h if h is not None else Hits.empty(d.shape[0])
