"""`rigcal export` and `rigcal import`: read the rig (or a Kalibr camchain), build the files
of the asked format, print warnings and write everything whole or not at all.

The builders are pure and live in rigcal.exports: formats for the camera formats and the
camchain reader, imu_formats for an IMU rig's formats (built on formats' camchain), and
openvins, vins, orbslam3, basalt and autopilot for the estimators and flight controllers.
This module chains them.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

from rigcal.errors import InputError, OutputError
from rigcal.exports.formats import (FORMATS, Export, json_text, kalibr_camchain, match_declared, opencv_files,
                                    parse_camchain, rig_from_camchain, ros_files)
from rigcal.exports.imu_formats import IMU_FORMATS, euroc_files, imucam_rig, kalibr_imu_files
from rigcal.exports.autopilot import ardupilot_params, px4_params
from rigcal.mag.autopilot import ardupilot_mag_params, px4_mag_params, px4_rotation_residual_deg
from rigcal.exports.basalt import basalt_file
from rigcal.exports.openvins import openvins_files
from rigcal.exports.orbslam3 import orbslam3_file
from rigcal.exports.vins import vins_files
from rigcal.core.io import atomic_dir, atomic_write_text
from rigcal.core.rig import Rig, dump_rig, load_rig, load_yaml
from rigcal.core.validate import read_text


# The estimator and autopilot formats; those in CAMERA_FORMATS take --camera.
TARGET_FORMATS = ("openvins", "vins", "orbslam3", "basalt", "px4", "ardupilot")
CAMERA_FORMATS = ("vins", "orbslam3", "px4", "ardupilot")
FILE_FORMATS = ("kalibr", "json", "orbslam3", "basalt", "px4", "ardupilot")  # --out is a file; the others a folder


def _mag_params(rig: Rig, label: str, fmt: str) -> dict[str, float | int]:
    """The autopilot's compass parameters (CAL_MAGn_* / COMPASS_*) of the rig's magnetometers;
    a declared magnetometer without a calibration block is refused: its parameters would be
    the autopilot's defaults, silently."""
    for m in rig.magnetometers:
        if not m.calibration or "hard_iron_uT" not in m.calibration:
            raise InputError(f"{label}: magnetometers.{m.name}: no calibration; --format {fmt} writes the compass "
                             f"parameters of calibrated magnetometers (run `rigcal calibrate` on a recording with mag/, "
                             f"or export a rig without the magnetometer)")
    return px4_mag_params(rig) if fmt == "px4" else ardupilot_mag_params(rig)


def _with_mag_warnings(export: Export, rig: Rig) -> Export:
    """PX4 holds a compass's orientation only as one of its rotation enums: what the fitted
    orientation differs from that enum stays as heading error."""
    extra = tuple(f"{name}: CAL_MAG ROT is the nearest PX4 rotation enum, {deg:.2f} deg from the calibrated "
                  f"orientation: up to that much heading error remains (ArduPilot's export holds it exactly)"
                  for name, deg in px4_rotation_residual_deg(rig).items() if deg > 0.05)
    return replace(export, warnings=export.warnings + extra) if extra else export


def build(rig: Rig, fmt: str, label: str = "<rig>", camera: str | None = None) -> Export:
    """Every file one export writes, without writing anything."""
    if camera is not None and fmt not in CAMERA_FORMATS:
        raise InputError(f"export: --camera applies to --format {', '.join(CAMERA_FORMATS)}, not {fmt}")
    if fmt in TARGET_FORMATS:
        builders = {"openvins": lambda: openvins_files(rig, label), "vins": lambda: vins_files(rig, label, camera),
                    "orbslam3": lambda: orbslam3_file(rig, label, camera), "basalt": lambda: basalt_file(rig, label),
                    "px4": lambda: _with_mag_warnings(px4_params(rig, label, camera, _mag_params(rig, label, "px4")), rig),
                    "ardupilot": lambda: ardupilot_params(rig, label, camera, _mag_params(rig, label, "ardupilot"))}
        return builders[fmt]()
    if fmt == "kalibr":
        return kalibr_camchain(rig, label)
    if fmt == "opencv":
        return opencv_files(rig, label)
    if fmt == "ros":
        return ros_files(rig, label)
    if fmt == "json":
        return Export({"rig.json": json_text(rig)})
    if fmt in IMU_FORMATS:
        return (kalibr_imu_files if fmt == "kalibr-imu" else euroc_files)(rig, label)
    raise InputError(f"export: --format: expected one of {', '.join(FORMATS + IMU_FORMATS + TARGET_FORMATS)}, "
                     f"got {fmt!r}")


def _warn(message: str) -> None:
    print(f"rigcal: warning: {message}", file=sys.stderr)


def write_export(result: Export, fmt: str, out_path: Path) -> None:
    """File formats go to out_path itself; folder formats are built in a temporary sibling
    folder and moved into place, so a failure leaves nothing behind."""
    if fmt in FILE_FORMATS:
        if out_path.is_dir():
            raise OutputError(f"{out_path}: is a directory; --format {fmt} writes one file")
        (text,) = result.files.values()
        atomic_write_text(out_path, text)
        return
    if out_path.is_dir() and any(out_path.iterdir()):
        raise OutputError(f"{out_path}: directory exists and is not empty; export writes a new folder "
                          "(choose another --out or remove this one)")
    with atomic_dir(out_path, force=True) as tmp:
        for name, text in result.files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)  # euroc: <sensor>/sensor.yaml
            atomic_write_text(tmp / name, text)


def run(rig_path: Path, fmt: str, out_path: Path, camera: str | None = None) -> str:
    """`rigcal export RIG --format F --out PATH [--camera NAME]`: returns the text for stdout."""
    rig_path, out_path = Path(rig_path), Path(out_path)
    rig = load_rig(rig_path)
    result = build(rig, fmt, str(rig_path), camera)
    for w in result.warnings:
        _warn(w)
    write_export(result, fmt, out_path)
    what = {"kalibr": "Kalibr camchain", "opencv": "OpenCV FileStorage folder",
            "ros": "ROS camera_info folder", "json": "rig JSON", "kalibr-imu": "Kalibr camchain-imucam folder",
            "euroc": "EuRoC sensor.yaml folder", "openvins": "OpenVINS config folder",
            "vins": "VINS-Fusion config folder", "orbslam3": "ORB-SLAM3 settings", "basalt": "basalt calibration",
            "px4": "PX4 parameter file", "ardupilot": "ArduPilot parameter file"}[fmt]
    counts = "" if fmt in TARGET_FORMATS else f" ({len(rig.cameras)} cameras, {len(rig.stereo_pairs)} stereo pairs)"
    lines = [f"wrote {what} {out_path}{counts}"]
    lines += [f"  {s}" for s in result.summary if fmt != "json"]
    return "\n".join(lines)


def run_import(source: Path, fmt: str, out_path: Path, rig_path: Path | None = None,
               body_from: str | None = None) -> str:
    """`rigcal import --format kalibr CAMCHAIN --out RIG [--rig DECLARED | --body-from camN]`."""
    if fmt != "kalibr":
        raise InputError(f"import: --format: expected kalibr, got {fmt!r}")
    if rig_path is not None and body_from is not None:
        raise InputError("import: give --rig or --body-from, not both")
    if rig_path is None and body_from is None:
        raise InputError(
            "import: a camchain gives poses relative to cam0, not in the drone's FLU body frame: give "
            "--rig DECLARED.yaml (declared camera names and poses; cam0 is placed at its declared pose) "
            "or --body-from cam0 (cam0's camera frame becomes the body frame)")
    label = str(source)
    doc = load_yaml(read_text(source, InputError), label, InputError)
    cams = parse_camchain(doc, label)
    declared = load_rig(rig_path) if rig_path is not None else None
    rig, notes, warnings = rig_from_camchain(cams, label, declared, str(rig_path) if rig_path else "", body_from)
    if declared is not None and declared.imus and all(c.has_imu for c in cams):
        rig = imucam_rig(rig, doc, match_declared(cams, declared)[0], declared, label)
        notes = [n for n in notes if "T_cam_imu" not in n and "body frame:" not in n]
        notes.append(f"camchain-imucam: every camera placed by T_cam_imu against {declared.imus[0].name} at its "
                     f"declared pose, timeshift_cam_imu as time_offset_s")
    for w in warnings:
        _warn(w)
    atomic_write_text(Path(out_path), dump_rig(rig))
    return "\n".join([f"wrote rig {out_path} from Kalibr camchain {label} ({len(rig.cameras)} cameras)"]
                     + [f"  {n}" for n in notes])
