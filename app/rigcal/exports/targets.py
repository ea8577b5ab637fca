"""What the estimator and autopilot exports share: the header every file carries, the
choice of cameras and IMU, and each target's distortion model with the refusal of what
it cannot hold.

Distortion models of the targets (rigcal's pinhole coefficients are OpenCV's
k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4]]]; its fisheye is OpenCV's equidistant k1..k4):

* ``radtan4`` — k1 k2 p1 p2 (OpenVINS radtan, VINS-Fusion PINHOLE);
* ``radtan5`` — k1 k2 p1 p2 k3 (ORB-SLAM3 PinHole);
* ``radtan8`` — k1 k2 p1 p2 k3 k4 k5 k6 (basalt pinhole-radtan8);
* ``kb4`` — the equidistant k1..k4, the same polynomial as OpenVINS's equidistant,
  VINS-Fusion's KANNALA_BRANDT (k2..k5), ORB-SLAM3's KannalaBrandt8 and basalt's kb4.

A pinhole camera with more coefficients than the target holds keeps the first ones when
dropping the rest moves no pixel by more than rigcal.exports.formats.TRUNCATION_LIMIT_PX
(with a warning), and is refused otherwise.
"""

from __future__ import annotations

from typing import Sequence

from rigcal.core.camera import PINHOLE_MODEL_NAMES
from rigcal.core.rig import Camera, Imu, Rig
from rigcal.errors import InputError
from rigcal.exports.formats import _shorten

HINTS = "recalibrate with a shorter --distortion model, or export opencv, ros or json"


def version() -> str:
    from rigcal import __version__  # here, not at import: rigcal/__init__ imports the core

    return __version__


def header(rig: Rig, label: str, target: str) -> list[str]:
    """The first comment lines of every file: what wrote it, from which rig."""
    return [f"{target} settings written by rigcal {version()} from rig {rig.name!r} ({label}).",
            "rigcal's body frame is FLU (x forward, y left, z up); T_a_b maps b-frame points into frame a."]


def first_imu(rig: Rig, label: str, fmt: str) -> Imu:
    if not rig.imus:
        raise InputError(f"{label}: imus: missing; --format {fmt} needs a rig with an IMU")
    return rig.imus[0]


def posed(cams: Sequence[Camera], label: str, fmt: str) -> None:
    for c in cams:
        if c.T_body_cam is None:
            raise InputError(f"{label}: cameras.{c.name}: no pose; --format {fmt} needs every exported camera's pose")


def camera_named(rig: Rig, name: str | None, label: str, fmt: str) -> Camera:
    if name is None:
        return rig.cameras[0]
    if name not in rig.names:
        raise InputError(f"export --format {fmt}: --camera: expected one of {', '.join(rig.names)}, got {name!r}")
    return rig.camera(name)


def one_or_pair(rig: Rig, label: str, fmt: str, name: str | None = None) -> tuple[Camera, ...]:
    """The cameras of a one-or-two-camera target: the first stereo pair holding `name`
    (any pair when None), else `name` (the first camera when None) alone."""
    chosen = camera_named(rig, name, label, fmt)
    for p in rig.stereo_pairs:
        if name is None or name in (p.left, p.right):
            cams = (rig.camera(p.left), rig.camera(p.right))
            break
    else:
        cams = (chosen,)
    posed(cams, label, fmt)
    return cams


def _model_name(cam: Camera) -> str:
    m = cam.intrinsics
    return "fisheye" if m.model == "fisheye" else f"pinhole {PINHOLE_MODEL_NAMES[len(m.dist)]}"


def pinhole_coeffs(cam: Camera, keep: int, label: str, target: str) -> tuple[tuple[float, ...], str | None]:
    """A pinhole camera's first `keep` coefficients (zeros appended up to `keep`), with a
    warning when small ones were dropped; InputError when they matter or for a fisheye."""
    m = cam.intrinsics
    if m.model != "pinhole":
        raise InputError(f"{label}: cameras.{cam.name}: {target} cannot hold a {_model_name(cam)} camera")
    if len(m.dist) <= keep:
        return tuple(float(x) for x in m.dist) + (0.0,) * (keep - len(m.dist)), None
    names = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
    dropped = f"{', '.join(names[keep:len(m.dist)])} (this camera is {_model_name(cam)})"
    coeffs, warning = _shorten(cam, keep, label, target, dropped, HINTS)
    return tuple(float(x) for x in coeffs), warning


def kb4(cam: Camera) -> tuple[float, ...]:
    """A fisheye camera's k1..k4 (exact in every target's Kannala-Brandt model)."""
    return tuple(float(x) for x in cam.intrinsics.dist)


def one_offset(cams: Sequence[Camera], target: str, key: str) -> tuple[float, list[str]]:
    """The single camera-IMU clock offset a target holds (the first camera's; 0 when not
    calibrated), with a warning when the cameras' offsets differ by more than 0.1 ms."""
    offsets = [c.time_offset_s for c in cams if c.time_offset_s is not None]
    first = cams[0].time_offset_s or 0.0
    warnings = []
    if offsets and max(abs(o - first) for o in offsets) > 1e-4:
        warnings.append(f"{target} holds one camera-IMU clock offset ({key}); wrote {cams[0].name}'s "
                        f"{first * 1000:.3f} ms, the others' differ: "
                        + ", ".join(f"{c.name} {c.time_offset_s * 1000:.3f} ms" for c in cams[1:]
                                    if c.time_offset_s is not None))
    return float(first), warnings
