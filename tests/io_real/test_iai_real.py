"""iai_kinect2 files and the Kinect v2 board recording (real data, ../shared/data)."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from tofmetry.calibrate import board as B
from tofmetry.io import iai_kinect2 as ik

pytestmark = pytest.mark.realdata
BOARD, SQ = (5, 7), 30.0      # README: 5x7 inner corners, 30 mm squares


def _devices(shared_data):
    root = shared_data / "kinect2-device-calibrations"
    return [d for d in sorted(root.iterdir()) if d.is_dir() and not d.name.startswith("_")]


def _strip_doc_start(text: str) -> str:
    # OpenCV 2.4 wrote no '---' after '%YAML:1.0', OpenCV 3+ does; both load in iai_kinect2
    return text.replace("%YAML:1.0\n---\n", "%YAML:1.0\n", 1)


def test_nine_devices_round_trip_byte_exact(shared_data, tmp_path):
    devs = _devices(shared_data)
    assert len(devs) == 9
    no_depth = []
    for d in devs:
        cal = ik.read_iai_calibration(d)
        out = tmp_path / d.name
        ik.write_iai_calibration(out, cal)
        for f in ik.CALIB_FILES:
            if not (d / f).is_file():
                assert not (out / f).exists()
                no_depth.append(d.name)
                continue
            assert _strip_doc_start((out / f).read_text()) == _strip_doc_start((d / f).read_text()), f"{d.name}/{f}"
        # essential/fundamental are derivable: recomputed from R, t and both intrinsics they
        # reproduce the stored doubles up to last-bit rounding
        E, F = ik.essential_fundamental(cal.ir_to_color, cal.ir, cal.color)
        np.testing.assert_allclose(E, cal.essential, rtol=0, atol=1e-15)
        np.testing.assert_allclose(F, cal.fundamental, rtol=1e-9, atol=1e-15)
        # device spread: real Kinect v2 IR focal lengths 326-370 px
        assert 320 < cal.ir.fx < 375 and cal.ir.shape == (424, 512)
    assert no_depth == ["299150235147"]


@pytest.fixture(scope="module")
def recording(shared_data):
    root = shared_data / "kinect2-board-recording"
    ids = sorted(p.name[:4] for p in root.glob("*_depth.png"))
    corners = [ik.read_ir_points(root / f"{i}_ir_points.yaml", BOARD) for i in ids]
    return root, ids, corners


def test_ir_intrinsics_from_real_corners(recording):
    root, ids, corners = recording
    fit = B.calibrate_intrinsics(corners, ids, BOARD, SQ, (512, 424), leave_one_out=False)
    # poses 0010 and 0011 hold mis-detected corners (a reflection on the board): 2.2-2.3 px
    assert fit.rejected_views == ["0010", "0011"]
    # measured 0.095 px (in-sample) and 0.098 px (5-fold held-out); 25 % margin
    assert fit.rms_px < 0.12
    cv = B.cross_validate_intrinsics(corners, BOARD, SQ, (512, 424), k=5,
                                     exclude=[ids.index(n) for n in fit.rejected_views])
    assert cv["rms_px"] < 0.125
    own = ik.read_calib_ir(root / "calib_ir.yaml")
    iai = B.reprojection_rms_with(own, [corners[i] for i in cv["views"]], BOARD, SQ)
    # the recording's own calib_ir.yaml: 0.113 px even in-sample; ours is better held-out
    assert cv["rms_px"] < np.sqrt(np.mean(iai ** 2))
    # and differs from it by several pixels in fy / cy (README)
    assert abs(fit.intrinsics.fy - own.fy) > 10 and abs(fit.intrinsics.cy - own.cy) > 5


def test_corner_detection_on_dark_ir(recording):
    root, ids, corners = recording
    found, err = 0, []
    for i, c in zip(ids[:20], corners[:20]):
        det = B.detect_corners(cv2.imread(str(root / f"{i}_ir.png"), cv2.IMREAD_UNCHANGED), BOARD)
        if det is not None:
            found += 1
            err.append(min(np.abs(det - c).max(), np.abs(det[::-1] - c).max()))
    # measured: 69/70 found (68/70 with the former detector), median max-corner difference to iai's corners 0.48 px
    assert found >= 17
    assert np.median(err) < 0.8


@pytest.fixture(scope="module")
def judged_run(shared_data, tmp_path_factory):
    """The user's path: import the recording, fit on poses 0000-0049 only (intrinsics included),
    judge 0050-0069 with the written calibration (``tofmetry calibrate depth DS --train-poses 0-49
    --judge-poses 50-69``)."""
    from tofmetry.io.board_dataset import BoardSpec, import_iai_kinect2
    from tofmetry.pipelines.board import calibrate_board

    ds = tmp_path_factory.mktemp("iai") / "ds"
    import_iai_kinect2(shared_data / "kinect2-board-recording", ds, BoardSpec(5, 7, 30.0))
    return calibrate_board(ds, None, train_poses="0-49", judge_poses="50-69")


def test_judged_poses_fit_on_earlier_poses(judged_run):
    """Fitted on the poses recorded first, judged on the 20 recorded later, which no fit saw.

    Measured (2026-11-24): none 10.98 mm RMS (our intrinsics; 37.65 with iai's), iai_kinect2's
    depthShift with its own intrinsics 15.69, the best constant of the training poses 4.95,
    tofmetry 3.35 mm (P95 6.29, mean +1.78); predicted for 20 new poses RMS [2.9, 4.4],
    P95 [5.6, 8.2], mean [-1.8, +2.1] mm: the measured values lie inside.
    """
    f = judged_run.fit
    j = f["judged"]
    c = j["cases"]
    assert f["train_poses"][-1] == "0049" and j["poses"] == [f"{i:04d}" for i in range(50, 70)]
    assert j["n_views"] == 20
    # the intrinsics were fitted on the training poses only, and said so
    assert judged_run.intrinsics_source.startswith("fitted on the board corners")
    ours, const, iai = c["tofmetry"]["rms_mm"], c["constant"]["rms_mm"], c["iai_kinect2"]["rms_mm"]
    print({k: (round(v["mean_mm"], 2), round(v["rms_mm"], 2), round(v["p95_abs_mm"], 2)) for k, v in c.items()})
    print("prediction", j["prediction"])
    # the two targets: below the best constant, and at most half of iai_kinect2's RMS
    assert ours < const
    assert ours <= 0.5 * iai
    # the raw error is about -36 mm with iai's intrinsics (README: -34 +- 17 mm)
    assert c["none_iai_intrinsics"]["mean_mm"] == pytest.approx(-36, abs=8)
    # honest prediction: the measured RMS and P95 lie within the predicted 90 % intervals
    p = j["prediction"]
    assert p["rms_mm_interval"][0] <= ours <= p["rms_mm_interval"][1]
    assert p["p95_abs_mm_interval"][0] <= c["tofmetry"]["p95_abs_mm"] <= p["p95_abs_mm_interval"][1]


def test_judged_run_model_support_and_grids(judged_run):
    f = judged_run.fit
    res = judged_run.board_result
    # the model was chosen on blocked folds: time blocks, range bins, image regions
    chosen = [r for r in f["selection"] if r["chosen"]]
    assert len(chosen) == 1 and {"time_rms_mm", "range_rms_mm", "region_rms_mm"} <= set(chosen[0])
    assert f["validation"]["random"]["blocked"] is False
    # poses 0010 / 0011: iai_kinect2's corners are wrong (a reflection, 2.3-2.4 px); they are
    # rejected by a threshold from the measured corner noise (0.08 px), not a px-scale constant
    rej = {r["view"] for r in f["grid_screen"]["rejected"]}
    assert rej == {"0010", "0011"}
    assert f["grid_screen"]["threshold_px"] < 1.0
    # the near poses whose white squares saturate are not skipped silently: their status is on record
    status = {r["pose"]: r["status"] for r in judged_run.rows}
    assert status["0003"] in ("dark-only", "skipped") and status["0020"] == "white"
    assert any("saturated white squares" in n for n in judged_run.notes)
    # dark squares read longer at low amplitude (measured: +18 mm at 750, -5 mm at 3700)
    db = res.dark_bias
    assert db(np.array([800.0]))[0] > db(np.array([3000.0]))[0] + 5.0
    # support: per 16 px cell and 100 mm bin, from the samples the final fit used
    assert res.support["counts"].sum() == len(res.samples["u"]) > 10000
    # the calibration file carries the prediction and the support
    cal = judged_run.calibration
    assert "predicted_error" in cal.diagnostics and cal.diagnostics["support"]["cell_px"] == 16


def test_four_poses_with_given_intrinsics_leave_one_out(recording):
    """Five poses at 0.5-1.3 m, each corrected by a calibration fitted on the other four with the
    recording's published intrinsics (iai's calib_ir.yaml): never refused, no per-pixel surface."""
    root, ids, corners = recording
    iai = ik.read_calib_ir(root / "calib_ir.yaml")
    sel = [12, 25, 40, 55, 62]
    views = [(cv2.imread(str(root / f"{ids[k]}_depth.png"), cv2.IMREAD_UNCHANGED),
              cv2.imread(str(root / f"{ids[k]}_ir.png"), cv2.IMREAD_UNCHANGED), corners[k]) for k in sel]
    errs = {"none": [], "constant": [], "tofmetry": []}
    for k in range(len(sel)):
        res = B.calibrate_depth_from_board([v for j, v in enumerate(views) if j != k], BOARD, SQ, iai)
        assert res.intrinsics_source == "given" and res.spec.surface_smooth is None
        cal = res.depth_calibration()
        ev = B.evaluate_views([views[k]], BOARD, SQ, iai, {
            "none": None, "constant": lambda u, v, z, s=res.constant_mm: np.full(len(u), s),
            "tofmetry": lambda u, v, z, cal=cal: B.core_correction(cal, u, v, z)},
            sigma_px=res.grid_screen["corner_noise_px"])
        for c, lst in errs.items():
            lst.append(ev["errors"][c])
    out = {c: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for c, v in errs.items()}
    print(out)
    # measured: none 42.4, constant 13.6, tofmetry (constant + gain in radial range) 6.8 mm
    assert out["tofmetry"] < out["constant"] < out["none"]


def test_import_recording_subset(recording, tmp_path):
    from tofmetry.io.board_dataset import BoardDataset, BoardSpec
    from tofmetry.pipelines.iai_import import import_iai_kinect2

    root, ids, corners = recording
    src = tmp_path / "src"           # a 3-pose copy in the test's temp folder
    src.mkdir()
    for f in ["calib_ir.yaml", "calib_color.yaml", "calib_pose.yaml", "calib_depth.yaml"] + \
             [f"{i}_{k}" for i in ids[:3] for k in ("depth.png", "ir.png", "ir_points.yaml")]:
        shutil.copy(root / f, src / f)
    s = import_iai_kinect2(src, tmp_path / "ds", BoardSpec(5, 7, 30.0))
    assert s["poses"] == 3 and s["with_corners"] == 3
    ds = BoardDataset(tmp_path / "ds")
    np.testing.assert_array_equal(ds.capture(1).depth(0), cv2.imread(str(root / f"{ids[1]}_depth.png"), cv2.IMREAD_UNCHANGED))
    np.testing.assert_array_equal(ds.corners(2), corners[2])
    assert ds.depth_shift_mm() == pytest.approx(25.495, abs=1e-3)
    assert ds.intrinsics() == ik.read_calib_ir(root / "calib_ir.yaml")
    from tofmetry.pipelines import load_calibration

    cal = load_calibration(tmp_path / "ds" / "depth_shift.npz", sensor="kinect_v2", shape=(424, 512))
    assert cal.offset_mm == pytest.approx(-25.495, abs=1e-3) and cal.surfaces.max() == 0


def test_the_raw_depth_of_this_kinect_is_tilted_against_its_ir_frame(judged_run):
    """The depth error linear in the image position (``tofmetry calibrate depth WALLS --tilt-boards``),
    measured on the raw depth of the recording with the intrinsics fitted on its poses 0000-0049.

    Measured (2026-11-29): (+8.3, +46.9) +- (1.6, 1.6) mm per unit of x / z, y / z over 60 views
    (2.7 deg at 1 m); the views scatter by 12-13 mm per unit, the board pose's rotation error of a
    0.18 x 0.24 m board at 0.5-1.4 m (Z times 0.6 deg). This pins what the estimator reads on real
    data, not the sensor's tilt: after the board calibration of poses 0000-0049 it still reads
    (+3.6, +20.3) +- 1.9 on them, and folding that in makes the held-out poses 0050-0069 worse
    (board-plane RMS 3.35 -> 7.05 mm), so the per-view tilts of this recording carry a bias the
    model does not capture (README, "The tilt from board poses").

    Since 2026-11-29 the estimator checks itself on blocks of the recording kept out of the fit:
    their board-plane offsets across the image carry only 0.53 +- 0.04 of this tilt (the rest is
    the slope within each board against its orientation from the IR corners), so it is contradicted
    and a calibration given to ``tilt_from_boards`` is not changed."""
    from pathlib import Path

    from tofmetry.pipelines.depth_tilt import tilt_from_boards

    f = tilt_from_boards(Path(judged_run.path), intrinsics=judged_run.intrinsics).fit
    assert len(f.view_z_mm) >= 50 and f.sigma_mm.max() < 3.0
    assert f.tilt_mm[1] > 10 * f.sigma_mm[1]
    h = f.held_out
    assert not f.confirmed and h["bound_mm"] is None and h["carried"] + 2 * h["carried_se"] < 1.0
