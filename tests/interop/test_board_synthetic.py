"""Board-based depth calibration on boards rendered by the virtual sensor, whose truth is known.

Sensors: the simulator's default Kinect v2 and random sensors of the family
(``tofmetry.simulate.family.random_sensor``), seeds drawn once and printed in the test ids.
The truth of each pixel's error is the renderer's noise-free systematic bias
(``VirtualKinect.systematic_mm``); the calibration never sees it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tofmetry.calibrate import board as B
from tofmetry.errors import InputError
from tofmetry.simulate import scenes
from tofmetry.simulate.family import default_sensor, random_sensor
from tofmetry.simulate.poses import board_poses
from tofmetry.simulate.surfaces import Scene

BOARD = (9, 7)          # inner corners
SQ_M = 0.04             # square [m]
SQ = SQ_M * 1000.0      # [mm]
CORNER_NOISE_PX = 0.05  # noise added to the exact corner projections (a good sub-pixel detector)
# random sensors: seeds drawn once (numpy default_rng(2026).integers(0, 1000, 2)) and kept fixed
RANDOM_SEEDS = (3, 11)


def render_views(sensor, n: int, seed: int, dist=(0.6, 1.6), amp_white_1m=None, max_tilt_deg=35.0):
    """n views of the board: (depth uint16 [mm], IR, corners (N,2) [px], systematic bias (H,W) [mm], truth)."""
    rng = np.random.default_rng(seed)
    em = sensor.errors if amp_white_1m is None else sensor.errors.with_(amp_white_1m=amp_white_1m)
    vk = sensor.with_errors(em).camera(seed=seed, supersample=1)
    out = []
    for T in board_poses(n, vk.intrinsics, *BOARD, SQ_M, rng, dist_range=dist, max_tilt_deg=max_tilt_deg):
        sc = scenes.checkerboard(*BOARD, SQ_M, board_to_world=T)
        rd = vk.render(sc)
        fr = next(vk.iter_frames(sc, n_frames=1, rendering=rd))
        obj = B.board_object_points(BOARD, SQ) / 1000.0
        c = vk.intrinsics.project(obj @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, CORNER_NOISE_PX, (len(obj), 2))
        out.append((fr.depth, fr.ir, c, vk.systematic_mm(rd), rd))
    return out


def white_truth(views, intr, cal=None):
    """Held-out white pixels: systematic bias b, measured - reference e0 and (with ``cal``) the
    correction c, concatenated over views; the views' ids."""
    b, e0, c, ids = [], [], [], []
    for k, (d, ir, corners, sysb, _) in enumerate(views):
        s = B.board_samples(d, ir, corners, BOARD, SQ, intr).select("white")
        b.append(sysb[s.v, s.u])
        e0.append(s.measured_mm - s.reference_mm)
        ids.append(np.full(len(s.u), k))
        if cal is not None:
            c.append(B.core_correction(cal, s.u, s.v, s.measured_mm))
    cat = np.concatenate
    return cat(b), cat(e0), (cat(c) if c else None), cat(ids)


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


SENSORS = [("default", None)] + [(f"random{s}", s) for s in RANDOM_SEEDS]


@pytest.fixture(scope="module", params=SENSORS, ids=[s[0] for s in SENSORS])
def rendered(request):
    name, seed = request.param
    sensor = default_sensor() if seed is None else random_sensor(seed)
    views = render_views(sensor, 16, seed=7 if seed is None else seed)
    return name, sensor, views


def test_correction_recovers_simulated_error_at_held_out_poses(rendered):
    """Fit on 12 views (recording order), judge on 4 the fit never saw, against the noise-free truth."""
    name, sensor, views = rendered
    intr = sensor.intrinsics
    train, held = views[:12], views[12:]
    res = B.calibrate_depth_from_board([v[:3] for v in train], BOARD, SQ, intr)
    assert res.intrinsics_source == "given" and res.intrinsics is intr
    cal = res.depth_calibration(sensor="kinect_v2")
    b, e0, c, _ = white_truth(held, intr, cal)
    raw = rms(b)
    after = rms(b + c)
    # the per-pixel noise of one frame plus the board plane's own error: what no correction removes
    noise = rms(e0 - b)
    print(f"{name}: model {res.spec.name}; held-out systematic RMS {raw:.2f} -> {after:.2f} mm; noise {noise:.2f} mm; "
          f"predicted RMS (incl. noise) {res.prediction['rms_mm']:.2f} {res.prediction['rms_mm_interval']}")
    # (1) most of the simulated error is removed
    assert after < 0.5 * raw + 0.3
    # (2) what remains is within what the method predicted for new poses: the predicted RMS
    # includes the noise, so the systematic part it allows is sqrt(hi^2 - noise^2); 0.5 mm for
    # the sampling of only 4 held-out views
    hi = res.predict(len(held))["rms_mm_interval"][1]
    assert after < np.sqrt(max(hi ** 2 - noise ** 2, 0.0)) + 0.5
    # (3) measured against the board, as a user would judge it, the correction is at least as good
    # as the best constant fitted on the same training views (0.25 mm: the sampling of 4 views; on
    # random11 the chosen constant + gain and the constant leave both ~1 mm of systematic error)
    e_const = e0 + res.constant_mm
    assert rms(e0 + c) < rms(e_const) + 0.25
    # the support and the prediction are carried
    assert res.support["counts"].sum() == len(res.samples["u"]) > 1000
    assert set(res.validation) >= {"time", "range", "region", "random"} and not res.validation["random"]["blocked"]


def test_dark_white_bias_is_measured(rendered):
    """The dark-square bias is measured, not assumed: the simulator's (k + k_abs) ln(white / black)."""
    name, sensor, views = rendered
    em = sensor.errors
    truth = (em.amp_bias_mm_per_ln + em.amp_bias_abs_mm_per_ln) * np.log(0.8 / 0.133)
    samples = [B.board_samples(d, ir, c, BOARD, SQ, sensor.intrinsics) for d, ir, c, _, _ in views]
    db = B.fit_dark_bias(samples)
    amp = np.concatenate([s.amplitude[s.dark] for s in samples])
    # per-view contrasts scatter by the views' noise and their white squares' own amplitude
    # bias at oblique incidence; the fitted curve must hold the truth within 3 standard errors
    se = np.std(db.contrast_mm) / np.sqrt(len(db.contrast_mm))
    print(f"{name}: dark - white truth {truth:.2f} mm, measured {np.median(db(amp)):.2f} mm (se {se:.2f})")
    assert abs(np.median(db(amp)) - truth) < 3 * se + 0.5


def test_saturated_white_squares_enter_through_dark_squares():
    """Near views whose white squares saturate are used (dark squares minus the measured bias) or
    left out by the blocked validation, never silently dropped."""
    sensor = default_sensor()
    views = render_views(sensor, 10, seed=5, dist=(0.45, 1.5), amp_white_1m=60000.0)
    res = B.calibrate_depth_from_board([v[:3] for v in views], BOARD, SQ, sensor.intrinsics)
    status = [r["status"] for r in res.views]
    sat = [v for v in views if (v[1] >= 65535).sum() > 500]
    assert sat, "the rendering should saturate the near white squares"
    assert "dark-only" in status
    assert any("saturated white squares" in n for n in res.notes)
    # the decision is on record with both variants' blocked scores
    assert {r["use_dark_views"] for r in res.selection} == {False, True}


def _two_board_scene():
    T1 = np.eye(4)
    T1[:3, 3] = [-0.45, -0.12, 1.3]
    T2 = np.eye(4)
    c, s = np.cos(0.3), np.sin(0.3)
    T2[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T2[:3, 3] = [0.08, -0.1, 1.2]
    a = scenes.checkerboard(*BOARD, SQ_M, board_to_world=T1)
    b = scenes.checkerboard(*BOARD, SQ_M, board_to_world=T2)
    return Scene("two boards", a.surfaces + b.surfaces, a.labels, {}), (T1, T2)


@pytest.fixture(scope="module")
def two_boards():
    sensor = default_sensor()
    vk = sensor.camera(seed=3, supersample=2)
    scene, Ts = _two_board_scene()
    fr = next(vk.iter_frames(scene, n_frames=1))
    obj = B.board_object_points(BOARD, SQ) / 1000.0
    truth = [vk.intrinsics.project(obj @ T[:3, :3].T + T[:3, 3]) for T in Ts]
    return sensor, fr.depth, fr.ir, truth


def _match(found, truth):
    """Max corner error of ``found`` against the nearer of the true grids (either corner order)."""
    return min(min(np.abs(f - t).max(), np.abs(f[::-1] - t).max()) for t in truth for f in [found])


def test_two_board_view_yields_two_boards(two_boards):
    sensor, depth, ir, truth = two_boards
    found = B.find_boards(ir, BOARD)
    assert len(found) == 2
    assert all(_match(f, truth) < 1.0 for f in found)
    # the two grids are the two different boards
    assert np.linalg.norm(found[0].mean(0) - found[1].mean(0)) > 50
    scr = B.screen_grids(found, BOARD, SQ, sensor.intrinsics)
    assert scr.accepted.all()
    # a view with no given corners contributes both boards' pixels
    samples = [B.board_samples(depth, ir, c, BOARD, SQ, sensor.intrinsics) for c in found]
    both = B.BoardSamples.concat(samples)
    assert len(both.u) == sum(len(s.u) for s in samples)


def test_wrong_grid_is_rejected_by_its_reprojection_error(two_boards):
    sensor, _, _, truth = two_boards
    n = BOARD[0] * BOARD[1]
    good = [t + np.random.default_rng(k).normal(0, CORNER_NOISE_PX, t.shape) for k, t in enumerate(truth)]
    # a grid spanning the two boards: the left columns from one, the right ones from the other
    g = truth[0].reshape(BOARD[1], BOARD[0], 2).copy()
    g[:, 5:] = truth[1].reshape(BOARD[1], BOARD[0], 2)[:, 5:]
    wrong = g.reshape(n, 2)
    scr = B.screen_grids(good * 3 + [wrong], BOARD, SQ, sensor.intrinsics)
    # the threshold comes from the measured corner noise (0.05 px), not from a px-scale constant
    assert scr.sigma_px == pytest.approx(CORNER_NOISE_PX, rel=0.5)
    assert scr.threshold_px < 0.5
    assert scr.accepted[:-1].all() and not scr.accepted[-1]
    assert scr.rms_px[-1] > 2.0


@pytest.mark.parametrize("seed", [None, RANDOM_SEEDS[0]], ids=["default", f"random{RANDOM_SEEDS[0]}"])
def test_four_views_with_given_intrinsics_are_never_refused(seed):
    """5 views at 1-3 m and published intrinsics (the second real Kinect's case), each corrected by
    a calibration fitted on the other 4: never refused; a model of what 4 views support (a
    constant, or no correction when the views show no offset), with its support and predicted
    error. With 4 views no rule can know beforehand whether the raw depth or a constant will do
    better on the fifth (measured: the default sensor's views disagree by more than their mean
    offset, so its constant is not significant, yet it helps on the held-out view; random sensor
    3's does not): asked is that the result is never clearly the worst of the two, and that the
    calibration predicted its own error."""
    sensor = default_sensor() if seed is None else random_sensor(seed)
    views = render_views(sensor, 5, seed=21, dist=(1.0, 3.0), max_tilt_deg=25)
    intr = sensor.intrinsics
    errs = {"none": [], "constant": [], "tofmetry": []}
    predicted = []
    for k in range(len(views)):
        train = [v[:3] for j, v in enumerate(views) if j != k]
        res = B.calibrate_depth_from_board(train, BOARD, SQ, intr, min_samples=100)
        assert res.spec.surface_smooth is None and res.spec.complexity <= 1
        print(f"  view {k} left out: {res.spec.name}, predicted RMS {res.prediction['rms_mm']:.2f} mm")
        assert res.prediction and np.isfinite(res.prediction["rms_mm"])
        predicted.append(res.prediction["rms_mm"])
        cal = res.depth_calibration()
        _, e0, c, _ = white_truth([views[k]], intr, cal)
        errs["none"].append(e0)
        errs["constant"].append(e0 + res.constant_mm)
        errs["tofmetry"].append(e0 + c)
    out = {k: rms(np.concatenate(v)) for k, v in errs.items()}
    print("4-view leave-one-out:", out)
    # measured: default sensor none 11.1 / constant 8.9 / tofmetry 11.9 mm; random 3: 5.6 / 6.5 / 5.6 mm.
    # Not significantly worse than the worse of the two: the per-view mean squared errors' paired
    # differences, within two standard errors
    per = {k: np.array([np.mean(np.square(e)) for e in v]) for k, v in errs.items()}
    worst = per["none"] if out["none"] >= out["constant"] else per["constant"]
    dv = per["tofmetry"] - worst
    assert dv.mean() <= 2 * dv.std(ddof=1) / np.sqrt(len(dv)), (dv.mean(), dv.std(ddof=1))
    # the predicted RMS (quadratic mean over the folds) holds within 1.5x
    assert out["tofmetry"] <= 1.5 * float(np.sqrt(np.mean(np.square(predicted))))


def test_board_cli_fits_on_training_poses_and_judges_the_others(tmp_path):
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.io import CaptureMeta, CaptureWriter, atomic_write_json
    from tofmetry.io.board_dataset import BoardSpec, write_corners
    from tofmetry.io.intrinsics_json import write_intrinsics
    from tofmetry.pipelines.calibration_files import load_calibration

    sensor = default_sensor()
    views = render_views(sensor, 10, seed=9)
    root = tmp_path / "ds"
    spec = BoardSpec(*BOARD, SQ)
    atomic_write_json(root / "board.json", {"cols": BOARD[0], "rows": BOARD[1], "square_mm": SQ, "sensor": "kinect_v2"})
    for i, (depth, ir, corners, _, _) in enumerate(views):
        with CaptureWriter(root / "poses" / f"{i:04d}", CaptureMeta(sensor="kinect_v2")) as w:
            w.add(depth, ir=ir)
        write_corners(root / "poses" / f"{i:04d}" / "corners.json", corners, spec)
    write_intrinsics(tmp_path / "intr.json", sensor.intrinsics)
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["calibrate", "depth", str(root), "-o", str(tmp_path / "cal.npz"), "--intrinsics",
                                 str(tmp_path / "intr.json"), "--train-poses", "0-7", "--judge-poses", "8,9",
                                 "--report", str(out)])
    assert r.exit_code == 0, r.output
    assert "judged poses" in r.output and "best constant" in r.output and "model selection" in r.output
    rep = json.loads((out / "fit.json").read_text())
    f = rep["fit"]
    assert f["train_poses"] == [f"{i:04d}" for i in range(8)] and f["judge_poses"] == ["0008", "0009"]
    assert f["intrinsics_source"] == "given"
    j = f["judged"]
    assert j["n_views"] == 2 and j["cases"]["tofmetry"]["rms_mm"] < j["cases"]["none"]["rms_mm"]
    assert set(j["prediction"]) >= {"rms_mm_interval", "p95_abs_mm_interval", "mean_mm_interval"}
    assert (out / "board_calibration.png").stat().st_size > 10000
    cal = load_calibration(tmp_path / "cal.npz", sensor="kinect_v2", shape=(424, 512))
    assert cal.surface_model.startswith("board") and "predicted_error" in cal.diagnostics
    assert cal.support is not None and cal.fallback == "hold" and cal.prediction["board"]
    # overlapping selections are refused, naming the options
    r = CliRunner().invoke(app, ["calibrate", "depth", str(root), "-o", str(tmp_path / "c2.npz"), "--train-poses",
                                 "0-8", "--judge-poses", "8-9"])
    assert r.exit_code != 0 and isinstance(r.exception, InputError) and "overlap" in str(r.exception)


def test_detect_corners_in_rendered_ir(rendered):
    _, _, views = rendered
    _, ir, corners, _, _ = views[2]
    det = B.detect_corners(ir, BOARD)
    assert det is not None
    d_ = det if np.abs(det - corners).max() < np.abs(det[::-1] - corners).max() else det[::-1]
    # corners rendered without anti-aliasing (supersample 1): each edge known to +-0.5 px
    assert np.median(np.abs(d_ - corners)) < 0.3


def test_corner_count_mismatch_is_clear(rendered):
    _, sensor, views = rendered
    depth, ir, corners, _, _ = views[0]
    with pytest.raises(InputError, match=r"do not match the board 9x7"):
        B.board_samples(depth, ir, corners[:-1], BOARD, SQ, sensor.intrinsics)
