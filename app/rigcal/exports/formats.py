"""The rig in the formats other tools read, and Kalibr's camchain read back.

Formats (docs/exports.md):

* ``kalibr`` — a camchain.yaml. Kalibr's reader (kalibr_common/ConfigReader.py,
  CameraChainParameters) counts cameras as ``len(top-level mapping)``, so the file
  holds nothing but ``cam0, cam1, ...``; inside a camera block it reads only its own
  keys, so the rig's camera name rides along as ``rigcal_name``. ``T_cn_cnm1`` maps
  camera n-1's coordinates into camera n's: ``T_cn_cnm1 = inv(T_body_cn) @ T_body_cnm1``.
* ``opencv`` — a folder of cv2.FileStorage YAML: ``stereo_<left>_<right>.yaml`` per pair
  (K1 D1 K2 D2 R T with ``x_right = R x_left + T``, and rigcal's own R1 R2 P1 P2 Q) and
  ``camera_<name>.yaml`` per camera (K, D, T_body_cam).
* ``ros`` — a folder of camera_info YAML (``<name>.yaml``) in the layout of ROS
  camera_calibration_parsers (parse_yml.cpp).
* ``json`` — the rig schema (docs/formats.md#rig-yaml) as JSON.

The builders are pure (rig in, file texts and warnings out), as is the camchain reader;
export_command does the reading, printing and whole-or-nothing writing (and adds the IMU
formats of export_imu, which builds on the camchain here).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import numpy as np
import yaml

from rigcal.core import geometry as geo
from rigcal.core.camera import CameraModel
from rigcal.errors import InputError
from rigcal.core.rig import NAME_RE, Camera, Rig, rig_from_dict, rig_to_dict
from rigcal.core.stereo import StereoRectification, rectify_pair

FORMATS = ("kalibr", "opencv", "ros", "json")

# Dropping coefficients a target format cannot hold is refused past this many pixels
# of change anywhere in the image: a tenth of a typical 0.1 px reprojection RMS.
TRUNCATION_LIMIT_PX = 0.01

# Depths at which one camera's rays are tested for landing in another (cam_overlaps).
OVERLAP_DEPTHS_M = (2.0, 3.5, 5.0, 7.5, 10.0)
_GRID = (17, 13)  # pixel samples across x, y for overlaps and truncation checks


@dataclass(frozen=True)
class Export:
    """What an export writes: file name -> text (one name for file formats, several
    for folders), warnings for stderr, and one summary line per written item."""

    files: Mapping[str, str]
    warnings: tuple[str, ...] = ()
    summary: tuple[str, ...] = ()


# ----------------------------------------------------------------------------- shared helpers


def _plain_float(x: float) -> float:
    # `+ 0.0` turns -0.0 into 0.0 so the files read cleanly.
    return float(x) + 0.0


def _rows(M: np.ndarray) -> list[list[float]]:
    return [[_plain_float(x) for x in row] for row in np.asarray(M, dtype=float)]


def _flat(M: np.ndarray) -> list[float]:
    return [_plain_float(x) for x in np.asarray(M, dtype=float).ravel()]


def _yaml(doc: Any) -> str:
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=4096)


def _pixel_grid(m: CameraModel) -> np.ndarray:
    """(N, 2) pixels covering the image edge to edge, corners included."""
    u = np.linspace(-0.5, m.width - 0.5, _GRID[0])
    v = np.linspace(-0.5, m.height - 0.5, _GRID[1])
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


def truncation_effect_px(m: CameraModel, keep: int) -> tuple[float, tuple[float, float]]:
    """Largest pixel shift anywhere in the image when a pinhole camera keeps only its first
    `keep` distortion coefficients, and the pixel (u, v) where it happens.

    Rays come from the full model's exact unprojection of an edge-to-edge pixel grid and
    are projected again with the shortened model."""
    uv = _pixel_grid(m)
    rays = m.unproject(uv)
    short = m.with_(dist=tuple(m.dist[:keep]))
    uv_short, valid = short.project(rays)
    shift = np.linalg.norm(uv_short - uv, axis=1)
    shift = np.where(valid & np.isfinite(shift), shift, np.inf)
    i = int(np.argmax(shift))
    return float(shift[i]), (float(uv[i, 0]), float(uv[i, 1]))


def _shorten(cam: Camera, keep: int, label: str, target: str, dropped: str, hint: str) -> tuple[tuple[float, ...], str | None]:
    """The first `keep` coefficients, a warning when the dropped ones are small but not
    zero, or InputError when they move a pixel by more than TRUNCATION_LIMIT_PX."""
    m = cam.intrinsics
    if not any(m.dist[keep:]):
        return tuple(m.dist[:keep]), None
    shift, (u, v) = truncation_effect_px(m, keep)
    key = f"{label}: cameras.{cam.name}.distortion"
    if shift > TRUNCATION_LIMIT_PX:
        raise InputError(
            f"{key}: {target} has no {dropped}; dropping them moves pixels by up to {shift:.3g} px "
            f"(at u={u:.0f}, v={v:.0f}), more than the {TRUNCATION_LIMIT_PX} px limit ({hint})")
    return tuple(m.dist[:keep]), (
        f"{key}: {target} has no {dropped}; dropped them (pixels move by at most {shift:.2g} px, "
        f"under the {TRUNCATION_LIMIT_PX} px limit)")


def _pair_rectifications(rig: Rig, label: str) -> list[StereoRectification]:
    out = []
    for i, p in enumerate(rig.stereo_pairs):
        left, right = rig.camera(p.left), rig.camera(p.right)
        for c in (left, right):
            if c.T_body_cam is None:
                raise InputError(f"{label}: cameras.{c.name}: no pose, so stereo pair "
                                 f"stereo_pairs[{i}] ({p.left}, {p.right}) cannot be rectified")
        out.append(rectify_pair(left, right))
    return out


# ----------------------------------------------------------------------------- kalibr


def kalibr_order(rig: Rig) -> list[str]:
    """Camera names in camchain order: rig order, except that each stereo pair's left
    and right follow each other (left first) where the first of them appears."""
    order: list[str] = []
    for name in rig.names:
        for p in rig.stereo_pairs:
            if name in (p.left, p.right):
                for n in (p.left, p.right):
                    if n not in order:
                        order.append(n)
        if name not in order:
            order.append(name)
    return order


def camera_overlaps(rig: Rig, names: Sequence[str] | None = None) -> dict[str, list[str]]:
    """Which cameras share a view: camera a overlaps b when a ray through some pixel of a,
    at a depth in OVERLAP_DEPTHS_M, lands inside b's image, or the other way round."""
    names = list(names or rig.names)
    sees: dict[tuple[str, str], bool] = {}
    for a in names:
        ca = rig.camera(a)
        rays = ca.intrinsics.unproject(_pixel_grid(ca.intrinsics))
        p_a = (rays[None] * np.asarray(OVERLAP_DEPTHS_M)[:, None, None]).reshape(-1, 3)
        p_body = geo.transform(ca.T_body_cam, p_a)
        for b in names:
            if b != a:
                sees[a, b] = bool(rig.camera(b).project_body(p_body).in_image.any())
    return {a: [b for b in names if b != a and (sees[a, b] or sees[b, a])] for a in names}


def _kalibr_distortion(cam: Camera, label: str) -> tuple[str, list[float], str | None]:
    m = cam.intrinsics
    if m.model == "fisheye":
        return "equidistant", [float(x) for x in m.dist], None
    if len(m.dist) == 2:  # radial only: Kalibr's radtan with p1 = p2 = 0 is the same model
        return "radtan", [float(m.dist[0]), float(m.dist[1]), 0.0, 0.0], None
    dropped = {5: "k3", 8: "k3, k4..k6", 12: "k3, k4..k6, s1..s4"}.get(len(m.dist), "")
    coeffs, warning = _shorten(cam, 4, label, "Kalibr's radtan model", dropped,
                               "recalibrate with --distortion radtan4, or export opencv, ros or json")
    return "radtan", [float(x) for x in coeffs], warning


def kalibr_camchain(rig: Rig, label: str = "<rig>") -> Export:
    """The rig as a Kalibr camchain.yaml (text), cameras in kalibr_order."""
    for c in rig.cameras:
        if c.T_body_cam is None:
            raise InputError(f"{label}: cameras.{c.name}: no pose; Kalibr's camchain needs every "
                             f"camera's pose (T_cn_cnm1)")
    order = kalibr_order(rig)
    index = {n: i for i, n in enumerate(order)}
    overlaps = camera_overlaps(rig, order)
    doc: dict[str, Any] = {}
    warnings = []
    for i, name in enumerate(order):
        cam = rig.camera(name)
        m = cam.intrinsics
        dmodel, coeffs, warning = _kalibr_distortion(cam, label)
        if warning:
            warnings.append(warning)
        block: dict[str, Any] = {
            "camera_model": "pinhole",
            "intrinsics": [float(m.fx), float(m.fy), float(m.cx), float(m.cy)],
            "distortion_model": dmodel,
            "distortion_coeffs": [_plain_float(x) for x in coeffs],
            "resolution": [int(m.width), int(m.height)],
            "rostopic": f"/{name}/image_raw",
            "cam_overlaps": sorted(index[o] for o in overlaps[name]),
        }
        if i > 0:
            T_body_prev = rig.camera(order[i - 1]).T_body_cam
            block["T_cn_cnm1"] = _rows(geo.inv_T(cam.T_body_cam) @ T_body_prev)
        block["rigcal_name"] = name
        doc[f"cam{i}"] = block
    header = (
        f"# Kalibr camera chain (camchain.yaml) of rig {rig.name!r}, written by rigcal.\n"
        "# camN.rigcal_name is the rig's camera name; Kalibr reads only its own keys.\n"
        "# T_cn_cnm1 maps camera n-1's coordinates into camera n's (metres); the body frame\n"
        "# is not part of this format: `rigcal import --rig DECLARED.yaml` puts it back.\n"
    )
    summary = tuple(f"cam{i} = {n}" for i, n in enumerate(order))
    return Export({"camchain.yaml": header + _yaml(doc)}, tuple(warnings), summary)


# ----------------------------------------------------------------------------- opencv


def _cv_D(m: CameraModel) -> np.ndarray:
    """Distortion as OpenCV takes it: pinhole radial-only is padded to k1 k2 p1 p2."""
    d = np.asarray(m.dist, dtype=float)
    if m.model == "pinhole" and len(d) == 2:
        d = np.concatenate([d, [0.0, 0.0]])
    return d.reshape(1, -1)


def _filestorage_text(write) -> str:
    fs = cv2.FileStorage("export.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    write(fs)
    return fs.releaseAndGetString()


def _write_size(fs, size: tuple[int, int]) -> None:
    fs.startWriteStruct("image_size", cv2.FileNode_SEQ | cv2.FileNode_FLOW)
    fs.write("", int(size[0]))
    fs.write("", int(size[1]))
    fs.endWriteStruct()


def opencv_files(rig: Rig, label: str = "<rig>") -> Export:
    """cv2.FileStorage YAML texts: camera_<name>.yaml per camera, stereo_<l>_<r>.yaml per pair."""
    files: dict[str, str] = {}
    for cam in rig.cameras:
        m = cam.intrinsics

        def write_camera(fs, cam=cam, m=m):
            fs.writeComment(f"camera {cam.name} of rig {rig.name}, written by rigcal. T_body_cam maps "
                            "camera coordinates (x right, y down, z forward) to the FLU body frame, metres.")
            fs.write("camera_name", cam.name)
            fs.write("model", m.model)
            _write_size(fs, m.resolution)
            fs.write("K", m.K)
            fs.write("D", _cv_D(m))
            if cam.T_body_cam is not None:
                fs.write("T_body_cam", np.asarray(cam.T_body_cam, dtype=float))

        files[f"camera_{cam.name}.yaml"] = _filestorage_text(write_camera)
    for rect in _pair_rectifications(rig, label):
        mL, mR = rig.camera(rect.left).intrinsics, rig.camera(rect.right).intrinsics

        def write_pair(fs, rect=rect, mL=mL, mR=mR):
            fn = "cv2.fisheye.stereoRectify" if mL.model == mR.model == "fisheye" else "cv2.stereoRectify"
            fs.writeComment(f"stereo pair {rect.left} (1, left) / {rect.right} (2, right) of rig {rig.name}, "
                            f"written by rigcal. x_right = R x_left + T (metres); R1 R2 P1 P2 Q from {fn} "
                            "with CALIB_ZERO_DISPARITY, as rigcal rectifies.")
            fs.write("left_camera", rect.left)
            fs.write("right_camera", rect.right)
            fs.write("model1", mL.model)
            fs.write("model2", mR.model)
            _write_size(fs, rect.size)
            for key, val in (("K1", mL.K), ("D1", _cv_D(mL)), ("K2", mR.K), ("D2", _cv_D(mR)),
                             ("R", rect.T_right_left[:3, :3]), ("T", rect.T_right_left[:3, 3].reshape(3, 1)),
                             ("R1", rect.R1), ("R2", rect.R2), ("P1", rect.P1), ("P2", rect.P2), ("Q", rect.Q)):
                fs.write(key, np.ascontiguousarray(val, dtype=float))

        files[f"stereo_{rect.left}_{rect.right}.yaml"] = _filestorage_text(write_pair)
    summary = tuple(sorted(files))
    return Export(files, (), summary)


# ----------------------------------------------------------------------------- ros


def _ros_distortion(cam: Camera, label: str) -> tuple[str, list[float], str | None]:
    m = cam.intrinsics
    d = list(m.dist)
    if m.model == "fisheye":
        return "equidistant", d, None
    if len(d) <= 5:  # radial2 and radtan4 are plumb_bob with the missing terms zero
        return "plumb_bob", d + [0.0] * (5 - len(d)), None
    if len(d) == 8:
        return "rational_polynomial", d, None
    coeffs, warning = _shorten(cam, 8, label, "ROS camera_info's rational_polynomial model", "s1..s4",
                               "recalibrate with --distortion rational8, or export opencv or json")
    return "rational_polynomial", list(coeffs), warning


def _ros_matrix(rows: int, cols: int, data: Sequence[float]) -> dict[str, Any]:
    return {"rows": rows, "cols": cols, "data": [_plain_float(x) for x in data]}


def ros_files(rig: Rig, label: str = "<rig>") -> Export:
    """camera_info YAML per camera. Stereo-pair members carry the pair's R1/P1 (left) or
    R2/P2 (right); a camera in several pairs takes its first pair's."""
    rect_of: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for rect in _pair_rectifications(rig, label):
        rect_of.setdefault(rect.left, (rect.R1, rect.P1))
        rect_of.setdefault(rect.right, (rect.R2, rect.P2))
    files, warnings = {}, []
    for cam in rig.cameras:
        m = cam.intrinsics
        dmodel, coeffs, warning = _ros_distortion(cam, label)
        if warning:
            warnings.append(warning)
        R, P = rect_of.get(cam.name, (np.eye(3), np.column_stack([m.K, np.zeros(3)])))
        doc = {
            "image_width": int(m.width),
            "image_height": int(m.height),
            "camera_name": cam.name,
            "camera_matrix": _ros_matrix(3, 3, _flat(m.K)),
            "distortion_model": dmodel,
            "distortion_coefficients": _ros_matrix(1, len(coeffs), coeffs),
            "rectification_matrix": _ros_matrix(3, 3, _flat(R)),
            "projection_matrix": _ros_matrix(3, 4, _flat(P)),
        }
        files[f"{cam.name}.yaml"] = _yaml(doc)
    return Export(files, tuple(warnings), tuple(sorted(files)))


# ----------------------------------------------------------------------------- json


def json_text(rig: Rig) -> str:
    """The rig schema as JSON; `rig_from_dict(json.load(f))` reads it back."""
    return json.dumps(rig_to_dict(rig), indent=2) + "\n"


# ----------------------------------------------------------------------------- kalibr import


@dataclass(frozen=True)
class KalibrCamera:
    """One camN block of a camchain: intrinsics and T_cam0_cam (this camera in cam0's frame)."""

    key: str
    intrinsics: CameraModel
    T_cam0_cam: np.ndarray
    rigcal_name: str | None
    rostopic: str | None
    has_imu: bool = False  # a camchain-imucam's T_cam_imu, which a rig file cannot hold


def _kerr(label: str, key: str, msg: str) -> InputError:
    return InputError(f"{label}: {key}: {msg}")


def _knumbers(v: Any, n: int, label: str, key: str) -> list[float]:
    ok = isinstance(v, list) and len(v) == n and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
    if not ok:
        raise _kerr(label, key, f"expected {n} finite numbers, got {v!r}")
    return [float(x) for x in v]


def _kalibr_intrinsics(key: str, d: Any, label: str) -> CameraModel:
    if not isinstance(d, dict):
        raise _kerr(label, key, f"expected a camera mapping, got {d!r}")
    for k in ("camera_model", "intrinsics", "distortion_model", "distortion_coeffs", "resolution"):
        if k not in d:
            raise _kerr(label, f"{key}.{k}", "missing")
    if d["camera_model"] != "pinhole":
        raise _kerr(label, f"{key}.camera_model", f"rigcal reads pinhole cameras (radtan or equidistant "
                    f"distortion) only, got {d['camera_model']!r}")
    fx, fy, cx, cy = _knumbers(d["intrinsics"], 4, label, f"{key}.intrinsics")
    if fx <= 0 or fy <= 0:
        raise _kerr(label, f"{key}.intrinsics", f"expected positive focal lengths [fu, fv, pu, pv], got {d['intrinsics']!r}")
    res = d["resolution"]
    if not (isinstance(res, list) and len(res) == 2 and all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in res)):
        raise _kerr(label, f"{key}.resolution", f"expected two positive integers [width, height], got {res!r}")
    dmodel, coeffs = d["distortion_model"], d["distortion_coeffs"]
    if dmodel == "none":
        n = len(coeffs) if isinstance(coeffs, list) else -1
        if n not in (0, 4) or any(_knumbers(coeffs, n, label, f"{key}.distortion_coeffs")):
            raise _kerr(label, f"{key}.distortion_coeffs", f"distortion_model none takes no (or 4 zero) coefficients, got {coeffs!r}")
        model, dist = "pinhole", (0.0,) * 5
    elif dmodel in ("radtan", "equidistant"):
        model = "pinhole" if dmodel == "radtan" else "fisheye"
        dist = tuple(_knumbers(coeffs, 4, label, f"{key}.distortion_coeffs"))
    else:
        raise _kerr(label, f"{key}.distortion_model", f"rigcal reads radtan, equidistant or none, got {dmodel!r}")
    return CameraModel(model=model, width=res[0], height=res[1], fx=fx, fy=fy, cx=cx, cy=cy, dist=dist)


def _kalibr_T(v: Any, label: str, key: str) -> np.ndarray:
    if not (isinstance(v, list) and len(v) == 4 and all(isinstance(r, list) for r in v)):
        raise _kerr(label, key, f"expected a 4x4 matrix (list of 4 rows), got {v!r}")
    T = np.array([_knumbers(r, 4, label, f"{key}[{i}]") for i, r in enumerate(v)])
    if np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9:
        raise _kerr(label, key, f"expected a last row [0, 0, 0, 1], got {T[3].tolist()}")
    try:
        geo.check_rotation(T[:3, :3])
    except ValueError as e:
        raise _kerr(label, key, f"its rotation {e}") from None
    return T


def parse_camchain(doc: Any, label: str) -> list[KalibrCamera]:
    """A loaded camchain.yaml -> cameras in chain order with their pose in cam0's frame."""
    if not isinstance(doc, dict) or not doc:
        raise _kerr(label, "", "expected a Kalibr camchain (a mapping cam0, cam1, ...)")
    keys = [f"cam{i}" for i in range(len(doc))]
    if sorted(map(str, doc)) != sorted(keys):
        raise InputError(f"{label}: expected top-level keys {', '.join(keys)} (a Kalibr camchain), "
                         f"got {', '.join(map(str, doc))}")
    cams: list[KalibrCamera] = []
    T_cam0_prev = np.eye(4)
    for i, key in enumerate(keys):
        d = doc[key]
        m = _kalibr_intrinsics(key, d, label)
        if i == 0:
            T_cam0_cam = np.eye(4)
        else:
            if "T_cn_cnm1" not in d:
                raise _kerr(label, f"{key}.T_cn_cnm1", f"missing (the pose of cam{i - 1} in {key})")
            T_cn_cnm1 = _kalibr_T(d["T_cn_cnm1"], label, f"{key}.T_cn_cnm1")
            T_cam0_cam = T_cam0_prev @ geo.inv_T(T_cn_cnm1)
        T_cam0_prev = T_cam0_cam
        name = d.get("rigcal_name")
        topic = d.get("rostopic")
        cams.append(KalibrCamera(key, m, T_cam0_cam, name if isinstance(name, str) else None,
                                 topic if isinstance(topic, str) else None, "T_cam_imu" in d))
    return cams


def match_declared(cams: list[KalibrCamera], declared: Rig) -> tuple[list[str], str]:
    """Declared camera name for each Kalibr camera, and how they were matched."""
    names = list(declared.names)
    if len(cams) != len(names):
        raise InputError(f"kalibr import: the camchain has {len(cams)} cameras, the declared rig "
                         f"{declared.name!r} has {len(names)} ({', '.join(names)})")
    by_name = [c.rigcal_name for c in cams]
    if sorted(n or "" for n in by_name) == sorted(names):
        return by_name, "by rigcal_name"  # type: ignore[return-value]
    by_topic = []
    for c in cams:
        parts = set((c.rostopic or "").split("/"))
        hits = [n for n in names if n in parts]
        by_topic.append(hits[0] if len(hits) == 1 else "")
    if sorted(by_topic) == sorted(names):
        return by_topic, "by rostopic"
    return names, "by order (camN = the declared rig's N-th camera)"


def _camera_entry(m: CameraModel, T_body_cam: np.ndarray) -> dict[str, Any]:
    """One camera of the rig schema (docs/formats.md#rig-yaml) from imported intrinsics and pose."""
    return {
        "model": m.model, "resolution": [m.width, m.height],
        "intrinsics": {"fx": m.fx, "fy": m.fy, "cx": m.cx, "cy": m.cy},
        "distortion": list(m.dist),
        "position": [_plain_float(x) for x in T_body_cam[:3, 3]],
        "rotation": _rows(T_body_cam[:3, :3]),
        "quaternion": [_plain_float(x) for x in geo.quat_from_R(T_body_cam[:3, :3])],
    }


def rig_from_camchain(cams: list[KalibrCamera], source: str, declared: Rig | None = None,
                      declared_label: str = "", body_from: str | None = None) -> tuple[Rig, list[str], list[str]]:
    """Kalibr cameras -> (rig, notes for stdout, warnings for stderr).

    With `declared`, cameras take the declared names and stereo pairs and the camera
    matched to cam0 sits at its declared pose. With `body_from` (a camN key or its
    rigcal_name), that camera's frame is the body frame."""
    notes: list[str] = []
    warnings: list[str] = []
    if declared is not None:
        names, how = match_declared(cams, declared)
        notes.append(f"cameras matched to {declared_label} {how}: "
                     + ", ".join(f"{c.key} = {n}" for c, n in zip(cams, names)))
        anchor = declared.camera(names[0])
        if anchor.T_body_cam is None:
            raise InputError(f"{declared_label}: cameras.{names[0]}: no pose; the camera matched to cam0 "
                             "needs a declared pose to place the rig in the body frame")
        T_body_cam0 = anchor.T_body_cam
        reference = f"declared:{names[0]}"
        pairs = [[p.left, p.right] for p in declared.stereo_pairs]
        rig_name = declared.name
        notes.append(f"body frame: {names[0]} (cam0) at its declared pose; the others follow Kalibr's T_cn_cnm1 chain")
    else:
        names = []
        for c in cams:
            n = c.rigcal_name
            names.append(n if n and NAME_RE.match(n) and n not in names else c.key)
        keys = {c.key: i for i, c in enumerate(cams)}
        keys.update({n: i for i, n in enumerate(names)})
        if body_from not in keys:
            raise InputError(f"kalibr import: --body-from: expected one of {', '.join(sorted(set(keys)))}, got {body_from!r}")
        i0 = keys[body_from]
        T_body_cam0 = geo.inv_T(cams[i0].T_cam0_cam)
        reference = f"camera:{names[i0]}"
        pairs = []
        rig_name = Path(source).stem
        notes.append(f"body frame = {cams[i0].key}'s camera frame (x right, y down, z forward): the rig file's "
                     f"'FLU' axes here are {names[i0]}'s axes, not the drone's forward, left, up")
        notes.append("no stereo pairs (a camchain does not name them): add them under stereo_pairs, or import with --rig")
    if any(c.has_imu for c in cams):
        notes.append("T_cam_imu and the other IMU keys were not imported (a rig file has no IMU)")
    cameras = {n: _camera_entry(c.intrinsics, T_body_cam0 @ c.T_cam0_cam) for c, n in zip(cams, names)}
    if declared is not None:
        cameras = {n: cameras[n] for n in declared.names}  # declared order
        warnings += _compare_declared(declared, cameras, declared_label)
    doc = {"rig": rig_name, "body_frame": "FLU", "cameras": cameras, "stereo_pairs": pairs,
           "calibration": {"tool": "kalibr (imported by rigcal)", "dataset": source, "reference": reference}}
    if not pairs:
        del doc["stereo_pairs"]
    return rig_from_dict(doc, f"{source} (imported)"), notes, warnings


def _compare_declared(declared: Rig, cameras: Mapping[str, Mapping[str, Any]], label: str) -> list[str]:
    """A camera far from its declared place usually means the cameras were matched wrongly."""
    out = []
    for c in declared.cameras:
        if c.T_body_cam is None:
            continue
        d = cameras[c.name]
        dpos = float(np.linalg.norm(np.asarray(d["position"]) - c.T_body_cam[:3, 3]))
        dang = geo.rotation_angle_deg(c.T_body_cam[:3, :3].T @ np.asarray(d["rotation"]))
        if dpos > 0.05 or dang > 10.0:
            out.append(f"{label}: cameras.{c.name}: the imported pose is {dpos * 1000:.0f} mm and {dang:.1f} deg "
                       "from the declared one; check that the cameras were matched correctly")
    return out
