"""Board depth calibration on a ChArUco board, partial views included, against the checkerboard.

Rendered board datasets (``tofmetry.simulate.board_datasets``) of one random sensor of the
family (seed 3, as ``tests/interop/test_board_synthetic``): 16 poses of the default 13 x 10 ChArUco
board (aimed at the image centre, corners and edges, overhanging them) and 16 of a 9 x 6
checkerboard (seen whole), 0.6-1.3 m; the last 4 of each are held out of every fit (intrinsics
included). Truth: each pixel's noise-free systematic depth error (``truth.npz``), never read by
the calibration.

Tolerances: as for the checkerboard (``test_board_synthetic``): most of the simulated error
removed (``after < 0.5 raw + 0.3 mm``), and 0.5 mm for the sampling of 4 held-out views when the
two boards' calibrations are compared on the same held-out pixels.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.calibrate import CharucoBoard
from tofmetry.calibrate import board as B
from tofmetry.calibrate._board_charuco import charuco_square_masks
from tofmetry.errors import EstimationError, FormatError, InputError
from tofmetry.io.board_dataset import BoardDataset, BoardSpec, read_corners, write_corners

BOARD = CharucoBoard(13, 10, 80.0, 56.0, "DICT_4X4_100")
SEED, N_POSES, JUDGE = 3, 16, "12-15"


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


# ----------------------------------------------------------------------------- units
def test_white_and_dark_pixels_of_the_design():
    """A fronto-parallel board at 2 mm per pixel: white pixels on the white margins around the
    markers, dark ones on the black squares, every one at least ``margin`` pixels from an edge;
    only the squares touching a seen corner."""
    step = 2.0
    by, bx = np.mgrid[1.0:800.0:step, 1.0:1040.0:step]
    seen = np.ones(BOARD.n_corners, bool)
    white, dark = charuco_square_masks(bx, by, BOARD, seen, margin_px=1.5)
    s, m = BOARD.square_mm, BOARD.marker_mm
    i, j = (bx // s).astype(int), (by // s).astype(int)
    fx, fy = bx - i * s, by - j * s
    black = (i + j) % 2 == 0                                  # OpenCV's pattern: black at the top-left
    edge = np.minimum(np.minimum(fx, s - fx), np.minimum(fy, s - fy))
    out_marker = np.maximum(np.abs(fx - s / 2), np.abs(fy - s / 2)) - m / 2
    assert white.any() and dark.any() and not (white & dark).any()
    assert (~black[white]).all() and black[dark].all()
    assert edge[white | dark].min() >= 1.5 * step - 1e-9
    assert out_marker[white].min() >= 1.5 * step - 1e-9
    # every white margin and black square is used where it is wide enough
    assert (white | ~(~black & (edge >= 3.5 * step) & (out_marker >= 3.5 * step))).all()
    # one corner seen (id 0, at (s, s)): only its four squares
    one = np.zeros(BOARD.n_corners, bool)
    one[0] = True
    w1, d1 = charuco_square_masks(bx, by, BOARD, one, margin_px=1.5)
    assert (bx[w1 | d1] < 2 * s).all() and (by[w1 | d1] < 2 * s).all() and w1.any() and d1.any()


def test_partial_grids_and_corner_files(tmp_path):
    g = np.full((BOARD.n_corners, 2), np.nan)
    g[:6] = np.arange(12.0).reshape(6, 2) + 100.0
    obj, c = B.seen_corners(g, BOARD, BOARD.square_mm)
    assert len(c) == 6 and np.allclose(obj[1], [160.0, 80.0, 0.0])
    with pytest.raises(InputError, match="at least 6 seen corners"):
        B.check_corners(g[:, :] * np.where(np.arange(BOARD.n_corners) < 5, 1.0, np.nan)[:, None], BOARD, "grid")
    half = g.copy()
    half[7, 0] = 3.0                                           # one coordinate of a pair
    with pytest.raises(InputError, match="NaN pairs"):
        B.check_corners(half, BOARD, "grid")
    with pytest.raises(InputError, match=r"ChArUco board 13x10"):
        B.check_corners(g[:50], BOARD, "grid")
    # corners.json with ids: the seen corners by id, NaN for the others
    spec = BoardSpec(12, 9, 80.0)
    write_corners(tmp_path / "c.json", g[:6], spec, ids=np.arange(6))
    back = read_corners(tmp_path / "c.json", spec)
    np.testing.assert_array_equal(np.isfinite(back).all(axis=1), np.arange(BOARD.n_corners) < 6)
    np.testing.assert_allclose(back[:6], g[:6])
    (tmp_path / "bad.json").write_text(json.dumps({"ids": [1, 1], "corners_px": [[0, 0], [1, 1]]}))
    with pytest.raises(FormatError, match="distinct ids"):
        read_corners(tmp_path / "bad.json", spec)


def test_charuco_board_json(tmp_path):
    (tmp_path / "board.json").write_text(json.dumps({"type": "charuco", **BOARD.to_dict()}))
    ds = BoardDataset(tmp_path)
    assert ds.charuco == {k: v for k, v in BOARD.to_dict().items() if k != "type"}
    assert ds.board.size == BOARD.inner and len(ds) == 0
    (tmp_path / "board.json").write_text(json.dumps({"type": "charuco", "squares_x": 13, "square_mm": 80}))
    with pytest.raises(FormatError, match="squares_y"):
        BoardDataset(tmp_path)


def test_corner_noise_of_grids_with_different_counts():
    """Per-grid corner counts: each grid's RMS gives a sigma (chi-square, 2N - 6 dof); with equal
    counts this is the one-count formula."""
    r = np.array([0.05, 0.06, 0.04, 0.2])
    assert B.corner_noise_px(r, np.full(4, 40)) == pytest.approx(B.corner_noise_px(r, 40), rel=1e-12)
    # a grid of 8 corners shows less RMS for the same noise (6 of its 16 values fit the pose)
    s8, s100 = B.corner_noise_px([0.05] * 3, [8] * 3), B.corner_noise_px([0.05] * 3, [100] * 3)
    assert s8 > 1.2 * s100


# ----------------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    from tofmetry.simulate import random_sensor
    from tofmetry.simulate.board_datasets import board_dataset

    root = tmp_path_factory.mktemp("boards")
    sensor = random_sensor(SEED)
    return {k: board_dataset(root / k, N_POSES, k, seed=SEED, sensor=sensor) for k in ("charuco", "checkerboard")}


def _held_out_truth(path, cals):
    """Systematic error (truth) and each calibration's correction on the held-out poses' white pixels
    (the pixels chosen with the true lens: the same for every calibration)."""
    from tofmetry.pipelines.board import parse_pose_selection, resolve_board
    from tofmetry.sensor import CameraIntrinsics

    ds = BoardDataset(path)
    board, sq, _ = resolve_board(ds)
    tz = np.load(path / "truth.npz")
    intr = CameraIntrinsics.from_dict(json.loads((path / "truth.json").read_text())["true_intrinsics"])
    b, c = [], [[] for _ in cals]
    for i in parse_pose_selection(JUDGE, ds.names):
        depth, ir, _ = ds.load_poses([i])[0]
        grids = B.find_boards(ir, board)
        assert grids, f"pose {ds.names[i]}: board not found"
        s = B.board_samples(depth, ir, grids[0], board, sq, intr).select("white")
        b.append(tz[f"systematic_mm_{ds.names[i]}"][s.v, s.u])
        for k, cal in enumerate(cals):
            c[k].append(B.core_correction(cal, s.u, s.v, s.measured_mm))
    return np.concatenate(b), [np.concatenate(x) for x in c]


def test_charuco_depth_calibration_matches_the_checkerboard(datasets, tmp_path):
    from tofmetry.cli import app
    from tofmetry.pipelines.board import calibrate_board
    from tofmetry.pipelines.calibration_files import load_calibration

    # ChArUco through the command (board from board.json, intrinsics fitted on the training corners)
    out = tmp_path / "report"
    r = CliRunner().invoke(app, ["calibrate", "depth", str(datasets["charuco"]), "-o", str(tmp_path / "ch.npz"),
                                 "--judge-poses", JUDGE, "--report", str(out)])
    assert r.exit_code == 0, r.output
    assert "ChArUco board 13x10 squares" in r.output and "judged poses" in r.output
    rep = json.loads((out / "fit.json").read_text())
    f = rep["fit"]
    assert f["board"]["type"] == "charuco" and f["judge_poses"] == ["0012", "0013", "0014", "0015"]
    used = [row for row in rep["rows"] if row["status"] != "skipped"]
    partial = [row for row in used if row["n_corners"] < BOARD.n_corners]
    assert len(used) >= 10 and len(partial) >= 6, [row["n_corners"] for row in rep["rows"]]
    j = f["judged"]
    assert j["n_views"] == 4 and j["cases"]["tofmetry"]["rms_mm"] < j["cases"]["none"]["rms_mm"]
    cal_ch = load_calibration(tmp_path / "ch.npz", sensor="kinect_v2", shape=(424, 512))
    # the checkerboard on the same sensor, same protocol
    run_cb = calibrate_board(datasets["checkerboard"], None, judge_poses=JUDGE)
    jc = run_cb.fit["judged"]
    # on the same held-out pixels (the ChArUco set's), against the truth
    b, (c_ch, c_cb) = _held_out_truth(datasets["charuco"], [cal_ch, run_cb.calibration])
    print(f"ChArUco: {len(partial)}/{len(used)} partial views; judged against the board planes (noise included): "
          f"ChArUco {j['cases']['none']['rms_mm']:.2f} -> {j['cases']['tofmetry']['rms_mm']:.2f} mm, checkerboard "
          f"{jc['cases']['none']['rms_mm']:.2f} -> {jc['cases']['tofmetry']['rms_mm']:.2f} mm; held-out systematic "
          f"error (truth) {rms(b):.2f} mm -> ChArUco {rms(b + c_ch):.2f}, checkerboard {rms(b + c_cb):.2f} mm")
    assert rms(b + c_ch) < 0.5 * rms(b) + 0.3
    assert rms(b + c_ch) < rms(b + c_cb) + 0.5
    assert j["cases"]["tofmetry"]["rms_mm"] < jc["cases"]["tofmetry"]["rms_mm"] + 0.5


def test_board_option(datasets, tmp_path):
    from tofmetry.cli import app

    # --board replaces board.json: no 9x6 checkerboard in the ChArUco images
    r = CliRunner().invoke(app, ["calibrate", "depth", str(datasets["charuco"]), "-o", str(tmp_path / "a.npz"),
                                 "--board", "9x6", "--square-mm", "50", "--train-poses", "0-2"])
    assert r.exit_code != 0 and isinstance(r.exception, EstimationError) and "0 board grid" in str(r.exception)
    r = CliRunner().invoke(app, ["calibrate", "depth", str(tmp_path), "-o", str(tmp_path / "b.npz"), "--board", "charuco",
                                 "--square-mm", "80"])
    assert r.exit_code != 0 and isinstance(r.exception, InputError) and "--board" in str(r.exception)
