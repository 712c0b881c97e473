"""ChArUco against checkerboard IR intrinsics on a family of random Kinect-v2-class lenses.

For every lens of the family (``tofmetry.simulate.random_sensor(seed)``, as in
:mod:`bench.intrinsics_family`) two calibration sets are rendered by the virtual sensor
(``supersample=4``, noise, vignetting on):

* **checkerboard, N views**: 9 x 6 inner corners, 50 mm squares, whole board inside the image
  (``poses.board_poses``: centre, corners and edges of the image), exactly the images of
  :func:`bench.intrinsics_family.render_views`; detected and calibrated by tofmetry
  (:func:`~tofmetry.calibrate.detect_board` + :func:`~tofmetry.calibrate.calibrate_intrinsics`);
* **ChArUco, N/2 views**: the default board of the virtual sensor
  (:data:`tofmetry.simulate.datasets.CHARUCO_DEFAULT`: 13 x 10 squares of 80 mm, 56 mm DICT_4X4_100
  markers, 108 corners) at 0.7-1.2 m, aimed at the image centre, corners and edges and overhanging them
  (partial views, ``poses.charuco_poses``); :func:`~tofmetry.calibrate.detect_charuco` (OpenCV's
  detector, then the X-junction fit with the markers masked) + ``calibrate_intrinsics`` with
  per-view object points. The ChArUco set is also calibrated from OpenCV's own ChArUco corners
  (``refine="opencv"``) for reference.

Each is judged by the ray error against the true lens over the full image (RMS, and max in the
four 10 % corner regions). Done-when: ChArUco with N/2 views is as accurate as the checkerboard
with N views, i.e. its median and p90 ray error over the family are not larger.

Run: ``.venv/bin/python -m bench.charuco_family [--lenses 10] [--views 16] [--seeds ...] [--json F]``
(seeds drawn at random and printed unless given).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.intrinsics_family import BOARD, SQUARE_MM, draw_seeds, render_views
from tofmetry.calibrate import CharucoBoard, calibrate_intrinsics, detect_board, detect_charuco, ray_error_px

METHODS = ("checkerboard", "charuco", "charuco_opencv")
LABELS = {"checkerboard": "checkerboard 9x6, N views (tofmetry)", "charuco": "ChArUco 13x10, N/2 views (tofmetry)",
          "charuco_opencv": "ChArUco 13x10, N/2 views, OpenCV's corners"}


def render_charuco(seed: int, n_images: int):
    """IR views of the default ChArUco board for lens ``seed`` (as ``datasets.charuco_images``).

    Returns lens (true CameraIntrinsics), board (CharucoBoard), images, poses (board-to-camera [m])."""
    from tofmetry.simulate import random_sensor, scenes
    from tofmetry.simulate.datasets import CHARUCO_DEFAULT, charuco_poses_for

    sensor = random_sensor(int(seed))
    vk = sensor.camera(int(seed), supersample=4)
    b = CHARUCO_DEFAULT
    poses = charuco_poses_for(n_images, vk.intrinsics, b, seed)
    images = [next(vk.iter_frames(scenes.charuco(b["squares_x"], b["squares_y"], b["square_mm"] / 1000,
                                                 b["marker_mm"] / 1000, b["dictionary"], board_to_world=T), 1)).ir
              for T in poses]
    return vk.intrinsics, CharucoBoard(**b), images, poses


def evaluate_lens(seed: int, n_views: int = 16) -> dict:
    """Both calibrations of one lens, judged by ray error. Returns a dict per method: views used,
    corners, corner error RMS [px] against the true projections, ray error (RMS, corners max) [px]."""
    out = {"seed": int(seed)}
    t0 = time.perf_counter()
    lens, images, truth, _ = render_views(seed, n_views, BOARD, SQUARE_MM)
    size = (lens.width, lens.height)
    cs, errs = [], []
    for im, tr in zip(images, truth):
        det = detect_board(im, BOARD)
        if det is None or not det.usable:
            continue
        cs.append(det.corners)
        e1, e2 = np.linalg.norm(det.corners - tr, axis=1), np.linalg.norm(det.corners[::-1] - tr, axis=1)
        errs.append(e1 if e1.mean() <= e2.mean() else e2)
    res = calibrate_intrinsics(cs, None, BOARD, SQUARE_MM, size, leave_one_out=False)
    e = np.concatenate(errs)
    out["lens"] = lens.to_dict()
    out["checkerboard"] = {"views": len(cs), "of": n_views, "corners": int(sum(len(c) for c in cs)),
                           "corner_rms_px": float(np.sqrt(np.mean(e ** 2))), "predicted_rms_px": res.predicted_ray.rms_px,
                           **ray_error_px(lens, res.intrinsics).to_dict()}
    n2 = max(3, n_views // 2)
    lens2, board, images, poses = render_charuco(seed, n2)
    assert lens2.to_dict() == lens.to_dict()
    for key, refine in (("charuco", "model"), ("charuco_opencv", "opencv")):
        cs, objs, errs = [], [], []
        for im, T in zip(images, poses):
            det = detect_charuco(im, board, refine=refine)
            if det is None:
                continue
            tr = lens.project(det.object_points / 1000.0 @ T[:3, :3].T + T[:3, 3])
            cs.append(det.corners)
            objs.append(det.object_points)
            errs.append(np.linalg.norm(det.corners - tr, axis=1))
        res = calibrate_intrinsics(cs, None, board.inner, board.square_mm, size, leave_one_out=False,
                                   object_points=objs)
        e = np.concatenate(errs)
        out[key] = {"views": len(cs), "of": n2, "corners": int(sum(len(c) for c in cs)),
                    "corner_rms_px": float(np.sqrt(np.mean(e ** 2))), "predicted_rms_px": res.predicted_ray.rms_px,
                    **ray_error_px(lens, res.intrinsics).to_dict()}
    out["seconds"] = time.perf_counter() - t0
    return out


def _q(x, p):
    x = np.asarray([v for v in x if np.isfinite(v)], float)
    return float(np.percentile(x, p)) if x.size else float("nan")


def summarize(rows: list[dict]) -> dict:
    s = {}
    for m in METHODS:
        for k in ("rms_px", "corners_max_px", "corner_rms_px", "corners", "views"):
            v = [r[m][k] for r in rows]
            s[f"{m}.{k}"] = {"median": _q(v, 50), "p90": _q(v, 90), "max": _q(v, 100)}
    ratio = [r["charuco"]["rms_px"] / r["checkerboard"]["rms_px"] for r in rows]
    s["charuco_over_checkerboard_rms"] = {"median": _q(ratio, 50), "p90": _q(ratio, 90), "max": _q(ratio, 100),
                                          "lenses_charuco_better": int(sum(x < 1 for x in ratio))}
    return s


def table(rows: list[dict], s: dict, n_views: int) -> str:
    lines = ["| seed | " + " | ".join(LABELS[m] + ": ray RMS / corners max [px]" for m in METHODS) + " |",
             "|---" * (1 + len(METHODS)) + "|"]
    for r in rows:
        lines.append(f"| {r['seed']} | " + " | ".join(f"{r[m]['rms_px']:.3f} / {r[m]['corners_max_px']:.3f}"
                                                      for m in METHODS) + " |")
    lines += ["", f"| over {len(rows)} lenses (N = {n_views}) | views | corners | corner error RMS [px] | "
              "ray RMS median / p90 [px] | ray max in the corners median / p90 [px] |", "|---|---|---|---|---|---|"]
    for m in METHODS:
        g = lambda k, f="{:.3f}": f"{f.format(s[f'{m}.{k}']['median'])} / {f.format(s[f'{m}.{k}']['p90'])}"  # noqa: E731
        lines.append(f"| {LABELS[m]} | {s[f'{m}.views']['median']:.0f} | {s[f'{m}.corners']['median']:.0f} | "
                     f"{s[f'{m}.corner_rms_px']['median']:.3f} | {g('rms_px')} | {g('corners_max_px')} |")
    v = s["charuco_over_checkerboard_rms"]
    lines.append(f"\nChArUco (N/2) / checkerboard (N) ray RMS: median {v['median']:.2f}, p90 {v['p90']:.2f}, max "
                 f"{v['max']:.2f}; ChArUco better on {v['lenses_charuco_better']} of {len(rows)} lenses")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lenses", type=int, default=10, help="number of random lenses [10]")
    ap.add_argument("--views", type=int, default=16, help="checkerboard views N (ChArUco gets N/2) [16]")
    ap.add_argument("--seeds", type=int, nargs="*", help="explicit lens seeds (default: drawn at random)")
    ap.add_argument("--json", type=Path, help="write every per-lens result here")
    args = ap.parse_args(argv)
    seeds = args.seeds if args.seeds else draw_seeds(args.lenses)
    print(f"seeds: {' '.join(map(str, seeds))}", file=sys.stderr)
    rows = []
    for k, sd in enumerate(seeds):
        r = evaluate_lens(sd, args.views)
        rows.append(r)
        print(f"[{k + 1}/{len(seeds)}] seed {sd}: " + "; ".join(
            f"{m} {r[m]['rms_px']:.3f} ({r[m]['views']} views, {r[m]['corners']} corners)" for m in METHODS)
            + f"  {r['seconds']:.0f} s", file=sys.stderr)
    s = summarize(rows)
    print(f"\nFamily of {len(seeds)} lenses; seeds {' '.join(map(str, seeds))}\n")
    print(table(rows, s, args.views))
    if args.json:
        args.json.write_text(json.dumps({"seeds": seeds, "views": args.views, "rows": rows, "summary": s}, indent=1,
                                        default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
