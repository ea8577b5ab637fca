"""Reading images for detection: any file a camera or renderer writes -> 8-bit grey.

png/jpg/bmp/tif, 8/16-bit or float, grey or colour. A file that cannot be read gives a
reason instead of an image (the caller skips and counts it); nothing here raises for a
bad file.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import cv2
import numpy as np


def read_gray(path: str | Path) -> tuple[np.ndarray | None, str | None]:
    """8-bit grey image of a file, or (None, reason). Never raises for a bad file.

    16-bit and float images are scaled by their maximum (a 12-bit sensor in a 16-bit
    container keeps its contrast); colour is converted with OpenCV's luma weights."""
    try:
        buf = np.fromfile(str(path), dtype=np.uint8)
    except FileNotFoundError:
        return None, "file not found (broken link?)"
    except OSError as e:
        return None, f"cannot read ({e.strerror or e})"
    if buf.size == 0:
        return None, "empty file"
    if buf[:8].tobytes() == PNG_SIGNATURE:
        problem = png_problem(buf.data)
        if problem is not None:
            return None, problem
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    except cv2.error:
        img = None
    finally:
        cv2.utils.logging.setLogLevel(level)
    if img is None or img.size == 0:
        return None, "not a readable image (truncated or corrupt?)"
    return to_gray8(img), None


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_problem(data: memoryview | bytes) -> str | None:
    """Why libpng would refuse this PNG file, or None. Checked before decoding because
    libpng reports a truncated or damaged file on the process's stderr by itself (one
    'libpng error' line per image, past any logging setting), and the file is skipped
    with a warning anyway. Walks the chunks up to IEND: each must be whole, and a
    critical one (upper-case first letter) must match its CRC; libpng only warns about
    and drops a damaged ancillary chunk."""
    data = memoryview(data).cast("B")
    pos, n = len(PNG_SIGNATURE), len(data)
    while pos + 12 <= n:
        length = int.from_bytes(data[pos:pos + 4], "big")
        end = pos + 12 + length
        if end > n:
            break
        kind = bytes(data[pos + 4:pos + 8])
        critical = not kind[0] & 0x20
        if critical and zlib.crc32(data[pos + 4:end - 4]) != int.from_bytes(data[end - 4:end], "big"):
            return f"corrupt PNG (the {kind.decode('latin-1')!r} chunk fails its CRC check)"
        if kind == b"IEND":
            return None
        pos = end
    return "truncated PNG (the file ends before its IEND chunk)"


def to_gray8(img: np.ndarray) -> np.ndarray:
    """Any decoded image (H, W[, C]) of any depth -> uint8 (H, W).

    Signed data (a TIFF of int16 or float with negatives) is stretched from its minimum."""
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        img = img.astype(np.float32)  # cvtColor takes 8U, 16U and 32F only (a float64 colour TIFF)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
            img = cv2.cvtColor(img[:, :, :4] if img.shape[2] > 4 else img, code)
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    f = img.astype(np.float32)
    f[~np.isfinite(f)] = 0
    low = min(float(f.min()), 0.0) if f.size else 0.0
    top = float(f.max()) - low if f.size else 0.0
    if top <= 0:
        return np.zeros(img.shape[:2], np.uint8)
    return np.clip((f - low) * (255.0 / top) + 0.5, 0, 255).astype(np.uint8)
