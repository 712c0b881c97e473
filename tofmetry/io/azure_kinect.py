"""Azure Kinect DK recordings (``.mkv`` written by ``k4arecorder``), read with PyAV.

Tracks (identified by their Matroska tags ``K4A_*_TRACK`` / titles):

* ``DEPTH``: rawvideo ``gray16be`` (16-bit big-endian), Z [mm] — decoded to native uint16;
* ``IR``: rawvideo ``gray16be`` amplitude;
* ``COLOR``: MJPG (decoded to RGB);
* attachment ``calibration.json``: factory calibration.

Factory calibration -> tofmetry model
------------------------------------
The JSON holds, per camera, ``ModelParameters`` ``[cx, cy, fx, fy, k1..k6, codx, cody, p2, p1]``
normalised to the raw sensor (depth 1024x1024, colour e.g. 4096x3072), and ``Rt`` (depth -> camera,
metres). As in the Azure Kinect SDK, the mode-specific intrinsics are obtained by scaling to the
binned resolution, subtracting the crop offset and moving to the pixel-centre origin (-0.5).

The lens model is Brown-Conrady *rational* (OpenCV ``k1,k2,p1,p2,k3,k4,k5,k6``): its radial
factor has a denominator (``1 + k4 r^2 + k5 r^4 + k6 r^6``). tofmetry keeps it as it is
(``CameraIntrinsics(model="rational")``): projection and ray tables reproduce OpenCV's rational
model to < 0.01 px over the whole image. For information, the importer still reports what a
5-coefficient Brown refit would cost (``depth_brown_refit_rms_px``; 6.5 px at worst on the real
device). ``codx, cody`` (centre of distortion; 0 on Azure Kinect devices) are dropped.

The sensor identity is ``"azure_kinect"`` (profile registered on import of this module), so a
Kinect v2 calibration is refused for these captures (``DepthCalibration.check_compatible``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from tofmetry.errors import FormatError, InputError
from tofmetry.io._atomic import atomic_write_bytes, atomic_write_json, read_json
from tofmetry.io.capture import CaptureMeta, CaptureWriter
from tofmetry.io.intrinsics_json import read_intrinsics, write_intrinsics
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics
from tofmetry.sensor.profiles import AZURE_KINECT  # noqa: F401  (re-exported: the sensor identity of imports)

SENSOR = "azure_kinect"

# (binned width, binned height), (crop x, crop y), (out width, out height)   -- Azure Kinect SDK tables
DEPTH_MODES = {
    "NFOV_2X2BINNED": ((512, 512), (96, 90), (320, 288)),
    "NFOV_UNBINNED": ((1024, 1024), (192, 180), (640, 576)),
    "WFOV_2X2BINNED": ((512, 512), (0, 0), (512, 512)),
    "WFOV_UNBINNED": ((1024, 1024), (0, 0), (1024, 1024)),
    "PASSIVE_IR": ((1024, 1024), (0, 0), (1024, 1024)),
}
COLOR_MODES = {  # for a 4:3 (4096x3072) colour sensor
    720: ((1280, 960), (0, 120), (1280, 720)),
    1080: ((1920, 1440), (0, 180), (1920, 1080)),
    1440: ((2560, 1920), (0, 240), (2560, 1440)),
    1536: ((2048, 1536), (0, 0), (2048, 1536)),
    2160: ((3840, 2880), (0, 360), (3840, 2160)),
    3072: ((4096, 3072), (0, 0), (4096, 3072)),
}

#: Azure Kinect DK, NFOV unbinned depth (typical values; the factory calibration of each device
#: is in its recordings): 640x576, 75x65 deg, 0.5-3.86 m, 30 fps; colour 1280x720 (720P).
@dataclass(frozen=True)
class AzureCamera:
    """One camera of the factory calibration in a given mode.

    Attributes
    ----------
    intrinsics : the factory lens, rational model (what tofmetry uses).
    rational : (8,) OpenCV rational coefficients ``k1,k2,p1,p2,k3,k4,k5,k6`` (exact).
    refit_rms_px, refit_max_px : what a 5-coefficient Brown refit would cost against the rational
        model [px] (information only: the refit is not used).
    to_depth : Extrinsics depth -> this camera [m] (identity for the depth camera).
    """

    intrinsics: CameraIntrinsics
    rational: np.ndarray
    refit_rms_px: float
    refit_max_px: float
    to_depth: Extrinsics
    dropped: tuple[str, ...]


def _camera_json(calib: dict, purpose: str, source: str) -> dict:
    try:
        cams = calib["CalibrationInformation"]["Cameras"]
    except (KeyError, TypeError):
        raise FormatError(f"{source}: expected CalibrationInformation.Cameras (Azure Kinect calibration.json)") from None
    for c in cams:
        if c.get("Purpose") == purpose:
            return c
    raise FormatError(f"{source}: no camera with Purpose {purpose!r}")


def brown_from_rational(K: np.ndarray, rational: np.ndarray, size: tuple[int, int], max_radius: float | None = None):
    """Least-squares 5-coefficient Brown model matching a rational model over the image.

    Parameters
    ----------
    K : (3, 3) camera matrix; rational : (8,) ``k1,k2,p1,p2,k3,k4,k5,k6``; size : (W, H).
    max_radius : only pixels whose undistorted normalised radius is below this are used.

    Returns
    -------
    dist5 : (5,) ; rms_px, max_px : float, reprojection difference over the used pixels.
    """
    W, H = size
    uu, vv = np.meshgrid(np.linspace(0, W - 1, 64), np.linspace(0, H - 1, 58))
    uv = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, rational, criteria=crit).reshape(-1, 2)
    # keep points that the rational model maps back onto their pixel (valid region of the inverse)
    back = cv2.projectPoints(np.column_stack([xy, np.ones(len(xy))]), np.zeros(3), np.zeros(3), K, rational)[0].reshape(-1, 2)
    ok = np.linalg.norm(back - uv, axis=1) < 0.01
    if max_radius is not None:
        ok &= np.hypot(xy[:, 0], xy[:, 1]) < max_radius
    x, y = xy[ok, 0], xy[ok, 1]
    tgt = (uv[ok] - K[:2, 2]) / np.array([K[0, 0], K[1, 1]])    # distorted normalised
    r2 = x * x + y * y
    # x_d - x = x(k1 r2 + k2 r4 + k3 r6) + 2 p1 x y + p2 (r2 + 2x^2); same for y
    Ax = np.column_stack([x * r2, x * r2 ** 2, 2 * x * y, r2 + 2 * x * x, x * r2 ** 3])
    Ay = np.column_stack([y * r2, y * r2 ** 2, r2 + 2 * y * y, 2 * x * y, y * r2 ** 3])
    A = np.vstack([Ax * K[0, 0], Ay * K[1, 1]])
    b = np.concatenate([(tgt[:, 0] - x) * K[0, 0], (tgt[:, 1] - y) * K[1, 1]])
    d, *_ = np.linalg.lstsq(A, b, rcond=None)
    res = (A @ d - b).reshape(2, -1)
    err = np.hypot(res[0], res[1])
    return d, float(np.sqrt(np.mean(err ** 2))), float(err.max())


def _mode_camera(cam: dict, binned, crop, out, source: str, max_radius: float | None) -> tuple[CameraIntrinsics, np.ndarray, float, float]:
    p = np.asarray(cam["Intrinsics"]["ModelParameters"], dtype=np.float64)
    if p.size < 14:
        raise FormatError(f"{source}: expected 14 ModelParameters, found {p.size}")
    cx = p[0] * binned[0] - crop[0] - 0.5
    cy = p[1] * binned[1] - crop[1] - 0.5
    fx, fy = p[2] * binned[0], p[3] * binned[1]
    k1, k2, k3, k4, k5, k6 = p[4:10]
    p2, p1 = p[12], p[13]
    rational = np.array([k1, k2, p1, p2, k3, k4, k5, k6])
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    d5, rms, mx = brown_from_rational(K, rational, out, max_radius)
    return CameraIntrinsics(out[0], out[1], fx, fy, cx, cy, tuple(rational), "rational"), rational, rms, mx


def parse_calibration(calib: dict, depth_mode: str, color_height: int | None, source: str = "calibration.json") -> dict:
    """Factory calibration -> ``{"depth": AzureCamera, "color": AzureCamera | None}`` for the recording's modes."""
    if depth_mode not in DEPTH_MODES:
        raise FormatError(f"{source}: unsupported depth mode {depth_mode!r} (known: {sorted(DEPTH_MODES)})")
    dcam = _camera_json(calib, "CALIBRATION_CameraPurposeDepth", source)
    binned, crop, out = DEPTH_MODES[depth_mode]
    mr = float(dcam.get("MetricRadius", 0)) or None
    intr, rat, rms, mx = _mode_camera(dcam, binned, crop, out, source, mr)
    dropped = ("codx, cody (centre of distortion)",)
    res = {"depth": AzureCamera(intr, rat, rms, mx, Extrinsics.identity("depth", "depth"), dropped), "color": None}
    if color_height:
        ccam = _camera_json(calib, "CALIBRATION_CameraPurposePhotoVideo", source)
        if color_height not in COLOR_MODES:
            raise FormatError(f"{source}: unsupported colour resolution {color_height}p")
        if ccam["SensorWidth"] * 3 != ccam["SensorHeight"] * 4:
            raise FormatError(f"{source}: colour sensor {ccam['SensorWidth']}x{ccam['SensorHeight']} is not 4:3")
        cb, cc, co = COLOR_MODES[color_height]
        cintr, crat, crms, cmx = _mode_camera(ccam, cb, cc, co, source, None)
        rt = ccam["Rt"]
        ext = Extrinsics(np.asarray(rt["Rotation"], float).reshape(3, 3), np.asarray(rt["Translation"], float), "depth", "color")
        res["color"] = AzureCamera(cintr, crat, crms, cmx, ext, dropped)
    return res


# ----------------------------------------------------------------------------- MKV
@dataclass
class AzureRecording:
    """Decoded recording.

    Attributes
    ----------
    depth : (T, H, W) uint16 [mm]; ir : (T, H, W) uint16 or None; color : list of (Hc, Wc, 3) uint8 RGB or None
    timestamps_s : (T,) device timestamps [s]; calibration : dict (calibration.json); tags : container tags
    depth_mode : e.g. "NFOV_UNBINNED"; color_height : e.g. 720 or None
    """

    depth: np.ndarray
    ir: np.ndarray | None
    color: list | None
    timestamps_s: np.ndarray
    calibration: dict
    tags: dict
    depth_mode: str
    color_height: int | None


def _find_track(container, key: str):
    for s in container.streams:
        md = {k.upper(): v for k, v in (s.metadata or {}).items()}
        if f"K4A_{key}_TRACK" in md or md.get("TITLE") == key:
            return s
    return None


@dataclass(frozen=True)
class AzureInfo:
    """What :func:`probe_azure_mkv` finds without decoding frames."""

    path: Path
    calibration: dict
    tags: dict
    depth_mode: str
    color_height: int | None
    depth_index: int
    ir_index: int | None
    color_index: int | None


def _damaged(path, exc) -> FormatError:
    msg = " ".join(str(exc).split())[:200]
    return FormatError(f"{path}: not a readable Azure Kinect recording ({type(exc).__name__}: {msg})")


def _guarded(fn):
    """Turn any error a damaged recording provokes in PyAV, json or the calibration parser into a
    FormatError naming the file (found by fuzzing: bad attachments, undecodable tags, broken streams)."""
    import functools

    @functools.wraps(fn)
    def wrapper(path, *args, **kwargs):
        import av

        try:
            return fn(path, *args, **kwargs)
        except (FormatError, InputError):
            raise
        except (av.error.FFmpegError, ValueError, KeyError, TypeError, IndexError, AttributeError, OSError,
                cv2.error, np.linalg.LinAlgError, ZeroDivisionError, OverflowError) as exc:
            raise _damaged(path, exc) from None

    return wrapper


@_guarded
def probe_azure_mkv(path: str | os.PathLike) -> AzureInfo:
    """Open an Azure Kinect ``.mkv`` and check its tracks and calibration attachment.

    Raises
    ------
    FormatError
        Not a Matroska file PyAV can open, no depth track, depth not 16-bit, no calibration.
    """
    import av

    path = Path(path)
    if not path.is_file():
        raise InputError(f"Azure Kinect recording not found: {path}")
    try:
        c = av.open(str(path))
    except (av.error.FFmpegError, OSError) as exc:
        raise FormatError(f"{path}: not a readable Matroska/MKV file ({exc})") from None
    with c:
        tags = dict(c.metadata or {})
        dst = _find_track(c, "DEPTH")
        if dst is None:
            raise FormatError(f"{path}: no depth track (expected a video track tagged K4A_DEPTH_TRACK / titled DEPTH); "
                              f"tracks: {[(s.type, (s.metadata or {}).get('title')) for s in c.streams]}")
        pix = dst.codec_context.pix_fmt
        if pix not in ("gray16be", "gray16le"):
            raise FormatError(f"{path}: depth track has pixel format {pix!r}, expected 16-bit greyscale (gray16be)")
        depth_mode = {k.upper(): v for k, v in dst.metadata.items()}.get("K4A_DEPTH_MODE", "NFOV_UNBINNED")
        irs = _find_track(c, "IR")
        cst = _find_track(c, "COLOR")
        calib = None
        for s in c.streams:
            if s.type == "attachment" and (s.name == "calibration.json" or (s.metadata or {}).get("filename") == "calibration.json"):
                calib = json.loads(bytes(s.data).decode())
        if calib is None:
            raise FormatError(f"{path}: no calibration.json attachment (factory calibration)")
        return AzureInfo(path, calib, tags, depth_mode, cst.codec_context.height if cst is not None else None,
                         dst.index, irs.index if irs is not None else None, cst.index if cst is not None else None)


def iter_azure_frames(info: AzureInfo, max_frames: int | None = None):
    """Stream synchronised frames in one demux pass.

    Yields
    ------
    (t_s, depth (H,W) uint16 [mm], ir (H,W) uint16 or None, color (Hc,Wc,3) uint8 RGB or None)

    Frames of one capture share a timestamp in k4arecorder files; a track missing at a
    timestamp takes its most recent frame (IR/colour stay aligned in count with depth).
    """
    import av

    kinds = {info.depth_index: "depth"}
    if info.ir_index is not None:
        kinds[info.ir_index] = "ir"
    if info.color_index is not None:
        kinds[info.color_index] = "color"
    pending: dict[float, dict] = {}
    last: dict[str, np.ndarray] = {}
    n = 0

    def complete(entry):
        return all(k in entry for k in kinds.values())

    def emit(t, entry):
        for k in ("ir", "color"):
            if k in entry:
                last[k] = entry[k]
        return (t, entry["depth"], entry.get("ir", last.get("ir")), entry.get("color", last.get("color")))

    with av.open(str(info.path)) as c:
        streams = [c.streams[i] for i in kinds]
        for pkt in c.demux(streams):
            kind = kinds.get(pkt.stream.index)
            if kind is None:
                continue
            for fr in pkt.decode():
                t = float(fr.time) if fr.time is not None else float(n)
                arr = fr.to_ndarray(format="rgb24") if kind == "color" else np.asarray(fr.to_ndarray(), np.uint16)
                pending.setdefault(t, {})[kind] = arr
                ready = sorted(tt for tt, e in pending.items() if complete(e))
                for tt in ready:
                    # everything older than a complete timestamp will not be completed any more
                    for old in sorted(x for x in pending if x < tt):
                        e = pending.pop(old)
                        if "depth" in e:
                            yield emit(old, e)
                            n += 1
                            if max_frames is not None and n >= max_frames:
                                return
                    yield emit(tt, pending.pop(tt))
                    n += 1
                    if max_frames is not None and n >= max_frames:
                        return
        for t in sorted(pending):
            e = pending[t]
            if "depth" in e:
                yield emit(t, e)
                n += 1
                if max_frames is not None and n >= max_frames:
                    return


@_guarded
def read_azure_mkv(path: str | os.PathLike, max_frames: int | None = None) -> AzureRecording:
    """Decode an Azure Kinect ``.mkv`` into memory (short recordings; :func:`import_azure_kinect` streams).

    Raises
    ------
    FormatError
        See :func:`probe_azure_mkv`; also a depth track without frames.
    """
    info = probe_azure_mkv(path)
    frames = list(iter_azure_frames(info, max_frames))
    if not frames:
        raise FormatError(f"{info.path}: the depth track holds no frames")
    ts = np.array([f[0] for f in frames])
    depth = np.stack([f[1] for f in frames])
    ir = np.stack([f[2] for f in frames]) if info.ir_index is not None and frames[0][2] is not None else None
    color = [f[3] for f in frames] if info.color_index is not None and frames[0][3] is not None else None
    return AzureRecording(depth, ir, color, ts, info.calibration, info.tags, info.depth_mode, info.color_height)


@_guarded
def import_azure_kinect(src: str | os.PathLike, out: str | os.PathLike, force: bool = False,
                        max_frames: int | None = None, progress=None) -> dict:
    """Write an Azure Kinect ``.mkv`` as a capture folder (sensor ``azure_kinect``).

    Besides the contract files the folder holds ``azure_calibration.json`` (the factory file),
    ``color_intrinsics.json`` and ``extrinsics.json`` (depth -> colour, [m]).
    """
    src = Path(src)
    info = probe_azure_mkv(src)
    cams = parse_calibration(info.calibration, info.depth_mode, info.color_height, f"{src} calibration.json")
    d, c = cams["depth"], cams["color"]
    azure = {"depth_mode": info.depth_mode, "color_height": info.color_height,
             "serial": info.tags.get("K4A_DEVICE_SERIAL_NUMBER"), "source": str(src),
             "depth_rational_distortion": d.rational, "depth_brown_refit_rms_px": d.refit_rms_px,
             "depth_brown_refit_max_px": d.refit_max_px, "dropped": list(d.dropped)}
    if c is not None:
        azure.update({"color_intrinsics": c.intrinsics.to_dict(), "color_rational_distortion": c.rational,
                      "color_brown_refit_rms_px": c.refit_rms_px, "depth_to_color": c.to_depth.to_dict()})
    meta = CaptureMeta(sensor=SENSOR, intrinsics=d.intrinsics, timestamps_s=[], extra={"azure": azure})
    with CaptureWriter(out, meta, force=force) as w:
        for t, depth, ir, color in iter_azure_frames(info, max_frames):
            if depth.shape != d.intrinsics.shape:
                raise FormatError(f"{src}: depth frames are {depth.shape[1]}x{depth.shape[0]}, the {info.depth_mode} "
                                  f"calibration is {d.intrinsics.width}x{d.intrinsics.height}")
            w.add(depth, ir=ir, color=color)
            meta.timestamps_s.append(float(t))
            if progress is not None:
                progress()
        if w.n == 0:
            raise FormatError(f"{src}: the depth track holds no frames")
        # side files go into the staging folder: they appear together with the capture
        atomic_write_bytes(w.staging / "azure_calibration.json", json.dumps(info.calibration, indent=1).encode())
        if c is not None:
            write_intrinsics(w.staging / "color_intrinsics.json", c.intrinsics, sensor=SENSOR)
            atomic_write_json(w.staging / "extrinsics.json", c.to_depth.to_dict())
    notes = [f"depth lens: factory rational model kept (a Brown refit would cost {d.refit_rms_px:.3f} px RMS, "
             f"max {d.refit_max_px:.3f} px); dropped: {'; '.join(d.dropped)}"]
    if c is not None:
        notes.append(f"colour lens: factory rational model kept (a Brown refit would cost {c.refit_rms_px:.3f} px RMS, "
                     f"max {c.refit_max_px:.3f} px)")
    return {"frames": int(w.n), "depth_mode": info.depth_mode, "color": info.color_index is not None,
            "sensor": SENSOR, "notes": notes}


def import_azure_kinect_cli(src, out, *, force: bool = False, progress=None, max_frames: int | None = None,
                            **_ignored) -> dict:
    """Registry entry for :func:`import_azure_kinect`."""
    return import_azure_kinect(src, out, force=force, max_frames=max_frames, progress=progress)


def load_capture_calibration(capture_path: str | os.PathLike) -> tuple[CameraIntrinsics, Extrinsics]:
    """Colour intrinsics and depth -> colour extrinsics stored beside an imported capture."""
    p = Path(capture_path)
    if not (p / "color_intrinsics.json").is_file():
        raise InputError(f"{p}: no color_intrinsics.json (not an imported Azure Kinect capture with colour)")
    ext = Extrinsics.from_dict(read_json(p / "extrinsics.json"), source_name=str(p / "extrinsics.json"))
    return read_intrinsics(p / "color_intrinsics.json"), ext
