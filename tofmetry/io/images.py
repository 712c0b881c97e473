"""Reading and writing single depth / IR / colour images (PNG, TIFF, NPY, JPG, BMP, PGM ...).

Every reader returns arrays with the dtype named in its docstring and raises
:class:`~tofmetry.errors.FormatError` naming the file on anything unexpected.
:func:`read_gray_image` reads any single-channel 8- or 16-bit image OpenCV decodes (and
greyscale stored as colour) at its own bit depth: the reader of checkerboard (IR) images.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import cv2
import numpy as np

from tofmetry.errors import FormatError
from tofmetry.io._atomic import atomic_write_bytes

DEPTH_SUFFIXES = (".png", ".tif", ".tiff", ".npy")
#: Suffixes :func:`read_gray_image` accepts (what OpenCV's ``imread`` decodes, plus ``.npy``).
GRAY_IMAGE_SUFFIXES = (".png", ".bmp", ".dib", ".tif", ".tiff", ".pgm", ".pnm", ".ppm", ".pbm", ".jpg", ".jpeg",
                       ".jpe", ".jp2", ".webp", ".npy")
_PNG_SIG = b"\x89PNG\r\n\x1a\n"


def png_header(path: str | os.PathLike) -> tuple[int, int, int, int]:
    """Read a PNG's IHDR without decoding: ``(width, height, bit_depth, colour_type)``."""
    path = Path(path)
    with open(path, "rb") as fh:
        head = fh.read(33)
    if len(head) < 33 or head[:8] != _PNG_SIG or head[12:16] != b"IHDR":
        raise FormatError(f"{path}: not a PNG file (bad signature or truncated header)")
    w, h, bit, ctype = struct.unpack(">IIBB", head[16:26])
    return w, h, bit, ctype


def read_depth_image(path: str | os.PathLike, as_float: bool = False) -> np.ndarray:
    """Read one depth frame.

    Parameters
    ----------
    path : PNG (16-bit grey), TIFF (16-bit) or ``.npy`` (uint16, or float in mm).
    as_float : return (H, W) float32 [mm] without rounding (keeps the precision of float
        ``.npy`` frames, e.g. ``tofmetry correct --float32`` output).

    Returns
    -------
    depth : (H, W) uint16 [mm] (float32 [mm] with ``as_float``), 0 = no measurement.
    """
    path = Path(path)
    if not path.is_file():
        raise FormatError(f"depth frame not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except Exception as exc:  # noqa: BLE001 - any decoding failure is a format error
            raise FormatError(f"{path}: unreadable .npy ({exc})") from None
        if arr.ndim != 2:
            raise FormatError(f"{path}: expected a 2-D depth array, found shape {arr.shape}")
        if arr.dtype == np.uint16:
            return arr.astype(np.float32) if as_float else arr
        if np.issubdtype(arr.dtype, np.floating):
            if not np.all(np.isfinite(arr)):
                raise FormatError(f"{path}: float depth contains NaN/inf; use 0 for invalid pixels")
            if arr.min() < 0 or arr.max() > 65535:
                raise FormatError(f"{path}: float depth outside 0..65535 mm")
            return arr.astype(np.float32) if as_float else np.rint(arr).astype(np.uint16)
        raise FormatError(f"{path}: expected uint16 (mm) depth, found dtype {arr.dtype}")
    if suffix == ".png":
        w, h, bit, ctype = png_header(path)
        if bit != 16 or ctype not in (0, 4):
            raise FormatError(
                f"{path}: expected a 16-bit greyscale PNG (uint16 mm), found bit depth {bit}, colour type {ctype}"
            )
    elif suffix not in (".tif", ".tiff"):
        raise FormatError(f"{path}: unsupported depth format {suffix!r}; use .png, .tif or .npy")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FormatError(f"{path}: unreadable or truncated image")
    if img.ndim != 2:
        raise FormatError(f"{path}: expected a single-channel depth image, found shape {img.shape}")
    if img.dtype != np.uint16:
        raise FormatError(f"{path}: expected 16-bit depth (uint16 mm), found {img.dtype}")
    return img.astype(np.float32) if as_float else img


def read_gray_image(path: str | os.PathLike) -> np.ndarray:
    """Read one single-channel image at its own bit depth (IR, grey, checkerboard photos).

    Parameters
    ----------
    path : any image OpenCV's ``imread`` decodes (PNG, BMP, TIFF, PGM/PNM, JPEG, ...; see
        :data:`GRAY_IMAGE_SUFFIXES`) or a 2-D ``.npy``. 8- and 16-bit single-channel images are
        returned as stored; 3-/4-channel images (greyscale saved as colour, e.g. 8-bit BMP or
        JPEG) become one channel (the first when all channels are equal, else the luminance
        ``0.299 R + 0.587 G + 0.114 B``); an alpha channel is dropped.

    Returns
    -------
    (H, W) uint8 or uint16 (float32 for float TIFF / ``.npy``).

    Raises
    ------
    FormatError
        Missing, unreadable or truncated file, or a content that is not one image of 8/16-bit
        (or float) intensities; the message names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise FormatError(f"image not found: {path}")
    if path.suffix.lower() == ".npy":
        try:
            img = np.load(path, allow_pickle=False)
        except Exception as exc:  # noqa: BLE001 - any decoding failure is a format error
            raise FormatError(f"{path}: unreadable .npy ({exc})") from None
    else:
        try:
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        except cv2.error as exc:
            raise FormatError(f"{path}: OpenCV could not decode it ({exc})") from None
        if img is None:
            raise FormatError(f"{path}: unreadable, truncated or not an image format OpenCV decodes "
                              f"(expected one of {', '.join(GRAY_IMAGE_SUFFIXES)})")
    return _as_gray(img, path)


def _as_gray(img: np.ndarray, path: Path) -> np.ndarray:
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        c = img[..., :3]
        if np.array_equal(c[..., 0], c[..., 1]) and np.array_equal(c[..., 0], c[..., 2]):
            img = np.ascontiguousarray(c[..., 0])
        elif c.dtype in (np.uint8, np.uint16, np.float32):
            img = cv2.cvtColor(np.ascontiguousarray(c), cv2.COLOR_BGR2GRAY)
        else:
            raise FormatError(f"{path}: colour image of dtype {img.dtype}; expected 8/16-bit")
    if img.ndim != 2 or img.size == 0:
        raise FormatError(f"{path}: expected a single-channel (H, W) image, found shape {img.shape}")
    if img.dtype in (np.uint8, np.uint16):
        return img
    if img.dtype == bool:
        return img.astype(np.uint8) * 255
    if np.issubdtype(img.dtype, np.floating):
        if not np.all(np.isfinite(img)):
            raise FormatError(f"{path}: float image contains NaN/inf")
        return img.astype(np.float32)
    if np.issubdtype(img.dtype, np.integer):
        lo, hi = int(img.min()), int(img.max())
        if lo >= 0 and hi <= 65535:
            return img.astype(np.uint16)
        raise FormatError(f"{path}: {img.dtype} values {lo}..{hi} do not fit 16 bit (expected 0..65535)")
    raise FormatError(f"{path}: expected 8/16-bit or float intensities, found dtype {img.dtype}")


def read_ir_image(path: str | os.PathLike) -> np.ndarray:
    """Read one IR amplitude frame: (H, W) uint16 (any format of :func:`read_gray_image`;
    8-bit values are promoted unscaled, float values clipped to 0..65535 and rounded)."""
    img = read_gray_image(path)
    if img.dtype == np.float32:
        return np.rint(np.clip(img, 0, 65535)).astype(np.uint16)
    return img.astype(np.uint16, copy=False)


def read_color_image(path: str | os.PathLike) -> np.ndarray:
    """Read a colour image as (H, W, 3) uint8 **RGB**."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FormatError(f"{path}: unreadable or truncated colour image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def encode_png16(img: np.ndarray) -> bytes:
    """Encode a (H, W) uint16 array as a 16-bit PNG."""
    if img.dtype != np.uint16 or img.ndim != 2:
        raise FormatError(f"encode_png16: expected (H, W) uint16, found {img.shape} {img.dtype}")
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise FormatError("PNG encoding failed")
    return buf.tobytes()


def write_png16(path: str | os.PathLike, img: np.ndarray) -> Path:
    """Atomically write a (H, W) uint16 array as 16-bit PNG."""
    return atomic_write_bytes(path, encode_png16(img))


def write_color_jpg(path: str | os.PathLike, rgb: np.ndarray, quality: int = 92) -> Path:
    """Atomically write an (H, W, 3) uint8 RGB image as JPEG."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise FormatError(f"{path}: JPEG encoding failed")
    return atomic_write_bytes(path, buf.tobytes())


def write_png(path: str | os.PathLike, img: np.ndarray) -> Path:
    """Atomically write an 8- or 16-bit image (grey or RGB) as PNG."""
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise FormatError(f"{path}: PNG encoding failed")
    return atomic_write_bytes(path, buf.tobytes())
