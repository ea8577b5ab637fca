"""EuRoC / ASL folders: `mav0/<sensor>/{sensor.yaml, data.csv, data/}`.

Camera `data.csv` is `#timestamp [ns],filename`; IMU `data.csv` is the IMU csv format
(docs/formats.md#imu-data). `sensor.yaml` (OpenCV-style, starting `%YAML:1.0`) gives `T_BS`
(maps sensor points into the body frame B, row-major 4x4 under `data`), `resolution`, `intrinsics` [fu, fv, cu, cv],
`camera_model`, `distortion_model` and `distortion_coefficients`; an IMU's gives the
Kalibr noise figures and `rate_hz`.

The rig written from them is FLU: B's axes are given in FLU terms by `body_axes`
(EuRoC's ADIS16448 is mounted x up, y right, z forward: `U -L F`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import yaml

from rigcal.core import geometry as geo
from rigcal.errors import InputError
from rigcal.core.rig import NAME_RE
from rigcal.data.ingest.writer import Frame, ImuBlock

EUROC_BODY_AXES = ("U", "-L", "F")
IMU_NOISE_KEYS = ("gyroscope_noise_density", "gyroscope_random_walk", "accelerometer_noise_density",
                  "accelerometer_random_walk")
_DISTORTION_MODELS = {"radial-tangential": "pinhole", "radtan": "pinhole", "equidistant": "fisheye"}


def find_mav0(source: Path) -> Path | None:
    """The folder holding the sensor folders: SOURCE/mav0, or SOURCE itself."""
    for d in (source / "mav0", source):
        if d.is_dir() and any((s / "data.csv").is_file() and (s / "sensor.yaml").is_file() for s in d.iterdir()
                              if s.is_dir()):
            return d
    return None


def read_sensor_yaml(path: Path) -> dict:
    """A sensor.yaml as a dict (its `%YAML:1.0` line is OpenCV's, which PyYAML refuses)."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    lines = [ln for ln in text.splitlines() if not ln.startswith("%YAML")]
    try:
        doc = yaml.safe_load("\n".join(lines).replace("!!opencv-matrix", ""))
    except yaml.YAMLError as e:
        raise InputError(f"{path}: not valid YAML ({' '.join(str(e).split())})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a mapping of sensor keys")
    return doc


@dataclass(frozen=True)
class EurocRecording:
    """The chosen sensors of a mav0 folder: dataset name -> sensor folder."""

    mav0: Path
    cameras: dict[str, Path]
    imus: dict[str, Path]
    rows: dict[str, tuple[np.ndarray, list[str]]]  # per camera its data.csv: (t_ns, file names)

    @property
    def sources(self) -> tuple[dict[str, str], dict[str, str]]:
        return ({c: str(p / "data.csv") for c, p in self.cameras.items()},
                {n: str(p / "data.csv") for n, p in self.imus.items()})

    def first_stamp_ns(self) -> int:
        return min(int(t.min()) for t, _ in self.rows.values())

    def total_frames(self) -> int:
        return sum(len(t) for t, _ in self.rows.values())

    def items(self) -> Iterator[tuple[str, str, Frame | ImuBlock]]:
        for name, folder in self.imus.items():
            yield "imu", name, read_imu_csv(folder / "data.csv")
        for camera, folder in self.cameras.items():
            t, names = self.rows[camera]
            for i, (ti, fname) in enumerate(zip(t, names)):
                path = folder / "data" / fname
                if not path.is_file():
                    raise InputError(f"{folder / 'data.csv'}: row {i + 2}: image {path} does not exist")
                yield "camera", camera, Frame(t_ns=int(ti), where=str(path), file=path)


def open_euroc(mav0: Path, cameras: dict[str, str], imus: dict[str, str]) -> EurocRecording:
    """Pick sensors: `cameras`/`imus` map dataset names to sensor folder names. Neither
    given: every camera and IMU folder under its own name; cameras chosen and no IMU: no
    IMU (as for a bag, where only --imu brings one in)."""
    kinds: dict[str, list[str]] = {"camera": [], "imu": []}
    for d in sorted(p for p in mav0.iterdir() if p.is_dir() and (p / "sensor.yaml").is_file()):
        kind = str(read_sensor_yaml(d / "sensor.yaml").get("sensor_type", "")).lower()
        if kind in kinds and (d / "data.csv").is_file():
            kinds[kind].append(d.name)
    cams = _choose(mav0, "camera", kinds["camera"], cameras)
    if not cams:
        raise InputError(f"{mav0}: no camera folder (a sensor.yaml with sensor_type: camera and a data.csv)")
    chosen_imus = _choose(mav0, "imu", kinds["imu"], imus) if imus or not cameras else {}
    return EurocRecording(mav0, cams, chosen_imus,
                          {c: read_camera_csv(d / "data.csv") for c, d in cams.items()})


def _choose(mav0: Path, kind: str, present: list[str], chosen: dict[str, str]) -> dict[str, Path]:
    if not chosen:
        bad = [n for n in present if not NAME_RE.match(n)]
        if bad:
            raise InputError(f"{mav0 / bad[0]}: {bad[0]!r} is not a rig name ([a-z0-9_]+); name it with "
                             f"--{kind} NAME={bad[0]}")
        return {n: mav0 / n for n in present}
    for name, folder in chosen.items():
        if folder not in present:
            raise InputError(f"{mav0}: no {kind} folder {folder!r} (there are: {', '.join(present) or 'none'})")
    return {name: mav0 / folder for name, folder in chosen.items()}


def read_camera_csv(path: Path) -> tuple[np.ndarray, list[str]]:
    """(t_ns (N,) int64, file names) from a camera data.csv."""
    t, names = [], []
    for row, cells in _csv_rows(path):
        if len(cells) != 2:
            raise InputError(f"{path}: row {row}: expected 2 columns (timestamp [ns], filename), got {len(cells)}")
        t.append(_int_cell(cells[0], path, row))
        names.append(cells[1].strip())
    if not t:
        raise InputError(f"{path}: no rows")
    return np.array(t, np.int64), names


def read_imu_csv(path: Path) -> ImuBlock:
    """An IMU data.csv (docs/formats.md#imu-data) as an ImuBlock; one line naming the row on bad cells."""
    t, vals = [], []
    for row, cells in _csv_rows(path):
        if len(cells) != 7:
            raise InputError(f"{path}: row {row}: expected 7 columns (timestamp, 3 gyroscope, 3 accelerometer), "
                             f"got {len(cells)}")
        t.append(_int_cell(cells[0], path, row))
        try:
            vals.append([float(c) for c in cells[1:]])
        except ValueError:
            raise InputError(f"{path}: row {row}: expected numbers, got {','.join(cells[1:])!r}") from None
    if not t:
        raise InputError(f"{path}: no samples")
    v = np.array(vals, np.float64)
    if not np.isfinite(v).all():
        row = int(np.flatnonzero(~np.isfinite(v).all(axis=1))[0])
        raise InputError(f"{path}: sample {row + 1}: not a finite number")
    return ImuBlock(np.array(t, np.int64), v[:, :3], v[:, 3:])


def _csv_rows(path: Path) -> Iterator[tuple[int, list[str]]]:
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    for i, line in enumerate(lines, start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            yield i, line.split(",")


def _int_cell(cell: str, path: Path, row: int) -> int:
    try:
        return int(cell.strip())
    except ValueError:
        raise InputError(f"{path}: row {row}: expected an integer timestamp in ns, got {cell.strip()!r}") from None


# ----------------------------------------------------------------------------- the declared rig


def T_BS(doc: dict, path: Path) -> np.ndarray:
    """sensor.yaml's T_BS as a checked 4x4 (the pose of the sensor in B)."""
    m = doc.get("T_BS")
    data = m.get("data") if isinstance(m, dict) else m
    try:
        T = np.array(data, np.float64).reshape(4, 4)
        geo.check_rotation(T[:3, :3])
    except (TypeError, ValueError) as e:
        raise InputError(f"{path}: T_BS: expected a rigid 4x4 transform (cols: 4, rows: 4, data: [16 numbers]), "
                         f"got {str(e) or data!r}") from None
    return T


def _camera_entry(doc: dict, path: Path, T_flu_B: np.ndarray) -> dict:
    model = str(doc.get("camera_model", "pinhole")).lower()
    dmodel = str(doc.get("distortion_model", "radial-tangential")).lower()
    if model != "pinhole" or dmodel not in _DISTORTION_MODELS:
        raise InputError(f"{path}: camera_model {model!r} / distortion_model {dmodel!r}: rigcal reads pinhole with "
                         f"radial-tangential or equidistant distortion")
    try:
        fu, fv, cu, cv = (float(x) for x in doc["intrinsics"])
        w, h = (int(x) for x in doc["resolution"])
        dist = [float(x) for x in doc.get("distortion_coefficients", [0.0] * 4)]
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{path}: expected intrinsics [fu, fv, cu, cv], resolution [w, h] and "
                         f"distortion_coefficients ({e.__class__.__name__}: {e})") from None
    T = T_flu_B @ T_BS(doc, path)
    return {"model": _DISTORTION_MODELS[dmodel], "resolution": [w, h],
            "intrinsics": {"fx": fu, "fy": fv, "cx": cu, "cy": cv}, "distortion": dist, **_pose(T)}


def _imu_entry(doc: dict, path: Path, T_flu_B: np.ndarray) -> dict:
    entry = {**_pose(T_flu_B @ T_BS(doc, path))}
    try:
        entry["update_rate"] = float(doc["rate_hz"])
        for k in IMU_NOISE_KEYS:
            entry[k] = float(doc[k])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{path}: expected rate_hz and {', '.join(IMU_NOISE_KEYS)} as numbers "
                         f"({e.__class__.__name__}: {e}); or give the rig with --rig") from None
    return entry


def _pose(T: np.ndarray) -> dict:
    # `+ 0.0` turns -0.0 into 0.0 so files read cleanly
    return {"position": [float(x) + 0.0 for x in T[:3, 3]],
            "rotation": [[float(x) + 0.0 for x in row] for row in T[:3, :3]]}


def R_flu_B(body_axes) -> np.ndarray:
    """B's x, y, z axes in FLU terms (rig-yaml `axes` tokens) -> R_flu_B."""
    try:
        return geo.R_from_axes(list(body_axes))
    except ValueError as e:
        raise InputError(f"--body-axes: {e}") from None


def declared_rig(rec: EurocRecording, body_axes=EUROC_BODY_AXES, name: str = "euroc") -> dict:
    """The rig document (docs/formats.md#rig-yaml, with `imus`) the sensor.yaml files declare."""
    T_flu_B = geo.make_T(R_flu_B(body_axes), np.zeros(3))
    cams = {c: _camera_entry(read_sensor_yaml(d / "sensor.yaml"), d / "sensor.yaml", T_flu_B)
            for c, d in rec.cameras.items()}
    doc: dict = {"rig": name, "body_frame": "FLU"}
    if rec.imus:
        doc["imus"] = {n: _imu_entry(read_sensor_yaml(d / "sensor.yaml"), d / "sensor.yaml", T_flu_B)
                       for n, d in rec.imus.items()}
    doc["cameras"] = cams
    pairs = stereo_pairs(cams)
    if pairs:
        doc["stereo_pairs"] = pairs
    return doc


def stereo_pairs(cams: dict[str, dict], max_angle_deg: float = 15.0) -> list[list[str]]:
    """[left, right] for cameras whose optical axes agree within max_angle_deg and which sit
    side by side (the other camera lies mostly along the first one's image x): left is
    the one that sees the other to its right (+x)."""
    names = list(cams)
    pairs = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            Ra, Rb = np.array(cams[a]["rotation"]), np.array(cams[b]["rotation"])
            if geo.rotation_angle_deg(Ra.T @ Rb) > max_angle_deg:
                continue
            p_a = Ra.T @ (np.array(cams[b]["position"]) - np.array(cams[a]["position"]))
            if np.linalg.norm(p_a) == 0 or abs(p_a[0]) < 0.7 * np.linalg.norm(p_a):
                continue
            pairs.append([a, b] if p_a[0] > 0 else [b, a])
    return pairs


def gravity_warning(block: ImuBlock, imu_entry: dict, name: str, seconds: float = 1.0) -> str | None:
    """A warning when the specific force over the first `seconds`, turned into FLU, does not
    point mostly up: the body axes given for B are then probably wrong."""
    t = block.t_ns
    first = block.accel[t <= t[0] + seconds * 1e9].mean(axis=0)
    f_body = np.array(imu_entry["rotation"]) @ first
    if np.linalg.norm(f_body) == 0 or f_body[2] >= 0.7 * np.linalg.norm(f_body):
        return None
    reads = (np.round(f_body, 2) + 0.0).tolist()
    return (f"warning: {name}: gravity over the first {seconds:g} s reads {reads} m/s^2 in FLU, "
            f"not mostly up (+U); if the rig was not held tilted, check --body-axes")
