"""Exports of a camera-IMU rig (docs/formats.md#motion-datasets, docs/camera-imu.md)
and the import of Kalibr's camchain-imucam.yaml.

* ``kalibr-imu`` — a folder with Kalibr's ``camchain-imucam.yaml`` (the camchain of
  rigcal.exports.formats.kalibr_camchain, each camera adding ``T_cam_imu`` = inv(T_body_cam) @
  T_body_imu, mapping IMU-frame points into the camera frame, and ``timeshift_cam_imu`` =
  time_offset_s, both t_imu = t_cam + shift) and ``imu.yaml`` (Kalibr's imu-results layout:
  ``imu0`` with ``T_i_b``, the four noise figures, ``model: calibrated``, ``rostopic``,
  ``time_offset: 0.0``, ``update_rate``).
* ``euroc`` — a folder ``<sensor>/sensor.yaml`` per camera and IMU as EuRoC ships them
  (``%YAML:1.0``; ``T_BS`` row-major, mapping sensor points into B = the first IMU's frame,
  so that IMU's is the identity).

The IMU is the rig's first (the motion-dataset format's default reference). Builders are pure: rig in,
rigcal.exports.formats.Export out.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import yaml

from rigcal.core import geometry as geo
from rigcal.errors import InputError
from rigcal.exports.formats import Export, kalibr_camchain
from rigcal.core.rig import IMU_NOISE_KEYS, Rig

IMU_FORMATS = ("kalibr-imu", "euroc")  # export_command's --format names of the builders here


def _plain(x: float) -> float:
    return float(x) + 0.0


def _matrix(T: np.ndarray) -> list[list[float]]:
    return [[_plain(x) for x in row] for row in np.asarray(T, float)]


def _dump(doc: Any) -> str:
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=4096)


def _first_imu(rig: Rig, label: str, fmt: str):
    if not rig.imus:
        raise InputError(f"{label}: imus: missing; --format {fmt} needs a rig with an IMU (docs/formats.md#imus)")
    return rig.imus[0]


def kalibr_imu_files(rig: Rig, label: str = "<rig>") -> Export:
    """camchain-imucam.yaml and imu.yaml (see the module text)."""
    imu = _first_imu(rig, label, "kalibr-imu")
    chain = kalibr_camchain(rig, label)
    doc = yaml.safe_load(chain.files["camchain.yaml"])
    for key, block in doc.items():
        cam = rig.camera(block["rigcal_name"])
        block["T_cam_imu"] = _matrix(geo.inv_T(cam.T_body_cam) @ imu.T_body_imu)
        block["timeshift_cam_imu"] = _plain(cam.time_offset_s or 0.0)
        if cam.line_delay_s:
            block["line_delay"] = _plain(cam.line_delay_s)  # rigcal's: Kalibr's camchain has no rolling shutter
        block["rigcal_name"] = block.pop("rigcal_name")  # keep it last, as in camchain.yaml
    header = (f"# Kalibr camchain-imucam.yaml of rig {rig.name!r} against IMU {imu.name!r}, written by rigcal.\n"
              "# T_cam_imu maps IMU-frame points into camera coordinates (metres); t_imu = t_cam + timeshift_cam_imu.\n")
    imu_doc = {"imu0": {"T_i_b": _matrix(np.eye(4)),
                        **{k: _plain(v) for k, v in zip(IMU_NOISE_KEYS, imu.noise)},
                        "model": "calibrated", "rostopic": f"/{imu.name}", "time_offset": 0.0,
                        "update_rate": _plain(imu.update_rate), "rigcal_name": imu.name}}
    files = {"camchain-imucam.yaml": header + _dump(doc),
             "imu.yaml": f"# Kalibr imu.yaml of IMU {imu.name!r}, written by rigcal.\n" + _dump(imu_doc)}
    return Export(files, chain.warnings, chain.summary + (f"imu0 = {imu.name}",))


def _sensor_text(comment: str, doc: dict) -> str:
    return "%YAML:1.0\n" + f"# {comment}\n" + _dump(doc)


def _T_BS(T: np.ndarray) -> dict:
    return {"cols": 4, "rows": 4, "data": [_plain(x) for x in np.asarray(T, float).ravel()]}


def euroc_files(rig: Rig, label: str = "<rig>") -> Export:
    """<sensor>/sensor.yaml per camera and IMU (see the module text). Distortion as Kalibr
    holds it (radial-tangential k1 k2 p1 p2, or equidistant), with the same refusal when
    dropped terms would move a pixel."""
    imu = _first_imu(rig, label, "euroc")
    chain = yaml.safe_load(kalibr_camchain(rig, label).files["camchain.yaml"])
    T_imu_body = geo.inv_T(imu.T_body_imu)
    files = {}
    for block in chain.values():
        cam = rig.camera(block["rigcal_name"])
        doc = {"sensor_type": "camera", "comment": f"rigcal camera {cam.name}",
               "T_BS": _T_BS(T_imu_body @ cam.T_body_cam),
               "resolution": block["resolution"], "camera_model": "pinhole", "intrinsics": block["intrinsics"],
               "distortion_model": "radial-tangential" if block["distortion_model"] == "radtan" else "equidistant",
               "distortion_coefficients": block["distortion_coeffs"]}
        if cam.time_offset_s is not None:
            doc["time_offset_s"] = _plain(cam.time_offset_s)  # rigcal's: t_imu = t_cam + time_offset_s
        files[f"{cam.name}/sensor.yaml"] = _sensor_text(
            f"camera {cam.name} of rig {rig.name}, written by rigcal; T_BS maps camera points into B = IMU "
            f"{imu.name}'s frame", doc)
    for i in rig.imus:
        doc = {"sensor_type": "imu", "comment": f"rigcal IMU {i.name}", "T_BS": _T_BS(T_imu_body @ i.T_body_imu),
               "rate_hz": _plain(i.update_rate), **{k: _plain(v) for k, v in zip(IMU_NOISE_KEYS, i.noise)}}
        files[f"{i.name}/sensor.yaml"] = _sensor_text(f"IMU {i.name} of rig {rig.name}, written by rigcal", doc)
    return Export(files, (), tuple(sorted(files)))


def _T(v: Any, label: str, key: str) -> np.ndarray:
    try:
        T = np.array(v, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)) or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise ValueError("expected a 4x4 matrix with last row [0, 0, 0, 1]")
        geo.check_rotation(T[:3, :3])
    except (ValueError, TypeError) as e:
        raise InputError(f"{label}: {key}: {e}") from None
    return T


def imucam_rig(rig: Rig, doc: dict, names: list[str], declared: Rig, label: str) -> Rig:
    """The rig imported from a camchain (rigcal.exports.formats.rig_from_camchain; `names`: the rig
    camera of cam0, cam1, ...) placed by a camchain-imucam's T_cam_imu: the declared rig's
    first IMU keeps its pose, every camera is T_body_imu @ inv(T_cam_imu), and
    timeshift_cam_imu becomes its time_offset_s."""
    from dataclasses import replace

    imu = declared.imus[0]
    cams = {}
    for i, name in enumerate(names):
        key = f"cam{i}"
        T_cam_imu = _T(doc[key]["T_cam_imu"], label, f"{key}.T_cam_imu")
        shift = doc[key].get("timeshift_cam_imu", 0.0)
        if isinstance(shift, bool) or not isinstance(shift, (int, float)) or not np.isfinite(shift):
            raise InputError(f"{label}: {key}.timeshift_cam_imu: expected seconds, got {shift!r}")
        cams[name] = replace(rig.camera(name), T_body_cam=imu.T_body_imu @ geo.inv_T(T_cam_imu),
                             time_offset_s=float(shift))
    top = dict(rig.calibration or {}, reference=f"imu:{imu.name}")
    return replace(rig, cameras=tuple(cams[n] for n in rig.names), imus=declared.imus, calibration=top)
