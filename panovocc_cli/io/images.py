"""PNG/JPEG/EXR images with validation: a bad file is one clear :class:`PanovoccError` line."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from .atomic import atomic_path


def _cv2():
    import cv2

    return cv2


def read_exr(path: str | Path) -> np.ndarray:
    """First channel of an OpenEXR file as (H, W) float32 (Holo360D's depth form: metres).

    Channels are tried in the order Z, R, Y, then the first one stored.
    """
    import OpenEXR

    path = Path(path)
    try:
        with OpenEXR.File(str(path)) as f:
            chans = f.channels()
            name = next((c for c in ("Z", "R", "Y", "depth") if c in chans), None) or sorted(chans)[0]
            arr = np.asarray(chans[name].pixels)
    except Exception as e:  # OpenEXR raises plain exceptions on corrupt files
        raise PanovoccError(f"cannot decode EXR ({e})", path) from None
    if arr.ndim == 3:
        arr = arr[..., 0]
    return arr.astype(np.float32)


def write_exr(path: str | Path, depth: np.ndarray) -> None:
    """Atomically write (H, W) float32 as a one-channel (Z) OpenEXR file."""
    import OpenEXR

    with atomic_path(path, suffix=".exr") as tmp:
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        with OpenEXR.File(header, {"Z": np.ascontiguousarray(depth, dtype=np.float32)}) as f:
            f.write(str(tmp))


def read_image(path: str | Path, flags: str = "color") -> np.ndarray:
    """Read an image file.

    Parameters
    ----------
    flags : ``"color"`` (RGB uint8, (H, W, 3)) or ``"unchanged"`` (as stored: uint16 stays uint16,
        EXR gives float32).
    """
    cv2 = _cv2()
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("file not found", path)
    if path.suffix.lower() == ".exr":
        return read_exr(path)
    flag = cv2.IMREAD_COLOR if flags == "color" else cv2.IMREAD_UNCHANGED
    # cv2.imread takes a str path and crashes (SIGSEGV) on names that are not valid UTF-8: read the bytes
    # ourselves (any path the OS accepts) and decode them in memory.
    data = np.fromfile(path, dtype=np.uint8)
    if data[:8].tobytes() == PNG_SIGNATURE:
        check_png_chunks(data.tobytes(), path)  # libpng would print its own line to stderr on a corrupt file
    img = cv2.imdecode(data, flag) if data.size else None
    if img is None:
        raise PanovoccError("cannot decode image (corrupt or unsupported file; expected PNG, JPEG or EXR)", path)
    if flags == "color":
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return img


def write_png(path: str | Path, image: np.ndarray, compression: int = 1) -> None:
    """Atomically write a PNG: (H, W) uint8/uint16 or (H, W, 3) uint8 RGB."""
    cv2 = _cv2()
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    params = [cv2.IMWRITE_PNG_COMPRESSION, compression]
    if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # the Sub row filter: about 25% faster than adaptive, same size
        params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB]
    ok, buf = cv2.imencode(".png", img, params)
    if not ok:
        raise PanovoccError("could not encode PNG", path)
    with atomic_path(path, suffix=".png") as tmp:  # bytes written by Python: any path the OS accepts
        with open(tmp, "wb") as f:
            f.write(buf.tobytes())


def _is_greyscale(head: bytes) -> bool:
    """Whether an image file's first bytes say it has no colour: a PNG of colour type 0 or 4 (grey, grey +
    alpha; a palette image is colour), or a JPEG whose frame header (SOF) has one component."""
    if head[:8] == PNG_SIGNATURE:
        return len(head) > 25 and head[25] in (0, 4)
    if head[:2] != b"\xff\xd8":
        return False
    pos = 2
    while pos + 9 < len(head):
        if head[pos] != 0xFF:
            return False
        marker = head[pos + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7 or marker == 0xFF:
            pos += 1 if marker == 0xFF else 2
            continue
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # start of frame: its component count
            return head[pos + 9] == 1
        pos += 2 + int.from_bytes(head[pos + 2:pos + 4], "big")
    return False


def check_colour(path: str | Path) -> None:
    """Refuse an image that is greyscale where a colour (RGB) image is expected (:func:`_is_greyscale`; only
    the file's first 64 KiB are read)."""
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except FileNotFoundError:
        raise PanovoccError("file not found", path) from None
    if _is_greyscale(head):
        raise PanovoccError("image is greyscale; expected a colour (RGB) image", path)


def read_rgb(path: str | Path, shape: tuple[int, int] | None = None) -> np.ndarray:
    """RGB image (H, W, 3) uint8; ``shape`` = (H, W) is checked when given. A greyscale file is refused
    (:func:`check_colour`): colour is expected, and a grey one is most likely another modality's image."""
    check_colour(path)
    img = read_image(path, "color")
    if shape is not None and img.shape[:2] != tuple(shape):
        raise PanovoccError(f"image is {img.shape[1]}x{img.shape[0]}, expected {shape[1]}x{shape[0]}", path)
    return img


def read_depth(path: str | Path, depth_scale: float, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Depth map (H, W) float32 metres from a uint16 PNG (value / depth_scale) or float EXR (metres).

    0 means no measurement. NaN, infinite or negative depth is an error.
    """
    img = read_image(path, "unchanged")
    if img.ndim == 3:
        img = img[..., 0]
    if img.dtype == np.uint16:
        depth = img.astype(np.float32) / np.float32(depth_scale)
    elif img.dtype in (np.float32, np.float64):
        depth = img.astype(np.float32)
        if not np.all(np.isfinite(depth)):
            raise PanovoccError("depth has NaN or infinite values (expected metres, 0 = no measurement)", path)
        if (depth < 0).any():
            raise PanovoccError("depth has negative values (expected metres, 0 = no measurement)", path)
    else:
        raise PanovoccError(f"depth image has dtype {img.dtype}, expected uint16 PNG or float EXR", path)
    if shape is not None and depth.shape != tuple(shape):
        raise PanovoccError(f"depth is {depth.shape[1]}x{depth.shape[0]}, expected {shape[1]}x{shape[0]}", path)
    return depth


def depth_to_uint16(depth: np.ndarray, depth_scale: float) -> np.ndarray:
    """Encode metres as uint16 ``round(depth * depth_scale)``; 0 and out-of-range become 0."""
    d = np.asarray(depth, dtype=np.float64) * depth_scale
    d = np.where(np.isfinite(d) & (d > 0) & (d < 65535.5), np.round(d), 0)
    return d.astype(np.uint16)


def read_labels(path: str | Path, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Class-id image (H, W) int64 from a uint8/uint16 PNG."""
    img = read_image(path, "unchanged")
    if img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
        raise PanovoccError(f"label image must be single-channel uint8/uint16, got {img.dtype} {img.shape}", path)
    if shape is not None and img.shape != tuple(shape):
        raise PanovoccError(f"labels are {img.shape[1]}x{img.shape[0]}, expected {shape[1]}x{shape[0]}", path)
    return img.astype(np.int64)


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_COLOR_TYPES = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # colour type -> channels as decoded (palette: 1 index)


def png_header(path: str | Path) -> tuple[int, int, int, int]:
    """(width, height, bit depth, channels) from a PNG's IHDR chunk (its first 33 bytes and last 12 read, to
    also catch a truncated file; nothing decoded).

    Raises :class:`PanovoccError` naming the file when it is missing or not a PNG.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(33)
            f.seek(max(0, f.seek(0, os.SEEK_END) - 12))
            tail = f.read(12)
    except FileNotFoundError:
        raise PanovoccError("file not found", path) from None
    if len(head) < 33 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise PanovoccError("not a PNG file (bad signature or header; corrupt or truncated)", path)
    if tail[4:8] != b"IEND":
        raise PanovoccError("PNG is truncated (no IEND chunk at its end)", path)
    w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    depth, ctype = head[24], head[25]
    if ctype not in _PNG_COLOR_TYPES:
        raise PanovoccError(f"PNG colour type {ctype} is invalid (corrupt file)", path)
    return w, h, depth, _PNG_COLOR_TYPES[ctype]


def check_image_header(path: str | Path, role: str, shape: tuple[int, int] | None = None) -> None:
    """Cheap check of a frame image before any work: readable header, size ``shape`` = (H, W), and the
    type its ``role`` needs (``rgb``; ``depth``: 16-bit single channel; ``labels``: 8/16-bit single
    channel; ``rgb``: colour, :func:`check_colour`). Only PNG headers are parsed; JPEG/EXR files are checked for
    existence, non-zero size and (``rgb``) a JPEG's component count."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        try:
            if path.stat().st_size == 0:
                raise PanovoccError("file is empty", path)
        except FileNotFoundError:
            raise PanovoccError("file not found", path) from None
        if role == "rgb":
            check_colour(path)
        return
    w, h, depth, ch = png_header(path)
    if shape is not None and (h, w) != tuple(shape):
        raise PanovoccError(f"{role} image is {w}x{h}, expected {shape[1]}x{shape[0]}", path)
    if role == "depth" and (depth != 16 or ch != 1):
        raise PanovoccError(f"depth PNG is {depth}-bit with {ch} channel(s); expected 16-bit single-channel "
                            "(depth x depth_scale)", path)
    if role == "rgb":
        check_colour(path)
    if role == "labels" and (depth not in (8, 16) or ch != 1):
        raise PanovoccError(f"label PNG is {depth}-bit with {ch} channel(s); expected 8/16-bit single-channel", path)


def check_png_chunks(raw: bytes, path: str | Path) -> None:
    """Walk a PNG's chunks and check each one's length and CRC, so that a corrupt file is one
    :class:`PanovoccError` (libpng would print its own message on stderr before OpenCV gives up)."""
    import zlib

    pos, n = 8, len(raw)
    while pos + 12 <= n:
        length = int.from_bytes(raw[pos:pos + 4], "big")
        end = pos + 12 + length
        if end > n:
            raise PanovoccError(f"PNG is truncated (chunk at byte {pos} runs past the end)", path)
        ctype = raw[pos + 4:pos + 8]
        if zlib.crc32(raw[pos + 4:pos + 8 + length]) != int.from_bytes(raw[pos + 8 + length:end], "big"):
            raise PanovoccError(f"PNG is corrupt (CRC mismatch in chunk {ctype.decode('latin-1')!r} at byte {pos})",
                                path)
        if ctype == b"IEND":
            return
        pos = end
    raise PanovoccError("PNG is truncated (no IEND chunk)", path)
