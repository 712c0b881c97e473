"""Procedural test meshes (numpy only): a balustrade-like lying baluster.

The paper's object (§5) is a balustrade element ~40 x 20 cm: nearly symmetric, flat faces,
sculpted ends. :func:`balustrade_mesh` lofts a cross-section along x that is a rounded square
(superellipse, flat faces) in the middle block and circular in the turned ends, with a
turned profile (neck, bulb, bead, end disc). The result is a closed, watertight,
consistently oriented (outward normals) triangle mesh.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from tofmetry.errors import InputError

#: Control points of the half profile (x [m] from the centre, radius [m], superellipse exponent).
_PROFILE = [
    (0.000, 0.100, 10.0),
    (0.085, 0.100, 10.0),
    (0.095, 0.090, 6.0),
    (0.105, 0.060, 2.0),
    (0.118, 0.050, 2.0),
    (0.145, 0.082, 2.0),
    (0.170, 0.058, 2.0),
    (0.182, 0.052, 2.0),
    (0.188, 0.066, 2.0),
    (0.200, 0.066, 2.0),
]


def _profile(x: np.ndarray, asym: float) -> tuple[np.ndarray, np.ndarray]:
    px = np.array([p[0] for p in _PROFILE])
    pr = np.array([p[1] for p in _PROFILE])
    pe = np.array([p[2] for p in _PROFILE])
    ax = np.abs(x)
    r = PchipInterpolator(px, pr)(ax)
    e = PchipInterpolator(px, pe)(ax)
    # near-symmetry: the +x end is turned slightly fuller than the -x end
    r = r * (1.0 + asym * np.clip(x / 0.2, 0, 1) * (ax > 0.1))
    return r, e


def balustrade_mesh(length_m: float = 0.40, n_along: int = 161, n_around: int = 96,
                    asymmetry: float = 0.04) -> tuple[np.ndarray, np.ndarray]:
    """A lying turned baluster: ~40 cm long, 20 cm high and wide.

    Parameters
    ----------
    length_m : float
        Overall length along x [m] (profile is scaled).
    n_along, n_around : int
        Rings along x and vertices per ring.
    asymmetry : float
        Relative extra radius of the +x turned end (0 = exactly symmetric).

    Returns
    -------
    vertices : (V, 3) float64 [m], centred, axis along x, lowest point z = -0.1 m (scaled).
    triangles : (F, 3) int64, outward oriented, watertight.
    """
    if n_along < 8 or n_around < 8:
        raise InputError(f"balustrade_mesh: n_along and n_around must be >= 8, found {n_along}, {n_around}")
    s = length_m / 0.40
    x = np.linspace(-0.2, 0.2, n_along)
    # denser sampling where the profile changes: keep uniform (fine enough at 2.5 mm)
    r, e = _profile(x, asymmetry)
    th = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    c, sn = np.cos(th), np.sin(th)
    # superellipse |y|^e + |z|^e = r^e: flat axis-aligned faces for large e, a circle for e = 2
    cy = np.sign(c)[None, :] * np.abs(c)[None, :] ** (2.0 / e[:, None])
    cz = np.sign(sn)[None, :] * np.abs(sn)[None, :] ** (2.0 / e[:, None])
    Y = r[:, None] * cy
    Z = r[:, None] * cz
    X = np.repeat(x[:, None], n_around, axis=1)
    verts = np.stack([X, Y, Z], axis=-1).reshape(-1, 3) * s
    tris = []
    for i in range(n_along - 1):
        a = i * n_around + np.arange(n_around)
        b = i * n_around + (np.arange(n_around) + 1) % n_around
        a2, b2 = a + n_around, b + n_around
        tris.append(np.stack([a, a2, b2], 1))
        tris.append(np.stack([a, b2, b], 1))
    c0 = len(verts)
    c1 = c0 + 1
    verts = np.vstack([verts, [[-0.2 * s, 0, 0], [0.2 * s, 0, 0]]])
    ring0 = np.arange(n_around)
    ringN = (n_along - 1) * n_around + np.arange(n_around)
    tris.append(np.stack([np.full(n_around, c0), ring0, np.roll(ring0, -1)], 1))
    tris.append(np.stack([np.full(n_around, c1), np.roll(ringN, -1), ringN], 1))
    f = np.vstack(tris).astype(np.int64)
    f = _orient_outward(verts, f)
    return verts, f


def _orient_outward(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Flip all faces if the signed volume is negative (consistent winding assumed)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    return f[:, ::-1].copy() if vol < 0 else f
