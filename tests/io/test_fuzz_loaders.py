"""Fuzzed loaders: every reader, fed mutated real files and random bytes, either reads them or raises
tofmetry's own error (a :class:`~tofmetry.errors.TofmetryError`) naming the file; never anything else.

Seeds are real files: the recordings of ``shared/data`` where present, and files written by the
virtual sensor. Mutations flip, insert, delete and truncate bytes (or replace the file by random
bytes; text formats also get random text). The number of cases per reader is
``TOFMETRY_FUZZ_EXAMPLES`` (default 60: a few seconds each in CI); ``bench/fuzz_loaders.py`` runs
10,000 per reader.
"""

from __future__ import annotations

import json
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from tofmetry.errors import TofmetryError  # noqa: E402

EXAMPLES = int(os.environ.get("TOFMETRY_FUZZ_EXAMPLES", "60"))
SHARED = Path(os.environ.get("TOFMETRY_SHARED_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=EXAMPLES <= 200,
                suppress_health_check=list(HealthCheck))


# ----------------------------------------------------------------------------- mutations
TOKENS = [b"-", b"1e308", b"NaN", b"null", b"[", b"]", b"{", b"}", b'"', b",", b":", b"\x00", b"\xff", b"..", b"/",
          b"-1", b"0", b"nan", b"inf"]


def _edit():
    """One byte-level edit: (op, position as a share of the length, value)."""
    return st.tuples(st.integers(0, 4), st.floats(0, 1, allow_nan=False), st.binary(min_size=1, max_size=16),
                     st.integers(0, 255), st.integers(1, 64), st.sampled_from(TOKENS))


def edits(text: bool = False):
    """A mutation of a seed file (applied by :func:`apply`): up to 4 edits, or random bytes/text."""
    return st.one_of(
        st.tuples(st.just("edits"), st.lists(_edit(), min_size=1, max_size=4)).filter(lambda x: True),
        st.tuples(st.just("edits"), st.lists(_edit(), min_size=1, max_size=4)),
        st.tuples(st.just("edits"), st.lists(_edit(), min_size=1, max_size=4)),
        st.tuples(st.just("bytes"), st.binary(max_size=512)),
        *([st.tuples(st.just("text"), st.text(max_size=400))] if text else []),
    )


def apply(seed: bytes, mutation) -> bytes:
    kind, arg = mutation
    if kind == "bytes":
        return arg
    if kind == "text":
        return arg.encode("utf-8", "surrogatepass")
    data = bytearray(seed)
    for op, where, blob, value, n, token in arg:
        if not data:
            break
        i = min(int(where * len(data)), len(data) - 1)
        if op == 0:
            data[i] = value
        elif op == 1:
            data[i:i] = blob
        elif op == 2:
            del data[i:i + n]
        elif op == 3:
            del data[i:]
        else:
            data[i:i] = token
    return bytes(data)


@st.composite
def mutated(draw, seed: bytes, text: bool = False):
    """``seed`` with up to 4 byte-level edits, or random bytes (random text for text formats)."""
    return apply(seed, draw(edits(text)))


COUNTS: dict[str, list[int]] = {}
CURRENT = "?"


@pytest.fixture(autouse=True)
def _count(request):
    """Cases run and cases a reader refused, per reader (written to $TOFMETRY_FUZZ_COUNTS by the bench)."""
    global CURRENT
    CURRENT = request.node.name
    COUNTS.setdefault(CURRENT, [0, 0])
    yield
    out = os.environ.get("TOFMETRY_FUZZ_COUNTS")
    if out:
        Path(out).write_text(json.dumps(COUNTS, indent=1))


def check(call, path: Path):
    """Run ``call()``; a failure must be a TofmetryError whose message names ``path``."""
    c = COUNTS.setdefault(CURRENT, [0, 0])
    c[0] += 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            call()
        except TofmetryError as exc:
            c[1] += 1
            assert path.name in str(exc) or str(path.parent.name) in str(exc), f"error does not name the file: {exc}"


# ----------------------------------------------------------------------------- seeds
@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    """Real files of every format (the virtual sensor's and shared/data's)."""
    from tofmetry.io import write_capture, write_intrinsics, write_ply
    from tofmetry.io.board_dataset import BoardSpec, write_corners
    from tofmetry.io.e57 import write_e57
    from tofmetry.pipelines import save_calibration
    from tofmetry.pipelines.frame_path import identity_calibration
    from tofmetry.sensor import KINECT_V2, CameraIntrinsics
    from tofmetry.study import StudyConfig, config_to_toml

    root = tmp_path_factory.mktemp("fuzz-seeds")
    rng = np.random.default_rng(0)
    small = CameraIntrinsics(32, 24, 30.0, 30.0, 15.5, 11.5, (0.1, -0.2, 0.0, 0.0, 0.05))
    depth = rng.integers(500, 4000, size=(24, 32)).astype(np.uint16)
    import cv2

    s = {"png": cv2.imencode(".png", depth)[1].tobytes(), "tiff": cv2.imencode(".tif", depth)[1].tobytes()}
    import io

    buf = io.BytesIO()
    np.save(buf, depth)
    s["npy"] = buf.getvalue()
    write_capture(root / "cap", [depth, depth], __import__("tofmetry.io", fromlist=["CaptureMeta"]).CaptureMeta(
        sensor="unknown", intrinsics=small))
    s["capture.json"] = (root / "cap" / "capture.json").read_bytes()
    write_intrinsics(root / "intrinsics.json", KINECT_V2.depth, rms_px=0.1)
    s["intrinsics.json"] = (root / "intrinsics.json").read_bytes()
    save_calibration(root / "cal.npz", identity_calibration(small))
    s["calibration"] = (root / "cal.npz").read_bytes()
    pts = rng.normal(size=(50, 3))
    write_ply(root / "a.ply", pts, colors=(rng.random((50, 3)) * 255).astype(np.uint8),
              faces=np.array([[0, 1, 2], [2, 3, 4]]), scalars={"deviation_mm": rng.normal(size=50)})
    s["ply"] = (root / "a.ply").read_bytes()
    s["ply_ascii"] = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n" \
                     b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    write_e57(root / "a.e57", pts, scalars={"deviation_mm": rng.normal(size=50)})
    s["e57"] = (root / "a.e57").read_bytes()
    s["study.toml"] = config_to_toml(StudyConfig()).encode()
    spec = BoardSpec(5, 7, 30.0)
    s["board.json"] = json.dumps({"cols": 5, "rows": 7, "square_mm": 30.0, "sensor": "unknown"}).encode()
    write_corners(root / "corners.json", rng.random((35, 2)) * 20, spec)
    s["corners.json"] = (root / "corners.json").read_bytes()
    s["tum"] = b"# timestamp filename\n1.0 depth/1.0.png\n2.0 depth/2.0.png\n"
    s["open3d"] = json.dumps({"width": 32, "height": 24, "intrinsic_matrix": [30, 0, 0, 0, 30, 0, 15.5, 11.5, 1]}).encode()
    cal_dir = SHARED / "kinect2-device-calibrations"
    yamls = sorted(cal_dir.rglob("calib_ir.yaml")) if cal_dir.is_dir() else []
    if yamls:
        s["calib_ir.yaml"] = yamls[0].read_bytes()
        dep = sorted(cal_dir.rglob("calib_depth.yaml"))
        s["calib_depth.yaml"] = dep[0].read_bytes() if dep else b"%YAML:1.0\n---\ndepthShift: -12.5\n"
    else:
        from tofmetry.io.iai_kinect2 import format_opencv_yaml

        s["calib_ir.yaml"] = format_opencv_yaml({"cameraMatrix": KINECT_V2.depth.K, "distortionCoefficients":
                                                 KINECT_V2.depth.dist_array.reshape(1, 5)}).encode()
        s["calib_depth.yaml"] = b"%YAML:1.0\n---\ndepthShift: -12.5\n"
    pts_yaml = SHARED / "kinect2-board-recording" / "0000_ir_points.yaml"
    s["ir_points.yaml"] = pts_yaml.read_bytes() if pts_yaml.is_file() else b"%YAML:1.0\n---\npoints: [1., 2., 3., 4.]\n"
    mkv = SHARED / "azure-kinect-recording" / "recording.mkv"
    s["mkv"] = mkv.read_bytes() if mkv.is_file() else None
    s["depth16"] = depth
    s["root"] = root
    return s


def _fresh(tmp_path_factory, name: str) -> Path:
    d = Path(tmp_path_factory.mktemp(name, numbered=True))
    return d


# ----------------------------------------------------------------------------- readers
@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz-work")


def _clean(d: Path) -> Path:
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    return d


@pytest.mark.parametrize("fmt", ["png", "tiff", "npy"])
def test_depth_images(seeds, work, fmt):
    from tofmetry.io.images import read_depth_image, read_gray_image, read_ir_image

    suffix = {"png": ".png", "tiff": ".tif", "npy": ".npy"}[fmt]
    f = work / f"frame{suffix}"

    @FUZZ
    @given(mutated(seeds[fmt]))
    def run(data):
        f.write_bytes(data)
        check(lambda: read_depth_image(f), f)
        check(lambda: read_depth_image(f, as_float=True), f)
        check(lambda: read_gray_image(f), f)
        check(lambda: read_ir_image(f), f)

    run()


def test_capture_folder(seeds, work):
    from tofmetry.io import Capture

    cap = work / "cap"

    @FUZZ
    @given(mutated(seeds["capture.json"], text=True), mutated(seeds["png"]), st.booleans())
    def run(meta, frame, keep_meta):
        _clean(cap)
        shutil.copytree(seeds["root"] / "cap", cap, dirs_exist_ok=True)
        if not keep_meta:
            (cap / "capture.json").write_bytes(meta)
        (cap / "depth" / "000001.png").write_bytes(frame)

        def read():
            c = Capture(cap)
            c.intrinsics()
            for i in range(len(c)):
                c.depth(i)
            c.timestamps_s

        check(read, cap / "x")

    run()


def test_intrinsics_json(seeds, work):
    from tofmetry.io import read_intrinsics

    f = work / "intrinsics.json"

    @FUZZ
    @given(mutated(seeds["intrinsics.json"], text=True))
    def run(data):
        f.write_bytes(data)
        check(lambda: read_intrinsics(f), f)

    run()


def test_calibration_file(seeds, work):
    from tofmetry.pipelines import load_calibration

    f = work / "cal.npz"

    @FUZZ
    @given(mutated(seeds["calibration"]))
    def run(data):
        f.write_bytes(data)
        check(lambda: load_calibration(f), f)

    run()


def test_calibration_header(seeds, work):
    """Structure-aware: a valid container whose JSON header is mutated."""
    from tofmetry.io.calibration_file import read_calibration_file
    from tofmetry.pipelines import load_calibration

    head, arrays = read_calibration_file(seeds["root"] / "cal.npz")
    text = json.dumps(head).encode()
    f = work / "calh.npz"

    @FUZZ
    @given(mutated(text, text=True))
    def run(data):
        np.savez(f, header=np.array(data.decode("utf-8", "replace")), **arrays)
        check(lambda: load_calibration(f), f)

    run()


@pytest.mark.parametrize("which", ["calib_ir.yaml", "calib_depth.yaml", "ir_points.yaml"])
def test_iai_yaml(seeds, work, which):
    from tofmetry.io.iai_kinect2 import read_calib_depth, read_calib_ir, read_ir_points

    f = work / which
    reader = {"calib_ir.yaml": read_calib_ir, "calib_depth.yaml": read_calib_depth,
              "ir_points.yaml": lambda p: read_ir_points(p, (5, 7))}[which]

    @FUZZ
    @given(mutated(seeds[which], text=True))
    def run(data):
        f.write_bytes(data)
        check(lambda: reader(f), f)

    run()


def test_board_dataset(seeds, work):
    from tofmetry.io.board_dataset import BoardDataset

    ds = work / "board"

    @FUZZ
    @given(mutated(seeds["board.json"], text=True), mutated(seeds["corners.json"], text=True))
    def run(board, corners):
        _clean(ds)
        (ds / "board.json").write_bytes(board)
        shutil.copytree(seeds["root"] / "cap", ds / "poses" / "0000")
        (ds / "poses" / "0000" / "corners.json").write_bytes(corners)

        def read():
            b = BoardDataset(ds)
            for i in range(len(b)):
                b.corners(i)
                b.capture(i)
            b.intrinsics()

        check(read, ds / "board.json")

    run()


def test_tum_folder(seeds, work):
    from tofmetry.io.tum import import_tum

    root, out = work / "tum", work / "tum-out"

    @FUZZ
    @given(mutated(seeds["tum"], text=True))
    def run(listing):
        _clean(root)
        (root / "depth").mkdir()
        for t in ("1.0", "2.0"):
            (root / "depth" / f"{t}.png").write_bytes(seeds["png"])
        (root / "depth.txt").write_bytes(listing)
        if out.exists():
            shutil.rmtree(out)
        check(lambda: import_tum(root, out), root / "depth.txt")

    run()


def test_open3d_folder(seeds, work):
    from tofmetry.io.open3d_rgbd import import_open3d

    root, out = work / "o3d", work / "o3d-out"

    @FUZZ
    @given(mutated(seeds["open3d"], text=True), mutated(seeds["png"]))
    def run(intr, frame):
        _clean(root)
        (root / "depth").mkdir()
        (root / "depth" / "000000.png").write_bytes(seeds["png"])
        (root / "depth" / "000001.png").write_bytes(frame)
        (root / "camera_intrinsic.json").write_bytes(intr)
        if out.exists():
            shutil.rmtree(out)
        check(lambda: import_open3d(root, out), root / "x")

    run()


@pytest.mark.parametrize("fmt", ["ply", "ply_ascii"])
def test_ply(seeds, work, fmt):
    from tofmetry.io.mesh import read_geometry
    from tofmetry.io.ply import read_ply

    f = work / "a.ply"

    @FUZZ
    @given(mutated(seeds[fmt], text=fmt == "ply_ascii"))
    def run(data):
        f.write_bytes(data)
        check(lambda: read_ply(f), f)
        check(lambda: read_geometry(f, "model"), f)

    run()


def test_e57(seeds, work):
    pytest.importorskip("pye57")
    from tofmetry.io.e57 import read_e57

    f = work / "a.e57"

    @FUZZ
    @given(mutated(seeds["e57"]))
    def run(data):
        f.write_bytes(data)
        check(lambda: read_e57(f), f)

    run()


def test_mkv(seeds, work):
    pytest.importorskip("av")
    if seeds["mkv"] is None:
        pytest.skip("no Azure Kinect recording in shared/data")
    from tofmetry.io.azure_kinect import import_azure_kinect

    f, out = work / "rec.mkv", work / "mkv-out"
    head = seeds["mkv"][:200_000]         # the header, the attachments and the first clusters

    @settings(FUZZ, max_examples=EXAMPLES if EXAMPLES > 200 else max(10, EXAMPLES // 3))
    @given(edits())
    def run(mutation):
        f.write_bytes(apply(head, mutation))
        if out.exists():
            shutil.rmtree(out)
        check(lambda: import_azure_kinect(f, out, max_frames=2), f)

    run()


def test_study_config(seeds, work):
    from tofmetry.study import load_config

    f = work / "study.toml"

    @FUZZ
    @given(mutated(seeds["study.toml"], text=True))
    def run(data):
        f.write_bytes(data)
        check(lambda: load_config(f), f)

    run()
