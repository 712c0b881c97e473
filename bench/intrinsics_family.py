"""IR intrinsics over a family of random Kinect-v2-class lenses: tofmetry against plain OpenCV.

For every lens of the family (``tofmetry.simulate.random_sensor(seed)``: 512 x 424, fx 365 px
+-5 %, fy within +-1 % of fx, principal point +-15 px, Brown k1/k2/k3 spanning the 9 real
iai_kinect2 calibrations, p1/p2 up to +-2e-3, invertible over the image) a set of checkerboard IR
images is rendered with the virtual sensor exactly as ``tofmetry.simulate.datasets.checkerboard_images``
does (``VirtualKinect`` of the drawn sensor, ``supersample=4``, ``scenes.checkerboard`` at
``poses.board_poses``), then calibrated twice on the same images:

* **tofmetry**: :func:`tofmetry.calibrate.detect_board` (grid from
  ``findChessboardCornersSB``, X-junction model fit) + :func:`calibrate_intrinsics`;
* **plain OpenCV**, the textbook recipe: ``findChessboardCorners`` (default flags) +
  ``cornerSubPix`` 11x11 (criteria EPS+MAX_ITER, 30, 0.001) + ``calibrateCamera``, on the same 8-bit
  image tofmetry finds its grid in (percentile stretch of the 16-bit IR: the textbook needs 8 bit).

Both are judged by the **ray error** against the true lens (:func:`ray_error_px`: angle between
the true and the estimated ray through every pixel, in px at the focal length; RMS over the full
image and max in the four 10 % corner regions). tofmetry's *predicted* ray error (from the
parameter covariance) is compared with its true one.

``--detectors`` adds the corner-error table of candidate detectors (errors against the true
projected corners) and the ray error each gives through ``calibrateCamera``.

Run: ``.venv/bin/python -m bench.intrinsics_family [--lenses 20] [--images 15] [--seeds ...]``
(seeds are drawn at random and printed unless given). Not a timed benchmark.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from tofmetry.calibrate import (
    board_object_points, calibrate_intrinsics, detect_board, detect_corners, find_grid, normalize_ir, ray_error_px,
    refine_corners, refine_corners_subpix,
)
from tofmetry.sensor import CameraIntrinsics

BOARD, SQUARE_MM = (9, 6), 50.0
#: Methods compared: tofmetry, OpenCV's SB corners alone, SB + cornerSubPix (half cell, 16 bit), the textbook.
METHODS = ("tofmetry", "opencv_sb", "opencv_sb_csp", "opencv")
LABELS = {"tofmetry": "tofmetry", "opencv_sb": "OpenCV SB N+E+A alone", "opencv_sb_csp": "OpenCV SB + cornerSubPix "
          "half cell (16 bit)", "opencv": "OpenCV textbook (classic + cornerSubPix 11x11)"}
#: The textbook cornerSubPix set-up (OpenCV calibration tutorial).
TEXTBOOK_WIN = (11, 11)
TEXTBOOK_CRIT = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


def render_views(seed: int, n_images: int, board=BOARD, square_mm: float = SQUARE_MM):
    """Render ``n_images`` IR views of the board for the family's lens ``seed``.

    Returns
    -------
    lens : CameraIntrinsics (true); images : list of (424, 512) uint16; truth : list of (N, 2)
    true corner projections [px]; poses : list of (4, 4) board-to-camera [m].
    """
    from tofmetry.simulate import random_sensor, scenes
    from tofmetry.simulate.poses import board_poses

    sensor = random_sensor(int(seed))
    vk = sensor.camera(int(seed), supersample=4)
    lens = vk.intrinsics
    rng = np.random.default_rng([int(seed), 7])
    sq = square_mm / 1000.0
    poses = board_poses(n_images, lens, board[0], board[1], sq, rng)
    obj = board_object_points(board, sq)
    images, truth = [], []
    for T in poses:
        fr = next(vk.iter_frames(scenes.checkerboard(board[0], board[1], sq, T), 1))
        images.append(fr.ir)
        truth.append(lens.project(obj @ T[:3, :3].T + T[:3, 3]))
    return lens, images, truth, poses


def _intr(K, dist, size) -> CameraIntrinsics:
    d = np.asarray(dist, float).ravel()[:5]
    return CameraIntrinsics(size[0], size[1], K[0, 0], K[1, 1], K[0, 2], K[1, 2], tuple(d))


def textbook_corners(img: np.ndarray, board=BOARD, to8=normalize_ir):
    """``findChessboardCorners`` (default flags) + ``cornerSubPix`` 11x11 on the 8-bit image ``to8(img)``."""
    img8 = to8(img)
    ok, c = cv2.findChessboardCorners(img8, board)
    if not ok:
        return None
    c = cv2.cornerSubPix(img8, c, TEXTBOOK_WIN, (-1, -1), TEXTBOOK_CRIT)
    return c.reshape(-1, 2).astype(np.float64)


def opencv_calibrate(corners: list, board, square_mm: float, size) -> CameraIntrinsics:
    """Plain ``cv2.calibrateCamera`` (default flags and criteria)."""
    obj = board_object_points(board, square_mm).astype(np.float32)
    imgs = [np.asarray(c, np.float32).reshape(-1, 1, 2) for c in corners]
    _rms, K, dist, _r, _t = cv2.calibrateCamera([obj] * len(imgs), imgs, size, None, None)
    return _intr(K, dist, size)


def _matched_error(c: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) |corner - truth| [px], board order or its 180-degree reversal (a symmetric board)."""
    e1 = np.linalg.norm(c - truth, axis=1)
    e2 = np.linalg.norm(c[::-1] - truth, axis=1)
    return e1 if e1.mean() <= e2.mean() else e2


def _old_tofmetry(img, board):
    """The previous detector: SB (N+E+A) + cornerSubPix in a 2-5 px window on the 8-bit stretch."""
    img8 = normalize_ir(img)
    f = find_grid(img, board)
    if f is None:
        return None
    c = f[0].astype(np.float32).reshape(-1, 1, 2)
    g = c.reshape(board[1], board[0], 2)
    step = min(np.linalg.norm(np.diff(g, axis=1), axis=2).min(), np.linalg.norm(np.diff(g, axis=0), axis=2).min())
    win = int(np.clip(round(0.2 * float(step)), 2, 5))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    return cv2.cornerSubPix(img8.astype(np.float32), c, (win, win), (-1, -1), crit).reshape(-1, 2).astype(np.float64)


def _sb(img8, board, flags):
    ok, c = cv2.findChessboardCornersSB(img8, board, flags=flags)
    return np.asarray(c, np.float64).reshape(-1, 2) if ok else None


def _classic(img8, board):
    ok, c = cv2.findChessboardCorners(img8, board)
    return np.asarray(c, np.float64).reshape(-1, 2) if ok else None


def candidate_detectors() -> dict:
    """name -> function(img16, board) -> corners or None: the detectors compared (``--detectors``)."""
    N, E, A = cv2.CALIB_CB_NORMALIZE_IMAGE, cv2.CALIB_CB_EXHAUSTIVE, cv2.CALIB_CB_ACCURACY

    def sb(flags, norm=normalize_ir):
        return lambda im, b: _sb(norm(im), b, flags)

    def then(first, refine):
        def f(im, b):
            c = first(im, b)
            return None if c is None else refine(im, c, b)
        return f

    def minmax(im):
        return cv2.normalize(im, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)

    def gamma(im):
        return normalize_ir(im, gamma=0.5)

    def csp8(win_frac):
        return lambda im, c, b: refine_corners_subpix(normalize_ir(im), c, b, window_frac=win_frac)

    return {
        "SB (no flags)": sb(0),
        "SB NORMALIZE": sb(N),
        "SB NORMALIZE+EXHAUSTIVE": sb(N | E),
        "SB ACCURACY": sb(A),
        "SB N+E+A (tofmetry's grid finder)": sb(N | E | A),
        "SB N+E+A, min-max 8 bit": sb(N | E | A, minmax),
        "SB N+E+A, gamma 0.5": sb(N | E | A, gamma),
        "previous tofmetry (SB + cornerSubPix 2-5 px, 8 bit)": _old_tofmetry,
        "classic findChessboardCorners alone": lambda im, b: _classic(normalize_ir(im), b),
        "textbook: classic + cornerSubPix 11x11 (8 bit)": textbook_corners,
        "textbook on min-max 8 bit": lambda im, b: textbook_corners(im, b, to8=minmax),
        "classic + cornerSubPix half cell (8 bit)": then(lambda im, b: _classic(normalize_ir(im), b), csp8(0.5)),
        "SB N+E+A + cornerSubPix half cell (8 bit)": then(sb(N | E | A), csp8(0.5)),
        "SB N+E+A + cornerSubPix 0.35 cell (16 bit)": then(sb(N | E | A),
                                                          lambda im, c, b: refine_corners_subpix(im, c, b, 0.35)),
        "SB N+E+A + cornerSubPix half cell (16 bit)": then(sb(N | E | A), refine_corners_subpix),
        "SB N+E+A + X-junction fit on the 8-bit stretch": then(sb(N | E | A),
                                                              lambda im, c, b: refine_corners(normalize_ir(im), c, b).corners),
        "tofmetry: SB N+E+A + X-junction fit (16 bit)": detect_corners,
    }


def evaluate_lens(seed: int, n_images: int = 15, board=BOARD, square_mm: float = SQUARE_MM,
                  detectors: dict | None = None) -> dict:
    """Render one lens's views, calibrate with tofmetry and with plain OpenCV, judge by ray error.

    Returns
    -------
    dict with ``seed``, ``lens``, per method (``tofmetry``, ``opencv``): detected views, corner
    error RMS [px], ray error (RMS, p90, max, corners max) [px]; ``predicted`` (tofmetry's
    predicted ray error) and ``ratio_rms`` / ``ratio_corners`` (true / predicted); with
    ``detectors``, ``candidates``: per detector the detected count, the corner errors and the
    ray RMS through ``calibrateCamera``.
    """
    t0 = time.perf_counter()
    lens, images, truth, _ = render_views(seed, n_images, board, square_mm)
    size = (lens.width, lens.height)
    t_render = time.perf_counter() - t0
    out = {"seed": int(seed), "lens": lens.to_dict(), "images": len(images), "render_s": t_render}
    # tofmetry
    t0 = time.perf_counter()
    cs, errs, fm, grids = [], [], [], []
    for im, tr in zip(images, truth):
        det = detect_board(im, board)
        if det is None:
            continue
        grids.append((im, det.refinement.initial, tr))
        if not det.usable:
            continue
        cs.append(det.corners)
        errs.append(_matched_error(det.corners, tr))
        fm.append(det.refinement.fraction_model)
    res = calibrate_intrinsics(cs, None, board, square_mm, size, leave_one_out=False)
    re = ray_error_px(lens, res.intrinsics)
    pr = res.predicted_ray
    e = np.concatenate(errs)
    out["tofmetry"] = {"detected": len(cs), "corner_rms_px": float(np.sqrt(np.mean(e ** 2))),
                       "model_fraction": float(np.mean(fm)), "reproj_rms_px": res.rms_px,
                       "rejected_views": len(res.rejected_views), **re.to_dict(), "seconds": time.perf_counter() - t0,
                       "uncovered_corners": res.uncovered_corners}
    out["predicted"] = pr.to_dict()
    out["ratio_rms"] = re.rms_px / pr.rms_px
    out["ratio_corners"] = re.corners_max_px / pr.corners_max_px
    # OpenCV set up well, on the same grids: the SB corners alone (the documented accurate recipe,
    # CALIB_CB_ACCURACY) and SB + cornerSubPix in a half-cell window on the 16-bit image
    for key, refine in (("opencv_sb", None), ("opencv_sb_csp", refine_corners_subpix)):
        c_ref = [g if refine is None else refine(im, g, board) for im, g, _ in grids]
        e = np.concatenate([_matched_error(c, tr) for c, (_, _, tr) in zip(c_ref, grids)])
        re = ray_error_px(lens, opencv_calibrate(c_ref, board, square_mm, size))
        out[key] = {"detected": len(c_ref), "corner_rms_px": float(np.sqrt(np.mean(e ** 2))), **re.to_dict()}
    # plain OpenCV, textbook
    t0 = time.perf_counter()
    cs, errs = [], []
    for im, tr in zip(images, truth):
        c = textbook_corners(im, board)
        if c is None:
            continue
        cs.append(c)
        errs.append(_matched_error(c, tr))
    if len(cs) >= 3:
        est = opencv_calibrate(cs, board, square_mm, size)
        re = ray_error_px(lens, est)
        e = np.concatenate(errs)
        out["opencv"] = {"detected": len(cs), "corner_rms_px": float(np.sqrt(np.mean(e ** 2))),
                         "corner_median_px": float(np.median(e)), **re.to_dict(), "seconds": time.perf_counter() - t0}
    else:
        out["opencv"] = {"detected": len(cs)}
    if detectors:
        cand = {}
        for name, fn in detectors.items():
            cs, errs, t0 = [], [], time.perf_counter()
            for im, tr in zip(images, truth):
                c = fn(im, board)
                if c is not None:
                    cs.append(c)
                    errs.append(_matched_error(c, tr))
            row = {"detected": len(cs), "of": len(images), "seconds_per_image": (time.perf_counter() - t0) / len(images)}
            if cs:
                row["errors_px"] = np.concatenate(errs)
            if len(cs) >= 3:
                row["ray_rms_px"] = ray_error_px(lens, opencv_calibrate(cs, board, square_mm, size), step=2).rms_px
            cand[name] = row
        out["candidates"] = cand
    return out


def _q(x, p):
    x = np.asarray([v for v in x if np.isfinite(v)], float)
    return float(np.percentile(x, p)) if x.size else float("nan")


def summarize(rows: list[dict]) -> dict:
    """Median and p90 over the family of the ray errors of both methods and the predicted/true ratio."""
    s = {}
    for m in METHODS:
        for k in ("rms_px", "corners_max_px", "max_px", "corner_rms_px"):
            v = [r[m].get(k, float("nan")) for r in rows]
            s[f"{m}.{k}"] = {"median": _q(v, 50), "p90": _q(v, 90), "max": _q(v, 100)}
    for k in ("ratio_rms", "ratio_corners"):
        v = [r[k] for r in rows]
        s[k] = {"median": _q(v, 50), "p10": _q(v, 10), "p90": _q(v, 90), "min": _q(v, 0), "max": _q(v, 100)}
    for m in METHODS[1:]:
        d = [r["tofmetry"]["rms_px"] - r[m].get("rms_px", np.inf) for r in rows]
        tol = [tolerance_px(r) for r in rows]
        s[f"tofmetry_minus_{m}_rms_px"] = {"median": _q(d, 50), "max": _q(d, 100),
                                           "lenses_worse_beyond_tolerance": int(sum(x > t for x, t in zip(d, tol)))}
    return s


def tolerance_px(row: dict) -> float:
    """Per-lens tolerance of "not worse than OpenCV" [px]: twice tofmetry's own predicted 1-sigma
    ray error (RMS over the grid). Two estimates from the same images that were equally good would
    differ by about sqrt(2) x that sigma; tofmetry may lose to a reference by no more than this."""
    return 2.0 * row["predicted"]["rms_px"]


def table(rows: list[dict], summary: dict) -> str:
    """Markdown tables: one row per lens (ray error RMS over the grid / max in the corners [px]),
    then median / p90 over the family."""
    def rc(d):
        return f"{d.get('rms_px', float('nan')):.3f} / {d.get('corners_max_px', float('nan')):.3f}"

    lines = ["| seed | fx | k1 k2 k3 | tofmetry | predicted | " + " | ".join(LABELS[m] for m in METHODS[1:])
             + " | views tof/textbook | corner RMS tof / SB / SB+cSP / textbook [px] |",
             "|---" * (8 + len(METHODS) - 2) + "|"]
    for r in rows:
        L = r["lens"]
        k = L["distortion"]
        cr = " / ".join(f"{r[m].get('corner_rms_px', float('nan')):.3f}" for m in METHODS)
        lines.append(f"| {r['seed']} | {L['fx']:.1f} | {k[0]:+.3f} {k[1]:+.3f} {k[4]:+.3f} | {rc(r['tofmetry'])} | "
                     f"{rc(r['predicted'])} | " + " | ".join(rc(r[m]) for m in METHODS[1:])
                     + f" | {r['tofmetry']['detected']}/{r['opencv']['detected']} | {cr} |")
    s = summary
    lines += ["", "| over the family [px] | median | p90 | max |", "|---|---|---|---|"]
    for m in METHODS:
        for key, what in (("rms_px", "ray RMS, full grid"), ("corners_max_px", "ray max in the corners"),
                          ("corner_rms_px", "corner error RMS")):
            v = s[f"{m}.{key}"]
            lines.append(f"| {LABELS[m]}: {what} | {v['median']:.3f} | {v['p90']:.3f} | {v['max']:.3f} |")
    for key, label in (("ratio_rms", "true / predicted ray error, RMS over the grid"),
                       ("ratio_corners", "true / predicted ray error, max in the corners")):
        v = s[key]
        lines.append(f"| {label} | {v['median']:.2f} | p10 {v['p10']:.2f}, p90 {v['p90']:.2f} | "
                     f"{v['min']:.2f}-{v['max']:.2f} |")
    for m in METHODS[1:]:
        v = s[f"tofmetry_minus_{m}_rms_px"]
        lines.append(f"| tofmetry - {LABELS[m]}, ray RMS (lenses worse beyond 2 x predicted sigma: "
                     f"{v['lenses_worse_beyond_tolerance']}) | {v['median']:+.3f} | | {v['max']:+.3f} |")
    return "\n".join(lines)


def candidate_table(rows: list[dict]) -> str:
    """Markdown table of the candidate detectors over all lenses (corner errors against the truth)."""
    names = list(rows[0]["candidates"])
    lines = [("| detector | detected | corner error RMS | median | p95 | max | ray RMS via calibrateCamera "
              "(median / max) | s / image |"), "|---|---|---|---|---|---|---|---|"]
    for n in names:
        det = sum(r["candidates"][n]["detected"] for r in rows)
        tot = sum(r["candidates"][n]["of"] for r in rows)
        e = [r["candidates"][n]["errors_px"] for r in rows if "errors_px" in r["candidates"][n]]
        e = np.concatenate(e) if e else np.array([np.nan])
        ray = [r["candidates"][n].get("ray_rms_px", np.nan) for r in rows]
        sp = np.mean([r["candidates"][n]["seconds_per_image"] for r in rows])
        lines.append(f"| {n} | {det}/{tot} | {np.sqrt(np.nanmean(e ** 2)):.4f} | {np.nanmedian(e):.4f} | "
                     f"{np.nanpercentile(e, 95):.4f} | {np.nanmax(e):.2f} | {_q(ray, 50):.3f} / {_q(ray, 100):.3f} | {sp:.3f} |")
    return "\n".join(lines)


def draw_seeds(n: int) -> list[int]:
    """``n`` distinct random seeds (system entropy)."""
    r = random.SystemRandom()
    return sorted(r.sample(range(1, 2 ** 31 - 1), n))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lenses", type=int, default=20, help="number of lenses (random seeds) [20]")
    ap.add_argument("--images", type=int, default=15, help="images per lens [15]")
    ap.add_argument("--seeds", type=int, nargs="*", help="explicit lens seeds (default: drawn at random)")
    ap.add_argument("--square-mm", type=float, default=SQUARE_MM, help="board square [mm] (board 9x6) [50]")
    ap.add_argument("--detectors", action="store_true", help="also compare candidate corner detectors")
    ap.add_argument("--json", type=Path, help="write every per-lens result here")
    args = ap.parse_args(argv)
    seeds = args.seeds if args.seeds else draw_seeds(args.lenses)
    print(f"seeds: {' '.join(map(str, seeds))}", file=sys.stderr)
    dets = candidate_detectors() if args.detectors else None
    rows = []
    for k, s in enumerate(seeds):
        r = evaluate_lens(s, args.images, BOARD, args.square_mm, dets)
        rows.append(r)
        t = r["tofmetry"]
        print(f"[{k + 1}/{len(seeds)}] seed {s}: tofmetry ray RMS {t['rms_px']:.3f} px (corners {t['corners_max_px']:.3f}),"
              f" predicted {r['predicted']['rms_px']:.3f}; " + "; ".join(
                  f"{m} {r[m].get('rms_px', float('nan')):.3f}" for m in METHODS[1:]), file=sys.stderr)
    summ = summarize(rows)
    print(f"\nFamily of {len(seeds)} lenses, {args.images} images each, board 9x6 / {args.square_mm:g} mm; seeds "
          f"{' '.join(map(str, seeds))}\n")
    print(table(rows, summ))
    if dets:
        print("\nCandidate detectors (all lenses pooled; errors against the true projected corners):\n")
        print(candidate_table(rows))
    if args.json:
        for r in rows:
            for c in r.get("candidates", {}).values():
                c.pop("errors_px", None)
        args.json.write_text(json.dumps({"seeds": seeds, "images": args.images, "square_mm": args.square_mm,
                                         "rows": rows, "summary": summ}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
