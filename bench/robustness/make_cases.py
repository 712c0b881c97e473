"""Robustness matrix inputs (simulated scans). Usage: make_cases.py CASE [CASE...] | all"""
import os
import sys
from pathlib import Path
import numpy as np
from scipy.spatial import ConvexHull
import tofmetry.simulate.poses as P
from tofmetry.simulate import ErrorModel, datasets

OUT = Path(os.environ.get("RB_ROOT", "/tmp/rb")) / "scans"
NF = 4


def hull_mesh(pts):
    h = ConvexHull(pts)
    f = h.simplices.copy()
    c = pts.mean(0)
    for k, (a, b, cc) in enumerate(f):  # outward winding
        n = np.cross(pts[b] - pts[a], pts[cc] - pts[a])
        if n @ (pts[a] - c) < 0:
            f[k] = [a, cc, b]
    return pts, f


def chamfer_box(sx=0.30, sy=0.20, sz=0.15, c=0.015):
    pts = []
    for X in (-1, 1):
        for Y in (-1, 1):
            for Z in (-1, 1):
                corner = np.array([X * sx / 2, Y * sy / 2, Z * sz / 2])
                for ax in range(3):
                    p = corner.copy()
                    p[ax] -= np.sign(p[ax]) * c
                    pts.append(p)
    return hull_mesh(np.array(pts))


def revolve(profile_z, profile_r, n_around=96):
    z, r = np.asarray(profile_z), np.asarray(profile_r)
    a = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    V = [np.c_[ri * np.cos(a), ri * np.sin(a), np.full(n_around, zi)] for zi, ri in zip(z, r)]
    V = np.vstack(V + [[[0, 0, z[0]]], [[0, 0, z[-1]]]])
    nz = len(z)
    F = []
    for i in range(nz - 1):
        for k in range(n_around):
            a0, a1 = i * n_around + k, i * n_around + (k + 1) % n_around
            b0, b1 = a0 + n_around, a1 + n_around
            F += [[a0, a1, b1], [a0, b1, b0]]
    c0, c1 = nz * n_around, nz * n_around + 1
    for k in range(n_around):
        F.append([c0, (k + 1) % n_around, k])
        top = (nz - 1) * n_around
        F.append([c1, top + k, top + (k + 1) % n_around])
    return V, np.array(F)


def vase():
    z = np.linspace(0, 0.28, 57)
    r = 0.06 + 0.03 * np.sin(np.pi * z / 0.28 * 1.3) - 0.012 * (z > 0.22) * (z - 0.22) / 0.06
    return revolve(z, r)


def lumpy(seed=7):
    import open3d as o3d
    m = o3d.geometry.TriangleMesh.create_sphere(1.0, 40)
    v = np.asarray(m.vertices).copy()
    f = np.asarray(m.triangles).copy()
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(9, 3)); dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    amp = rng.uniform(-0.25, 0.3, 9); wid = rng.uniform(0.3, 0.7, 9)
    u = v / np.linalg.norm(v, axis=1, keepdims=True)
    r = 1 + sum(a * np.exp(-(1 - u @ d) / w ** 2) for a, d, w in zip(amp, dirs, wid))
    v = u * r[:, None] * np.array([0.11, 0.08, 0.10])
    v[:, 2] = np.maximum(v[:, 2], v[:, 2].min() + 0.03)  # flat base to stand on
    return v, f


def half_circle(n_views, radius_m, elevation_deg, target, start_deg=0.0):
    out = []
    el = np.radians(elevation_deg)
    for k in range(n_views):
        az = np.pi * k / (n_views - 1)
        d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        out.append(P.look_at(np.asarray(target, float) + radius_m * d, target))
    return out


CASES = {
    "base": dict(),
    "seed2": dict(seed=2), "seed3": dict(seed=3),
    "el20": dict(elevation_deg=20.0), "el45": dict(elevation_deg=45.0),
    "v6": dict(n_views=6), "v12": dict(n_views=12),
    "r0.8": dict(radius_m=0.8), "r1.4": dict(radius_m=1.4),
    "box6": dict(n_views=6, mesh="box"), "box8": dict(n_views=8, mesh="box"),
    "vase": dict(mesh="vase"), "lumpy": dict(mesh="lumpy"),
    "half4": dict(n_views=4, half=True),
}
MESHES = {"box": chamfer_box, "vase": vase, "lumpy": lumpy}

if __name__ == "__main__":
    names = list(CASES) if sys.argv[1:] == ["all"] else sys.argv[1:]
    nf = NF
    for name in names:
        kw = dict(CASES[name])
        half = kw.pop("half", False)
        if "mesh" in kw:
            kw["mesh"] = MESHES[kw["mesh"]]()
        kw.setdefault("seed", 0)
        orig = P.orbit_poses
        if half:
            P.orbit_poses = half_circle
        try:
            datasets.scan(OUT / name, n_frames=nf, errors=ErrorModel(), force=True, **kw)
        finally:
            P.orbit_poses = orig
        print("made", name, flush=True)
