"""A family of objects to scan, drawn by seed: real scanned meshes and procedural shapes.

A reconstruction method built beside one object can fit that object. :func:`random_object`
draws an object the method was not built beside:

* **real meshes** (``../shared/data/scan-meshes``, read in place, never copied; pass their
  folder as ``mesh_dir``): the Stanford bunny, the Igea marble head, a mechanical rocker arm and
  the fandisk CAD part, each stood on its natural base (:data:`REAL_MESHES`);
* **procedural shapes** (:data:`PROCEDURAL`), one per character the registration must survive:
  ``vase`` (a surface of revolution with a small handle: nearly rotation-symmetric), ``box``
  (a chamfered box with one corner cut: nearly 180-degree symmetric), ``pebble`` (smooth and
  lumpy), ``baluster`` (elongated, nearly mirror-symmetric, the study's object class), ``bar``
  (elongated, a bent bar of rounded section), ``plaque`` (thin: an upright slab with an
  irregular outline, 20-40 mm thick) and ``dome`` (nearly featureless: a smooth triaxial dome
  with two faint bumps).

Every object is rotated so that its up axis is world z, scaled so that its largest bounding-box
side is the drawn size [m], turned by a random yaw about z, and placed on the ground (lowest
point at z = 0, bounding-box centre on the z axis), as
:func:`tofmetry.simulate.scenes.mesh_on_ground` expects. Distributions: 0.5 real, 0.5
procedural (uniform within each group); size U(0.15, 0.45) m for the real meshes and the range
given per shape for the procedural ones; yaw U(0, 360) deg.

Paint (the IR albedo a ToF camera sees as amplitude texture): a plain object has albedo 0.7
everywhere; a painted one (:func:`paint`) dark blobs and bands (0.25) on a light ground (0.75),
with probability 0.75 for the shapes whose geometry leaves a rotation free (vase, dome, box: a
decorated vase, a labelled box) and 0.5 for the others. The plaque is never painted.
:func:`textured_scene` builds the scene the virtual camera renders.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry._shared.geometry import skew
from tofmetry.errors import InputError

#: Real meshes: file in the scan-meshes folder, the mesh's up axis (it stands on the opposite side)
#: and its character.
REAL_MESHES = {
    "bunny": ("stanford-bunny.obj", (0.0, 1.0, 0.0), "real scan, organic, holes at the base"),
    "igea": ("igea.ply", (0.0, 1.0, 0.0), "real scan, a head with fine detail"),
    "rocker-arm": ("rocker-arm.obj", (1.0, 0.0, 0.0), "mechanical part lying on its flat side"),
    "fandisk": ("fandisk.obj", (0.0, 0.0, 1.0), "CAD part, flat faces and sharp edges, nearly symmetric in places"),
}
#: Procedural shapes: character and size range of the largest side [m].
PROCEDURAL = {
    "vase": ("symmetric: surface of revolution with a small handle", (0.18, 0.35)),
    "box": ("symmetric: chamfered box, one corner cut", (0.20, 0.40)),
    "pebble": ("smooth, lumpy", (0.15, 0.35)),
    "baluster": ("elongated, nearly mirror-symmetric", (0.30, 0.50)),
    "bar": ("elongated: bent bar of rounded section", (0.30, 0.50)),
    "plaque": ("thin: upright slab with an irregular outline", (0.20, 0.35)),
    "dome": ("nearly featureless: smooth triaxial dome, two faint bumps", (0.18, 0.35)),
}
REAL_SIZE_M = (0.15, 0.45)


@dataclass
class ObjectDraw:
    """One object of the family, placed in the z-up world on the ground plane z = 0.

    Attributes
    ----------
    name : str, a key of :data:`REAL_MESHES` or :data:`PROCEDURAL`
    kind : ``"real"`` or ``"procedural"``
    character : str, what makes it hard (symmetric, thin, ...)
    vertices : (V, 3) float64 [m], world frame (lowest point z = 0, bounding box centred on the z axis)
    triangles : (F, 3) int64, outward oriented
    albedo : (F,) IR albedo per triangle (a painted pattern), or None for a uniform object (0.7)
    size_m : float, largest bounding-box side [m]
    yaw_deg : float, rotation about z applied after standing it up [deg]
    seed : int or None
    """

    name: str
    kind: str
    character: str
    vertices: np.ndarray
    triangles: np.ndarray
    size_m: float
    yaw_deg: float
    seed: int | None = None
    extra: dict = field(default_factory=dict)
    albedo: np.ndarray | None = None

    @property
    def extent_m(self) -> np.ndarray:
        """(3,) bounding-box sides [m] (x, y, z)."""
        return self.vertices.max(0) - self.vertices.min(0)

    @property
    def centre_m(self) -> np.ndarray:
        """(3,) bounding-box centre [m] (on the z axis, half the height up)."""
        return np.array([0.0, 0.0, float(self.vertices[:, 2].max()) / 2.0])

    def to_dict(self) -> dict:
        """JSON-able description (no arrays)."""
        return {"name": self.name, "kind": self.kind, "character": self.character, "size_m": round(self.size_m, 4),
                "yaw_deg": round(self.yaw_deg, 2), "seed": self.seed, "painted": self.albedo is not None,
                "extent_m": [round(float(x), 4) for x in self.extent_m], "n_triangles": int(len(self.triangles)),
                **self.extra}


# ----------------------------------------------------------------------------------- meshes
def _orient_outward(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    return f[:, ::-1].copy() if vol < 0 else f


def grid_mesh(P: np.ndarray, close_ends: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Mesh of a closed-around grid of points, each end capped by a fan.

    Parameters
    ----------
    P : (n_rings, n_around, 3) float [m], rings of points around the object, in order
    close_ends : cap the first and the last ring with a fan around its mean

    Returns
    -------
    vertices : (n_rings * n_around [+ 2], 3) float [m]
    triangles : (M, 3) int64, oriented outward
    """
    n, m, _ = P.shape
    v = P.reshape(-1, 3)
    f = []
    for i in range(n - 1):
        a = i * m + np.arange(m)
        b = i * m + (np.arange(m) + 1) % m
        f += [np.stack([a, b, b + m], 1), np.stack([a, b + m, a + m], 1)]
    if close_ends:
        c0, c1 = len(v), len(v) + 1
        v = np.vstack([v, P[0].mean(0), P[-1].mean(0)])
        r0, r1 = np.arange(m), (n - 1) * m + np.arange(m)
        f += [np.stack([np.full(m, c0), np.roll(r0, -1), r0], 1), np.stack([np.full(m, c1), r1, np.roll(r1, -1)], 1)]
    f = np.vstack(f).astype(np.int64)
    return v, _orient_outward(v, f)


def _revolve(z: np.ndarray, r: np.ndarray, n_around: int = 96) -> tuple[np.ndarray, np.ndarray]:
    a = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    P = np.stack([r[:, None] * np.cos(a), r[:, None] * np.sin(a), np.repeat(z[:, None], n_around, 1)], -1)
    return grid_mesh(P)


def vase(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Surface of revolution (height 1) with a handle-like bump on one side."""
    z = np.linspace(0.0, 1.0, 81)
    r0, bulge, neck = rng.uniform(0.18, 0.26), rng.uniform(0.06, 0.14), rng.uniform(0.55, 0.8)
    r = r0 + bulge * np.sin(np.pi * z / neck * 0.9) * (z < neck) - 0.05 * np.clip(z - neck, 0, None) / (1 - neck)
    r = np.maximum(r, 0.08)
    a = np.linspace(0, 2 * np.pi, 128, endpoint=False)
    R = r[:, None] * np.ones_like(a)[None]
    # the handle: a smooth bump at one azimuth, mid height
    za, aa, h = rng.uniform(0.35, 0.65), rng.uniform(0, 2 * np.pi), rng.uniform(0.05, 0.09)
    d_ang = np.angle(np.exp(1j * (a - aa)))
    R += h * np.exp(-(d_ang[None] / 0.22) ** 2 - ((z[:, None] - za) / 0.12) ** 2)
    P = np.stack([R * np.cos(a), R * np.sin(a), np.repeat(z[:, None], len(a), 1)], -1)
    return grid_mesh(P)


def _hull(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from scipy.spatial import ConvexHull

    h = ConvexHull(pts)
    f = h.simplices.astype(np.int64).copy()
    c = pts.mean(0)
    a, b, cc = pts[f[:, 0]], pts[f[:, 1]], pts[f[:, 2]]
    flip = np.einsum("ij,ij->i", np.cross(b - a, cc - a), a - c) < 0
    f[flip] = f[flip][:, ::-1]
    used = np.unique(f)
    remap = -np.ones(len(pts), np.int64)
    remap[used] = np.arange(len(used))
    return pts[used], remap[f]


def _subdivide_long_edges(v: np.ndarray, f: np.ndarray, max_edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Split triangles until no edge is longer than ``max_edge`` (midpoint subdivision, flat)."""
    for _ in range(8):
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        longest = np.max(np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                                   np.linalg.norm(a - c, axis=1)]), 0)
        if longest.max() <= max_edge:
            break
        mids: dict = {}
        verts = list(v)

        def mid(i, j):
            key = (min(i, j), max(i, j))
            if key not in mids:
                mids[key] = len(verts)
                verts.append((v[i] + v[j]) / 2)
            return mids[key]

        nf = []
        for (i, j, k) in f:
            ij, jk, ki = mid(i, j), mid(j, k), mid(k, i)
            nf += [(i, ij, ki), (ij, j, jk), (ki, jk, k), (ij, jk, ki)]
        v, f = np.array(verts), np.array(nf, np.int64)
    return v, f


def box(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Chamfered box (largest side 1) with one corner cut off (breaks the 180-degree symmetry)."""
    sx, sy, sz = 1.0, rng.uniform(0.5, 0.8), rng.uniform(0.4, 0.7)
    c = rng.uniform(0.03, 0.07)
    pts = []
    for X in (-1, 1):
        for Y in (-1, 1):
            for Z in (-1, 1):
                corner = np.array([X * sx / 2, Y * sy / 2, Z * sz / 2])
                cut = 3.5 * c if (X, Y, Z) == (1, 1, 1) else c
                for ax in range(3):
                    p = corner.copy()
                    p[ax] -= np.sign(p[ax]) * cut
                    pts.append(p)
    v, f = _hull(np.array(pts))
    return _subdivide_long_edges(v, f, 0.08)


def _sphere(n: int = 48) -> tuple[np.ndarray, np.ndarray]:
    th = np.linspace(0.0, np.pi, n + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    P = np.stack([np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph),
                  np.repeat(np.cos(th)[:, None], len(ph), 1)], -1)[::-1]
    return grid_mesh(P)


def pebble(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Smooth lumpy body: a sphere with 9 random Gaussian lumps, flattened base."""
    v, f = _sphere(48)
    dirs = rng.normal(size=(9, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    amp, wid = rng.uniform(-0.25, 0.3, 9), rng.uniform(0.3, 0.7, 9)
    r = 1 + sum(a * np.exp(-(1 - v @ d) / w ** 2) for a, d, w in zip(amp, dirs, wid))
    v = v * r[:, None] * np.array([1.0, rng.uniform(0.65, 0.9), rng.uniform(0.7, 0.95)])
    v[:, 2] = np.maximum(v[:, 2], v[:, 2].min() + 0.25)  # a flat base to stand on
    return v, f


def dome(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Smooth triaxial dome with two faint bumps (a few per cent of its size)."""
    v, f = _sphere(48)
    v = v * np.array([1.0, rng.uniform(0.7, 0.85), rng.uniform(0.55, 0.8)])
    for _ in range(2):
        d = rng.normal(size=3)
        d[2] = abs(d[2]) + 0.3
        d /= np.linalg.norm(d)
        u = v / np.linalg.norm(v, axis=1, keepdims=True)
        v = v * (1 + rng.uniform(0.03, 0.06) * np.exp(-(1 - u @ d) / 0.05))[:, None]
    v[:, 2] = np.maximum(v[:, 2], 0.0)  # cut at the equator: it lies on its flat base
    return v, f


def baluster(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The study's object class: a lying turned baluster, nearly mirror-symmetric."""
    from tofmetry.simulate.meshes import balustrade_mesh

    return balustrade_mesh(length_m=1.0, n_along=121, n_around=72, asymmetry=rng.uniform(0.02, 0.08))


def bar(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A bent bar of rounded-square section, lying on the ground (length 1)."""
    s = np.linspace(-0.5, 0.5, 90)
    bend, rad = rng.uniform(0.08, 0.25), rng.uniform(0.06, 0.1)
    centre = np.stack([s, bend * (1 - (2 * s) ** 2) + 0.1 * rng.uniform(-1, 1) * s, np.zeros_like(s)], 1)
    tang = np.gradient(centre, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0])
    side = np.cross(up, tang)
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    e = 4.0  # superellipse: rounded square
    ca, sa = np.cos(a), np.sin(a)
    cy, cz = np.sign(ca) * np.abs(ca) ** (2 / e), np.sign(sa) * np.abs(sa) ** (2 / e)
    taper = 1.0 + 0.25 * (s + 0.5)  # one end thicker
    P = centre[:, None] + rad * taper[:, None, None] * (cy[None, :, None] * side[:, None] + cz[None, :, None] * up)
    return grid_mesh(P)


def plaque(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Thin upright slab (1 wide, 0.6-0.9 high) with an irregular outline, 20-40 mm thick at size 0.3 m."""
    n = 96
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    w, h = 0.5, rng.uniform(0.3, 0.45)
    r = 1 + sum(rng.uniform(-0.08, 0.08) * np.cos(k * t + rng.uniform(0, 2 * np.pi)) for k in range(2, 6))
    x, z = w * r * np.cos(t), h * r * np.sin(t)
    z = np.maximum(z, -h * 0.8)  # a flat bottom edge to stand on
    thick = rng.uniform(0.07, 0.12)
    outline = np.stack([x, z], 1)
    rings = [np.stack([outline[:, 0], np.full(n, y), outline[:, 1]], 1) for y in (-thick / 2, thick / 2)]
    return grid_mesh(np.stack(rings))


#: shapes whose geometry leaves a rotation free: painted more often (a decorated vase, a labelled box)
_OFTEN_PAINTED = ("vase", "dome", "box")
#: probability that an object is painted (its IR albedo patterned), for those and for the others
P_PAINTED = (0.75, 0.5)
#: albedo of the two paints (the plain object: 0.7)
PAINT_ALBEDO = (0.25, 0.75)


def paint(vertices: np.ndarray, triangles: np.ndarray, rng: np.random.Generator, size_m: float) -> np.ndarray:
    """A two-tone painted pattern: (F,) albedo per triangle. Dark blobs (radius 3-8 % of the
    object's size, 15-30 of them, centred on random vertices) on a light ground, plus a dark band
    round the object at a random height with probability 0.5."""
    c = vertices[triangles].mean(1)
    dark = np.zeros(len(triangles), bool)
    for _ in range(int(rng.integers(15, 31))):
        ctr = vertices[rng.integers(len(vertices))]
        r = rng.uniform(0.03, 0.08) * size_m
        dark |= np.linalg.norm(c - ctr, axis=1) < r
    if rng.random() < 0.5:
        zc, w = rng.uniform(0.2, 0.8) * vertices[:, 2].max(), rng.uniform(0.02, 0.05) * size_m
        dark |= np.abs(c[:, 2] - zc) < w
    return np.where(dark, PAINT_ALBEDO[0], PAINT_ALBEDO[1])


_GENERATORS = {"vase": vase, "box": box, "pebble": pebble, "baluster": baluster, "bar": bar, "plaque": plaque,
               "dome": dome}


def load_real_mesh(name: str, mesh_dir: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (arbitrary units) and triangles of one of :data:`REAL_MESHES`, read in place."""
    from tofmetry.io.mesh import read_geometry

    if name not in REAL_MESHES:
        raise InputError(f"real mesh: expected one of {sorted(REAL_MESHES)}, found {name!r}")
    path = Path(mesh_dir) / REAL_MESHES[name][0]
    if not path.is_file():
        raise InputError(f"real mesh {name}: {path} not found (pass the scan-meshes folder as mesh_dir)")
    g = read_geometry(path, f"mesh {name}")
    return np.asarray(g.points, np.float64), _orient_outward(np.asarray(g.points), np.asarray(g.faces, np.int64))


def _up_rotation(up) -> np.ndarray:
    """(3, 3) rotation taking ``up`` to +z."""
    u = np.asarray(up, float) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(u, z), float(u @ z)
    if c < -0.999999:
        return np.diag([1.0, -1.0, -1.0])
    K = skew(v)
    return np.eye(3) + K + K @ K / (1 + c)


def place_object(vertices: np.ndarray, up=(0.0, 0.0, 1.0), size_m: float = 0.3, yaw_deg: float = 0.0) -> np.ndarray:
    """Stand a mesh on the ground: ``up`` -> z, largest bounding-box side = ``size_m`` [m], yaw about
    z [deg], lowest point at z = 0, bounding-box centre on the z axis. Returns (V, 3) [m]."""
    v = np.asarray(vertices, np.float64) @ _up_rotation(up).T
    v = v * (size_m / float((v.max(0) - v.min(0)).max()))
    a = math.radians(yaw_deg)
    Rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    v = v @ Rz.T
    c = (v.min(0) + v.max(0)) / 2
    return v - np.array([c[0], c[1], v[:, 2].min()])


def make_object(name: str, seed: int = 0, size_m: float | None = None, yaw_deg: float | None = None,
                mesh_dir: str | os.PathLike | None = None, painted: bool | None = None) -> ObjectDraw:
    """One named object (real or procedural), its shape parameters, size, yaw and paint (:func:`paint`;
    probability :data:`P_PAINTED`) drawn from ``seed`` unless given."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x0B1E]))
    if name in REAL_MESHES:
        if mesh_dir is None:
            raise InputError(f"object {name}: a real mesh needs mesh_dir (the scan-meshes folder)")
        v, f = load_real_mesh(name, mesh_dir)
        up, character = REAL_MESHES[name][1], REAL_MESHES[name][2]
        kind, lo_hi = "real", REAL_SIZE_M
    elif name in PROCEDURAL:
        v, f = _GENERATORS[name](rng)
        up, character, lo_hi, kind = (0.0, 0.0, 1.0), PROCEDURAL[name][0], PROCEDURAL[name][1], "procedural"
    else:
        raise InputError(f"object: expected one of {sorted(REAL_MESHES) + sorted(PROCEDURAL)}, found {name!r}")
    size = float(rng.uniform(*lo_hi)) if size_m is None else float(size_m)
    yaw = float(rng.uniform(0.0, 360.0)) if yaw_deg is None else float(yaw_deg)
    p_paint = P_PAINTED[0] if name in _OFTEN_PAINTED else P_PAINTED[1]
    painted = rng.random() < p_paint if painted is None else bool(painted)
    vw = place_object(v, up, size, yaw)
    albedo = None
    if painted and name != "plaque":  # the plaque's long fan triangles carry no pattern
        if name == "box":
            vw, f = _subdivide_long_edges(vw, f, 0.012)
        albedo = paint(vw, f, rng, size)
    return ObjectDraw(name, kind, character, vw, f, size, yaw, int(seed), albedo=albedo)


def random_object(seed: int, mesh_dir: str | os.PathLike | None = None, names: tuple | None = None) -> ObjectDraw:
    """Draw an object of the family (module docstring). Without ``mesh_dir`` only procedural shapes
    are drawn; ``names`` restricts the choice."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x0B1F]))
    if names is None:
        real = sorted(REAL_MESHES) if mesh_dir is not None else []
        proc = sorted(PROCEDURAL)
        group = real if real and rng.random() < 0.5 else proc
        name = str(rng.choice(group))
    else:
        name = str(rng.choice(list(names)))
    return make_object(name, seed, mesh_dir=mesh_dir)


def textured_scene(vertices: np.ndarray, triangles: np.ndarray, albedo: np.ndarray | None = None, mat=None):
    """The object on the ground as a :class:`~tofmetry.simulate.surfaces.Scene`: like
    :func:`tofmetry.simulate.scenes.mesh_on_ground` (placed the same way, on ``mat``, a
    :class:`~tofmetry.simulate.mat.DotMat`, when one is given), with one mesh per albedo
    level of ``albedo`` (F,) so that the IR amplitude shows the pattern. Label 1 = object."""
    from tofmetry.simulate.scenes import mesh_on_ground
    from tofmetry.simulate.surfaces import MeshSurface

    sc = mesh_on_ground(vertices, triangles, mat=mat)
    if albedo is None:
        return sc
    a = np.asarray(albedo, np.float64).reshape(-1)
    if len(a) != len(triangles):
        raise InputError(f"textured_scene: {len(a)} albedos for {len(triangles)} triangles")
    vw = sc.info["mesh_vertices_world"]
    ground = [s for s in sc.surfaces if not isinstance(s, MeshSurface)]
    parts = [MeshSurface(vw, triangles[a == lev], float(lev), 1) for lev in np.unique(a)]
    sc.surfaces = ground + parts
    sc.info["albedo_levels"] = [float(x) for x in np.unique(a)]
    return sc
