"""Pixels from recorded images: ROS `sensor_msgs/Image` encodings, compressed images, focus.

Everything returns what the dataset layout takes (docs/formats.md#dataset): 8-bit grey (H, W) or
8-bit BGR (H, W, 3), the order OpenCV writes. Pure functions over numpy arrays.
"""

from __future__ import annotations

import cv2
import numpy as np

# ROS's bayer names give the colours of the top-left 2x2 block; OpenCV names its conversions
# after the second row's 2nd-3rd pixels, so rggb is OpenCV's BG (cv_bridge's table).
_BAYER = {
    "bayer_rggb8": cv2.COLOR_BayerBG2BGR,
    "bayer_bggr8": cv2.COLOR_BayerRG2BGR,
    "bayer_gbrg8": cv2.COLOR_BayerGR2BGR,
    "bayer_grbg8": cv2.COLOR_BayerGB2BGR,
}
_CHANNELS = {"mono8": 1, "8uc1": 1, "mono16": 1, "16uc1": 1, "bgr8": 3, "rgb8": 3, "8uc3": 3,
             "bgra8": 4, "rgba8": 4, **{k: 1 for k in _BAYER}}
ENCODINGS = tuple(sorted(_CHANNELS))
_COMPRESSED_SUFFIX = {b"\x89PNG": ".png", b"\xff\xd8\xff": ".jpg"}


class EncodingError(ValueError):
    """An image that cannot be turned into pixels; the message says why (the caller adds where)."""


def raw_pixels(encoding: str, height: int, width: int, step: int, is_bigendian: bool, data: np.ndarray
               ) -> np.ndarray:
    """A `sensor_msgs/Image` as 8-bit grey (H, W) or BGR (H, W, 3).

    mono16 is brought to 8 bits by dropping the low bits that its brightest pixel leaves
    unused (a 12-bit sensor in 16-bit words keeps its top 8 bits), so a dark frame is not
    crushed to black; the shift is per image."""
    enc = encoding.lower()
    if enc not in _CHANNELS:
        raise EncodingError(f"image encoding {encoding!r} is not supported (rigcal reads {', '.join(ENCODINGS)})")
    depth = 2 if enc in ("mono16", "16uc1") else 1
    ch = _CHANNELS[enc]
    if height <= 0 or width <= 0 or step < width * ch * depth or len(data) < step * height:
        raise EncodingError(f"{encoding} image of {width}x{height} with step {step} holds {len(data)} bytes, "
                            f"expected at least {max(step, width * ch * depth) * height}")
    rows = np.asarray(data, np.uint8)[:step * height].reshape(height, step)[:, :width * ch * depth]
    if depth == 2:
        return _mono16_to_8(rows.copy().view(">u2" if is_bigendian else "<u2").reshape(height, width))
    img = rows.reshape(height, width, ch) if ch > 1 else rows
    if enc in _BAYER:
        return cv2.cvtColor(np.ascontiguousarray(img), _BAYER[enc])
    if enc == "rgb8":
        return np.ascontiguousarray(img[:, :, ::-1])
    if enc == "rgba8":
        return np.ascontiguousarray(img[:, :, 2::-1])
    if enc == "bgra8":
        return np.ascontiguousarray(img[:, :, :3])
    return np.ascontiguousarray(img)


def _mono16_to_8(img16: np.ndarray) -> np.ndarray:
    top = int(img16.max())
    shift = max(top.bit_length() - 8, 0)
    return (img16 >> shift).astype(np.uint8)


def compressed_suffix(data: bytes) -> str | None:
    """'.png' or '.jpg' from the file signature (what a CompressedImage holds), else None."""
    head = bytes(data[:4])
    for magic, suffix in _COMPRESSED_SUFFIX.items():
        if head.startswith(magic):
            return suffix
    return None


def decode(data: bytes | np.ndarray) -> np.ndarray:
    """Encoded bytes (png, jpeg, ...) -> 8-bit grey or BGR pixels; EncodingError if unreadable."""
    buf = np.frombuffer(bytes(data), np.uint8) if not isinstance(data, np.ndarray) else data
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if img is None:
        raise EncodingError("compressed image data does not decode as an image")
    if img.dtype == np.uint16:
        img = _mono16_to_8(img) if img.ndim == 2 else (img >> 8).astype(np.uint8)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    return np.ascontiguousarray(img)


def grey(img: np.ndarray) -> np.ndarray:
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def focus_measure(img: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image (Pech-Pacheco et al. 2000): high for
    sharp frames, low for motion-blurred or defocused ones. Used to pick the sharpest frame
    of a time slot; comparable between frames of one camera, not between cameras."""
    return float(cv2.Laplacian(grey(img), cv2.CV_64F).var())
