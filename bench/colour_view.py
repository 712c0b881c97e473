"""Render a colourised PLY cloud to a PNG, to look at where colour sits on the geometry.

Two panels: the cloud seen from its own camera, and from a camera turned ``--yaw`` degrees about
a vertical axis through the cloud's median depth (colour that leaked across a depth edge shows up
there as a fringe on the wrong surface). Points without colour (``colored`` = 0) are drawn magenta.

    python -m bench.colour_view cloud.ply -o view.png [--yaw 30]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from tofmetry.io import read_ply


def _view(pts: np.ndarray, rgb: np.ndarray, yaw_deg: float, size=(960, 720), f=620.0) -> np.ndarray:
    pivot = np.array([0.0, 0.0, np.median(pts[:, 2])])
    a = np.radians(yaw_deg)
    R = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])
    q = (pts - pivot) @ R.T + pivot
    W, H = size
    ok = q[:, 2] > 0.1
    u = np.rint(f * q[ok, 0] / q[ok, 2] + W / 2).astype(int)
    v = np.rint(f * q[ok, 1] / q[ok, 2] + H / 2).astype(int)
    z, c = q[ok, 2], rgb[ok]
    img = np.full((H, W, 3), 40, np.uint8)
    zbuf = np.full((H, W), np.inf)
    order = np.argsort(-z)  # far first: near points overwrite
    for du in (0, 1):
        for dv in (0, 1):
            uu, vv = u[order] + du, v[order] + dv
            m = (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H)
            img[vv[m], uu[m]] = c[order][m]
            zbuf[vv[m], uu[m]] = np.minimum(zbuf[vv[m], uu[m]], z[order][m])
    return img


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ply")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--yaw", type=float, default=30.0)
    args = ap.parse_args()
    d = read_ply(args.ply)
    pts = np.asarray(d["points"], np.float64)
    rgb = np.asarray(d["colors"], np.uint8).copy()
    colored = np.asarray(d.get("colored", np.ones(len(pts)))) > 0.5
    rgb[~colored] = (255, 0, 255)
    panel = np.hstack([_view(pts, rgb, 0.0), _view(pts, rgb, args.yaw)])
    cv2.imwrite(args.output, cv2.cvtColor(panel, cv2.COLOR_RGB2BGR))
    print(f"{args.output}: {len(pts)} points, {colored.mean() * 100:.1f} % coloured")


if __name__ == "__main__":
    main()
