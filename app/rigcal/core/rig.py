"""The rig model and its YAML schema (docs/formats.md#rig-yaml).

File keys equal the code's names, so the spec, the loader and the writer cannot
drift apart. Validation happens here, once; the rest of rigcal trusts the types.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from rigcal.core import geometry as geo
from rigcal.core.camera import FISHEYE_DIST_LENGTH, MODELS, PINHOLE_DIST_LENGTHS, CameraModel
from rigcal.errors import RigFileError
from rigcal.core.io import atomic_write_text
from rigcal.core.validate import (check_finite_tree, describe, finite_number, number_vector, positive_number,
                                  read_text, refuse_unknown_keys, shorten)

NAME_RE = re.compile(r"^[a-z0-9_]+$")
TOP_KEYS = ("rig", "body_frame", "imus", "magnetometers", "cameras", "stereo_pairs", "calibration")
CAMERA_KEYS = ("model", "resolution", "intrinsics", "distortion", "position", "look", "axes", "rotation",
               "quaternion", "time_offset_s", "line_delay_s", "calibration")
# docs/formats.md#imus: Kalibr's imu.yaml names and units; every one is required and positive
IMU_NOISE_KEYS = ("gyroscope_noise_density", "gyroscope_random_walk", "accelerometer_noise_density",
                  "accelerometer_random_walk")
IMU_KEYS = ("position", "axes", "rotation", "quaternion", "update_rate") + IMU_NOISE_KEYS + ("calibration",)
MIN_IMU_RATE_HZ = 1.0
# docs/magnetometer.md: the pose keys (position optional), the noise figure, its IMU, clock and site field
MAG_KEYS = ("position", "axes", "rotation", "quaternion", "update_rate", "noise_density", "imu", "time_offset_s",
            "earth_field_uT", "calibration")
MAX_EARTH_FIELD_UT = 100.0  # the Earth's field is 22-67 uT everywhere; more is a unit error (gauss, nT)
MAX_TIME_OFFSET_S = 10.0  # a larger clock offset is a wrong unit (ms, ns) rather than a real offset
MAX_FRAME_READOUT_S = 1.0  # line_delay_s times the image height
ORIENTATION_KEYS = ("look", "axes", "rotation", "quaternion")
INTRINSIC_KEYS = ("fx", "fy", "cx", "cy", "focal")
PAIR_KEYS = ("left", "right", "baseline_m", "depth_check", "sanity_10m")
MAX_PIXELS = 1 << 20  # per image side; OpenCV sizes are C ints


@dataclass(frozen=True, eq=False)
class Camera:
    """One camera: its intrinsics and, when declared or calibrated, T_body_cam (4x4)."""

    name: str
    intrinsics: CameraModel
    T_body_cam: np.ndarray | None = None
    calibration: Mapping[str, Any] | None = None
    time_offset_s: float | None = None  # t_imu = t_cam + time_offset_s; None when not declared
    line_delay_s: float | None = None  # rolling shutter: row r exposed at t + r * line_delay_s; None: global

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return ((self.name, self.intrinsics, self.calibration, self.time_offset_s, self.line_delay_s)
                == (other.name, other.intrinsics, other.calibration, other.time_offset_s, other.line_delay_s)
                and _same_pose(self.T_body_cam, other.T_body_cam))

    @property
    def has_pose(self) -> bool:
        return self.T_body_cam is not None

    def project_body(self, p_body: np.ndarray) -> "Projection":
        """Body-frame points (N, 3) -> this camera's pixels."""
        if self.T_body_cam is None:
            raise ValueError(f"camera {self.name} has no pose")
        p_cam = geo.transform(geo.inv_T(self.T_body_cam), np.atleast_2d(p_body))
        uv, valid = self.intrinsics.project(p_cam)
        return Projection(p_cam=p_cam, uv=uv, valid=valid, in_image=valid & self.intrinsics.in_image(uv))


def _same_pose(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


@dataclass(frozen=True, eq=False)
class Imu:
    """One IMU (docs/formats.md#imus): its pose T_body_imu (4x4; its axes are the measurement axes), its
    nominal sample rate (Hz) and Kalibr's four noise figures (continuous-time densities)."""

    name: str
    T_body_imu: np.ndarray
    update_rate: float
    gyroscope_noise_density: float  # rad/s/sqrt(Hz)
    gyroscope_random_walk: float  # rad/s^2/sqrt(Hz)
    accelerometer_noise_density: float  # m/s^2/sqrt(Hz)
    accelerometer_random_walk: float  # m/s^3/sqrt(Hz)
    calibration: Mapping[str, Any] | None = None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Imu):
            return NotImplemented
        return (self.name, self.update_rate, self.noise, self.calibration) == (
            other.name, other.update_rate, other.noise, other.calibration) and _same_pose(self.T_body_imu,
                                                                                           other.T_body_imu)

    @property
    def noise(self) -> tuple[float, float, float, float]:
        """The four noise figures in IMU_NOISE_KEYS order."""
        return (self.gyroscope_noise_density, self.gyroscope_random_walk, self.accelerometer_noise_density,
                self.accelerometer_random_walk)


@dataclass(frozen=True, eq=False)
class Magnetometer:
    """One magnetometer (docs/magnetometer.md): its pose T_body_mag (4x4; its axes are the
    measurement axes; the position is not estimated), nominal rate (Hz), noise density
    (uT/sqrt(Hz)), the IMU it is calibrated against (None: the rig's first), its clock
    offset (t_imu = t_mag + time_offset_s; None when not declared) and the site's field
    magnitude (uT; None: unknown, the soft iron is then normalised to determinant 1)."""

    name: str
    T_body_mag: np.ndarray
    update_rate: float
    noise_density: float
    imu: str | None = None
    time_offset_s: float | None = None
    earth_field_uT: float | None = None
    calibration: Mapping[str, Any] | None = None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Magnetometer):
            return NotImplemented
        keys = lambda m: (m.name, m.update_rate, m.noise_density, m.imu, m.time_offset_s,  # noqa: E731
                          m.earth_field_uT, m.calibration)
        return keys(self) == keys(other) and _same_pose(self.T_body_mag, other.T_body_mag)

    @property
    def sample_sigma_uT(self) -> float:
        """The per-sample 1-sigma of one axis: noise_density * sqrt(update_rate)."""
        return self.noise_density * float(np.sqrt(self.update_rate))


@dataclass(frozen=True)
class Projection:
    """Points in one camera: p_cam (N, 3); uv (N, 2), NaN where not valid;
    valid: in front of / inside the model's field; in_image: valid and on the sensor."""

    p_cam: np.ndarray
    uv: np.ndarray
    valid: np.ndarray
    in_image: np.ndarray

    def reason(self, i: int = 0) -> str | None:
        """None when point i is seen, else why not (words for the CLI)."""
        if self.in_image[i]:
            return None
        if not self.valid[i]:
            return "behind the camera" if self.p_cam[i, 2] <= 0 else "outside the lens model's field of view"
        return "outside the image"


@dataclass(frozen=True)
class StereoPair:
    """Two cameras declared as a stereo pair, with the calibration's baseline and depth checks
    (checks.py) when the file holds them."""

    left: str
    right: str
    baseline_m: float | None = None
    depth_check: Mapping[str, Any] | None = None
    sanity_10m: Mapping[str, Any] | None = None


@dataclass(frozen=True, eq=False)
class Rig:
    """The rig: its cameras (T_body_cam, intrinsics), IMUs, stereo pairs, body frame and the
    calibration block of a calibrated file (docs/formats.md#rig-yaml). load_rig / dump_rig read and write it."""

    name: str
    cameras: tuple[Camera, ...]
    stereo_pairs: tuple[StereoPair, ...] = ()
    calibration: Mapping[str, Any] | None = None
    body_frame: str = "FLU"
    imus: tuple[Imu, ...] = ()
    magnetometers: tuple[Magnetometer, ...] = ()

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Rig):
            return NotImplemented
        return (self.name, self.cameras, self.stereo_pairs, self.calibration, self.body_frame, self.imus,
                self.magnetometers) == (other.name, other.cameras, other.stereo_pairs, other.calibration,
                                        other.body_frame, other.imus, other.magnetometers)

    def magnetometer(self, name: str) -> Magnetometer:
        for m in self.magnetometers:
            if m.name == name:
                return m
        raise KeyError(name)

    def mag_imu(self, mag: Magnetometer) -> Imu:
        """The IMU `mag` is calibrated against: its declared `imu`, else the rig's first."""
        return self.imu(mag.imu) if mag.imu is not None else self.imus[0]

    def imu(self, name: str) -> Imu:
        for i in self.imus:
            if i.name == name:
                return i
        raise KeyError(name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.cameras)

    def camera(self, name: str) -> Camera:
        for c in self.cameras:
            if c.name == name:
                return c
        raise KeyError(name)

    def with_cameras(self, cameras: Sequence[Camera]) -> "Rig":
        return replace(self, cameras=tuple(cameras))

    def project(self, p_nav: np.ndarray, T_nav_body: np.ndarray) -> dict[str, Projection]:
        """ENU points (N, 3) seen from the body pose T_nav_body -> per camera Projection."""
        p_body = geo.transform(geo.inv_T(T_nav_body), np.atleast_2d(p_nav))
        return {c.name: c.project_body(p_body) for c in self.cameras}

    def stereo_depth(self, pair: StereoPair | tuple[str, str], p_nav: np.ndarray, T_nav_body: np.ndarray):
        """Disparity (px) and depth Z = B f / d of ENU points in a stereo pair's rectified frame."""
        from rigcal.core.stereo import rectify_pair, stereo_depth_of_points

        left, right = (pair.left, pair.right) if isinstance(pair, StereoPair) else pair
        rect = rectify_pair(self.camera(left), self.camera(right))
        p_body = geo.transform(geo.inv_T(T_nav_body), np.atleast_2d(p_nav))
        return stereo_depth_of_points(rect, p_body, rig=self)


# ----------------------------------------------------------------------------- loading


# The repository's rigs/ ship inside the package (app/rigcal/rigs links to it), so an
# installed rigcal can run `rigcal simulate drone-stereo-back --out D` with no source tree.
SHIPPED_RIGS = Path(__file__).parents[1] / "rigs"


def shipped_rig_names() -> tuple[str, ...]:
    """Names of the rigs shipped with rigcal (file stems of rigcal/rigs/*.yaml)."""
    return tuple(sorted(p.stem for p in SHIPPED_RIGS.glob("*.yaml")))


def rig_file(path: str | Path) -> Path:
    """`path` when it exists; otherwise a bare name (`drone-stereo-back`, with or without
    `.yaml`, no folder part) that names a shipped rig gives that rig's file."""
    path = Path(path)
    if path.exists() or path.parent != Path("."):
        return path
    shipped = SHIPPED_RIGS / (path.name if path.suffix == ".yaml" else f"{path.name}.yaml")
    return shipped if shipped.is_file() else path


def load_rig(path: str | Path) -> Rig:
    """Read and validate a rig file (or a shipped rig by name, see rig_file); raises
    RigFileError naming file, key and what was expected."""
    found = rig_file(path)
    try:
        text = read_text(found, RigFileError)
    except RigFileError as e:
        if found.exists() or Path(path).parent != Path("."):
            raise
        raise RigFileError(f"{e} (nor a rig shipped with rigcal: {', '.join(shipped_rig_names())})") from None
    return parse_rig(text, str(path))


def parse_rig(text: str, label: str = "<rig>") -> Rig:
    """Rig from YAML text; `label` (the file name) starts every error message."""
    return rig_from_dict(load_yaml(text, label, RigFileError), label)


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that leaves dates as text (a rig file has no dates, and PyYAML's date
    constructor raises plain ValueErrors on text like 2001-13-01).

    Deliberately the pure-Python loader: libyaml's composer recurses in C without a limit,
    so a file nested 100000 deep crashes the interpreter instead of raising."""


if getattr(yaml, "__with_libyaml__", False):
    class _FastStrictLoader(yaml.CSafeLoader):
        """The same rules with libyaml's parser (10x faster: a simulated truth.yaml of 60
        frames took 0.18 s to compose in Python), for texts that cannot nest deeply."""
else:  # pragma: no cover - PyYAML built without libyaml
    _FastStrictLoader = _StrictLoader

for _loader in {_StrictLoader, _FastStrictLoader}:
    _loader.add_constructor("tag:yaml.org,2002:timestamp", lambda loader, node: loader.construct_scalar(node))

# Nesting needs a longer line (block style, compact "- - x") or another bracket (flow
# style) per level, so within these limits a document nests at most 10000 deep. libyaml's
# recursive composer was measured to survive 20000 levels and to crash at 50000.
FAST_YAML_MAX_LINE = 2000
FAST_YAML_MAX_BRACKETS = 8000


def _loader_for(text: str) -> type:
    longest = max((len(line) for line in text.splitlines()), default=0)
    brackets = text.count("[") + text.count("{")
    if longest <= FAST_YAML_MAX_LINE and brackets <= FAST_YAML_MAX_BRACKETS:
        return _FastStrictLoader
    return _StrictLoader

# PyYAML's constructors leak plain Python errors on malformed tagged scalars
# (`!!float abc` -> ValueError, `!!bool abc` -> KeyError); nesting too deep -> RecursionError.
_YAML_FAILURES = (yaml.YAMLError, ValueError, TypeError, KeyError, AttributeError, RecursionError, OverflowError)
# Nodes a document may expand to through aliases (a billion-laughs file is refused, not expanded).
MAX_YAML_NODES = 1_000_000


def load_yaml(text: str, label: str, error: type = RigFileError) -> Any:
    """YAML text -> plain Python, refusing what safe_load would silently accept: duplicate
    mapping keys (safe_load keeps the last), aliases that contain themselves, and alias
    bombs. Every failure is one `error` line naming `label`, the key path and the line."""
    loader = None
    try:
        loader = _loader_for(text)(text)  # both readers refuse control characters
        node = loader.get_single_node()
        if node is None:
            return None
        problem = _check_nodes(node)
        if problem is not None:
            key, msg = problem
            raise error(_one_line(f"{label}: {key}: {msg}" if key else f"{label}: {msg}"))
        return loader.construct_document(node)
    except _YAML_FAILURES as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        what = getattr(e, "problem", None) or f"{e.__class__.__name__}: {e}"
        if isinstance(e, RecursionError):
            what = "nested too deeply"
        raise error(_one_line(f"{label}: not valid YAML{where}: {what}")) from None
    finally:
        if loader is not None:
            loader.dispose()


def _check_nodes(root: yaml.Node) -> tuple[str, str] | None:
    """Walk the composed node graph once: (key path, message) of the first duplicate key,
    self-containing alias or oversized expansion, else None."""
    state: dict[int, int] = {}  # id(node) -> 1 while being walked, 2 when done
    size: dict[int, int] = {}  # id(node) -> nodes it expands to

    def walk(node: yaml.Node, path: str) -> tuple[str, str] | None:
        state[id(node)] = 1
        n = 1
        children: list[tuple[yaml.Node, str]] = []
        if isinstance(node, yaml.MappingNode):
            seen: dict[tuple[str, str], None] = {}
            for k, v in node.value:
                if isinstance(k, yaml.ScalarNode):
                    ident = (k.tag, k.value)
                    if ident in seen:
                        line = k.start_mark.line + 1
                        if path == "cameras":
                            return "cameras", f"duplicate camera name {k.value!r} (line {line})"
                        return _join(path, k.value), f"duplicate key (line {line}); each key may appear once"
                    seen[ident] = None
                    children.append((v, _join(path, k.value)))
                else:
                    children += [(k, path), (v, path)]
        elif isinstance(node, yaml.SequenceNode):
            children = [(v, f"{path}[{i}]") for i, v in enumerate(node.value)]
        for child, cpath in children:
            st = state.get(id(child))
            if st == 1:
                return cpath, "a YAML alias that contains itself (recursive structure)"
            if st is None:
                problem = walk(child, cpath)
                if problem is not None:
                    return problem
            n += size[id(child)]
            if n > MAX_YAML_NODES:
                return cpath, f"expands to more than {MAX_YAML_NODES} values through aliases"
        state[id(node)] = 2
        size[id(node)] = n
        return None

    return walk(root, "")


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else str(key)


_LINE_BREAKS = re.compile(r"[\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]")


def _one_line(message: str) -> str:
    """Errors are one line on stderr, whatever text a file put in a key or value."""
    return _LINE_BREAKS.sub(lambda m: repr(m.group())[1:-1], message)


def rig_from_dict(doc: Any, label: str = "<rig>") -> Rig:
    """Validate a parsed rig document (docs/formats.md#rig-yaml) into a Rig, or raise RigFileError."""
    def err(key: str, msg: str) -> RigFileError:
        return RigFileError(_one_line(f"{label}: {key}: {msg}" if key else f"{label}: {msg}"))

    if not isinstance(doc, dict):
        raise err("", f"expected a mapping with `cameras`, got {describe(doc)}")
    refuse_unknown_keys(doc, TOP_KEYS, "", err)
    name = doc.get("rig", "rig")
    if isinstance(name, float):
        name = finite_number(name, "rig", err)
    if not isinstance(name, (str, int, float)) or isinstance(name, bool):
        raise err("rig", f"expected a name (text), got {describe(name)}")
    body = doc.get("body_frame", "FLU")
    if body != "FLU":
        raise err("body_frame", f"only FLU is defined, got {describe(body)}")
    if "cameras" not in doc:
        raise err("cameras", "missing (expected a mapping of camera name -> camera)")
    cams_doc = doc["cameras"]
    if not isinstance(cams_doc, dict) or not cams_doc:
        raise err("cameras", f"expected a non-empty mapping of camera name -> camera, got {describe(cams_doc)}")
    cameras = []
    for cname, cdoc in cams_doc.items():
        if not isinstance(cname, str) or not NAME_RE.match(cname):
            raise err(f"cameras.{cname}", f"camera names must match [a-z0-9_]+, got {describe(cname)}")
        cameras.append(_camera_from_dict(cname, cdoc, f"cameras.{cname}", err))
    pairs = _pairs_from_doc(doc.get("stereo_pairs"), {c.name: c for c in cameras}, err)
    imus = _imus_from_doc(doc.get("imus"), {c.name for c in cameras}, err) if "imus" in doc else ()
    mags = (_mags_from_doc(doc.get("magnetometers"), {c.name for c in cameras}, imus, err)
            if "magnetometers" in doc else ())
    calib = doc.get("calibration")
    if calib is not None and not isinstance(calib, dict):
        raise err("calibration", f"expected a mapping, got {describe(calib)}")
    check_finite_tree(calib, "calibration", err)
    return Rig(name=str(name), cameras=tuple(cameras), stereo_pairs=pairs, calibration=calib, imus=imus,
               magnetometers=mags)


def _mags_from_doc(v: Any, camera_names: set[str], imus: tuple[Imu, ...], err) -> tuple[Magnetometer, ...]:
    if not isinstance(v, dict) or not v:
        raise err("magnetometers", f"expected a non-empty mapping of magnetometer name -> magnetometer, "
                                   f"got {describe(v)}")
    imu_names = [i.name for i in imus]
    out = []
    for name, d in v.items():
        key = f"magnetometers.{name}"
        if not isinstance(name, str) or not NAME_RE.match(name):
            raise err(key, f"magnetometer names must match [a-z0-9_]+, got {describe(name)}")
        if name in camera_names or name in imu_names:
            what = "a camera's" if name in camera_names else "an IMU's"
            raise err(key, f"the name {name!r} is also {what}; sensor names must be unique")
        out.append(_mag_from_dict(name, d, key, imu_names, err))
    return tuple(out)


def _time_offset(v, key: str, err) -> float:
    """A sensor's declared clock offset (t_imu = t_sensor + offset), seconds within +-MAX_TIME_OFFSET_S."""
    offset = finite_number(v, key, err)
    if abs(offset) > MAX_TIME_OFFSET_S:
        raise err(key, f"expected seconds within +-{MAX_TIME_OFFSET_S:g}, got {offset!r}")
    return offset


def _mag_from_dict(name: str, d: Any, key: str, imu_names: list[str], err) -> Magnetometer:
    if not isinstance(d, dict):
        raise err(key, f"expected a mapping, got {describe(d)}")
    if "look" in d:
        raise err(f"{key}.look", "a magnetometer has no viewing direction; give its axes, rotation or quaternion")
    refuse_unknown_keys(d, MAG_KEYS, key, err)
    if not any(k in d for k in ORIENTATION_KEYS):
        raise err(key, "missing orientation (expected one of axes, rotation, quaternion: R_body_mag)")
    T = _pose({"position": [0.0, 0.0, 0.0], **d}, key, err)
    if "update_rate" not in d:
        raise err(f"{key}.update_rate", "missing (expected the nominal sample rate in Hz)")
    rate = finite_number(d["update_rate"], f"{key}.update_rate", err)
    if rate < MIN_IMU_RATE_HZ:
        raise err(f"{key}.update_rate", f"expected at least {MIN_IMU_RATE_HZ:g} Hz, got {d['update_rate']!r}")
    if "noise_density" not in d:
        raise err(f"{key}.noise_density", "missing (expected microtesla / sqrt(Hz))")
    noise = positive_number(d["noise_density"], f"{key}.noise_density", err)
    imu = d.get("imu")
    if not imu_names:
        raise err(key, "a magnetometer is calibrated against an IMU; declare one under `imus:`")
    if imu is not None and imu not in imu_names:
        raise err(f"{key}.imu", f"expected one of the rig's IMUs ({', '.join(imu_names)}), got {describe(imu)}")
    offset = field = None
    if "time_offset_s" in d:
        offset = _time_offset(d["time_offset_s"], f"{key}.time_offset_s", err)
    if "earth_field_uT" in d:
        field = positive_number(d["earth_field_uT"], f"{key}.earth_field_uT", err)
        if field > MAX_EARTH_FIELD_UT:
            raise err(f"{key}.earth_field_uT", f"expected microtesla (the Earth's field is 22-67 uT), got {field!r}")
    calib = d.get("calibration")
    if calib is not None and not isinstance(calib, dict):
        raise err(f"{key}.calibration", f"expected a mapping, got {describe(calib)}")
    check_finite_tree(calib, f"{key}.calibration", err)
    return Magnetometer(name, T, rate, noise, imu=imu, time_offset_s=offset, earth_field_uT=field,
                        calibration=calib)


def _imus_from_doc(v: Any, camera_names: set[str], err) -> tuple[Imu, ...]:
    if not isinstance(v, dict) or not v:
        raise err("imus", f"expected a non-empty mapping of IMU name -> IMU, got {describe(v)}")
    out = []
    for name, d in v.items():
        key = f"imus.{name}"
        if not isinstance(name, str) or not NAME_RE.match(name):
            raise err(key, f"IMU names must match [a-z0-9_]+, got {describe(name)}")
        if name in camera_names:
            raise err(key, f"the name {name!r} is also a camera's; sensor names must be unique")
        out.append(_imu_from_dict(name, d, key, err))
    return tuple(out)


def _imu_from_dict(name: str, d: Any, key: str, err) -> Imu:
    if not isinstance(d, dict):
        raise err(key, f"expected a mapping, got {describe(d)}")
    if "look" in d:
        raise err(f"{key}.look", "an IMU has no viewing direction; give its axes, rotation or quaternion")
    refuse_unknown_keys(d, IMU_KEYS, key, err)
    if "position" not in d or not any(k in d for k in ORIENTATION_KEYS):
        raise err(key, "missing pose (expected `position` and one of axes, rotation, quaternion)")
    T = _pose(d, key, err)
    if "update_rate" not in d:
        raise err(f"{key}.update_rate", "missing (expected the nominal sample rate in Hz)")
    rate = finite_number(d["update_rate"], f"{key}.update_rate", err)
    if rate < MIN_IMU_RATE_HZ:
        raise err(f"{key}.update_rate", f"expected at least {MIN_IMU_RATE_HZ:g} Hz, got {d['update_rate']!r}")
    noise = []
    for k in IMU_NOISE_KEYS:
        if k not in d:
            raise err(f"{key}.{k}", "missing (Kalibr's imu.yaml figure, continuous time)")
        noise.append(positive_number(d[k], f"{key}.{k}", err))
    calib = d.get("calibration")
    if calib is not None and not isinstance(calib, dict):
        raise err(f"{key}.calibration", f"expected a mapping, got {describe(calib)}")
    check_finite_tree(calib, f"{key}.calibration", err)
    return Imu(name, T, rate, *noise, calibration=calib)


def _camera_from_dict(name: str, d: Any, key: str, err) -> Camera:
    if not isinstance(d, dict):
        raise err(key, f"expected a mapping, got {describe(d)}")
    refuse_unknown_keys(d, CAMERA_KEYS, key, err)
    model = d.get("model", "pinhole")
    if model not in MODELS:
        raise err(f"{key}.model", f"expected one of {', '.join(MODELS)}, got {describe(model)}")
    if "resolution" not in d:
        raise err(f"{key}.resolution", "missing (expected [width, height] in pixels)")
    res = d["resolution"]
    if (not isinstance(res, (list, tuple)) or len(res) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= MAX_PIXELS for v in res)):
        raise err(f"{key}.resolution", f"expected two positive integers [width, height], got {describe(res)}")
    width, height = res
    fx, fy, cx, cy = _intrinsics(d.get("intrinsics"), width, height, f"{key}.intrinsics", err)
    dist = _distortion(d.get("distortion"), model, f"{key}.distortion", err)
    cam = CameraModel(model=model, width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy, dist=dist)
    T = _pose(d, key, err)
    calib = d.get("calibration")
    if calib is not None and not isinstance(calib, dict):
        raise err(f"{key}.calibration", f"expected a mapping, got {describe(calib)}")
    check_finite_tree(calib, f"{key}.calibration", err)
    offset = delay = None
    if "time_offset_s" in d:
        offset = _time_offset(d["time_offset_s"], f"{key}.time_offset_s", err)
    if "line_delay_s" in d:
        delay = finite_number(d["line_delay_s"], f"{key}.line_delay_s", err)
        if delay < 0 or delay * height > MAX_FRAME_READOUT_S:
            raise err(f"{key}.line_delay_s", f"expected seconds per row, >= 0 and at most "
                      f"{MAX_FRAME_READOUT_S:g} s over the image's {height} rows, got {delay!r}")
    return Camera(name=name, intrinsics=cam, T_body_cam=T, calibration=calib, time_offset_s=offset,
                  line_delay_s=delay)


def _intrinsics(d: Any, width: int, height: int, key: str, err) -> tuple[float, float, float, float]:
    if d is None:
        raise err(key, "missing (expected fx, fy or focal, and optionally cx, cy)")
    if not isinstance(d, dict):
        raise err(key, f"expected a mapping, got {describe(d)}")
    refuse_unknown_keys(d, INTRINSIC_KEYS, key, err)
    if "focal" in d and ("fx" in d or "fy" in d):
        raise err(key, "give either `focal` or `fx`/`fy`, not both")
    if "focal" in d:
        fx = fy = positive_number(d["focal"], f"{key}.focal", err)
    else:
        for k in ("fx", "fy"):
            if k not in d:
                raise err(f"{key}.{k}", "missing (expected a positive focal length in pixels, or `focal`)")
        fx = positive_number(d["fx"], f"{key}.fx", err)
        fy = positive_number(d["fy"], f"{key}.fy", err)
    cx = finite_number(d.get("cx", width / 2.0), f"{key}.cx", err)
    cy = finite_number(d.get("cy", height / 2.0), f"{key}.cy", err)
    return fx, fy, cx, cy


def _distortion(v: Any, model: str, key: str, err) -> tuple[float, ...]:
    if v is None:
        return (0.0,) * (FISHEYE_DIST_LENGTH if model == "fisheye" else 5)
    if not isinstance(v, (list, tuple)):
        raise err(key, f"expected a list of numbers, got {describe(v)}")
    vals = tuple(finite_number(x, f"{key}[{i}]", err) for i, x in enumerate(v))
    allowed = (FISHEYE_DIST_LENGTH,) if model == "fisheye" else PINHOLE_DIST_LENGTHS
    if len(vals) not in allowed:
        what = "4 (k1 k2 k3 k4)" if model == "fisheye" else "2, 4, 5, 8 or 12"
        raise err(key, f"a {model} camera takes {what} coefficients, got {len(vals)}")
    return vals


def _pose(d: dict, key: str, err) -> np.ndarray | None:
    present = [k for k in ORIENTATION_KEYS if k in d]
    has_pos = "position" in d
    if not present and not has_pos:
        return None  # pose left for calibrate to find
    if not has_pos:
        raise err(f"{key}.position", "missing (an orientation without a position)")
    t = number_vector(d["position"], 3, f"{key}.position", err)
    # A calibrated file writes rotation + quaternion together (docs/formats.md#rig-yaml); they must agree.
    if sorted(present) == ["quaternion", "rotation"]:
        R = _rotation(d, "rotation", key, err)
        Rq = _rotation(d, "quaternion", key, err)
        # 1e-5, not 1e-6: a rotation accepted as orthonormal within 1e-6 can sit ~1.5e-6
        # from the rotation of its own (unit) quaternion, and a written file must load.
        if np.abs(R - Rq).max() > 1e-5:
            raise err(f"{key}.quaternion", "does not match `rotation` (a calibrated file writes both; they must agree)")
    elif len(present) > 1:
        raise err(key, f"exactly one orientation key expected, got {', '.join(present)}")
    elif not present:
        raise err(key, "missing orientation (one of look, axes, rotation, quaternion)")
    else:
        R = _rotation(d, present[0], key, err)
    return geo.make_T(R, t)


def _rotation(d: dict, k: str, key: str, err) -> np.ndarray:
    v = d[k]
    try:
        if k == "look":
            if not isinstance(v, str):
                raise ValueError(f"expected one of {', '.join(geo.LOOK_AXES)}, got {describe(v)}")
            return geo.R_from_look(v)
        if k == "axes":
            if isinstance(v, (list, tuple)):
                for i, a in enumerate(v):
                    if isinstance(a, (list, tuple)):
                        number_vector(a, 3, f"{key}.axes[{i}]", err)
            return geo.R_from_axes(v)
        if k == "rotation":
            if (not isinstance(v, (list, tuple)) or len(v) != 3
                    or not all(isinstance(r, (list, tuple)) and len(r) == 3 for r in v)):
                raise ValueError(f"expected a 3x3 matrix [[r00, r01, r02], ...], got {describe(v)}")
            rows = [[finite_number(x, f"{key}.rotation[{i}][{j}]", err) for j, x in enumerate(r)]
                    for i, r in enumerate(v)]
            return geo.check_rotation(np.array(rows))
        q = number_vector(v, 4, f"{key}.quaternion", err)
        return geo.R_from_quat(q)
    except ValueError as e:
        raise err(f"{key}.{k}", str(e)) from None


def _pairs_from_doc(v: Any, cameras: dict[str, Camera], err) -> tuple[StereoPair, ...]:
    if v is None:
        return ()
    if not isinstance(v, list):
        raise err("stereo_pairs", f"expected a list of [left, right] pairs, got {describe(v)}")
    pairs = []
    for i, p in enumerate(v):
        key = f"stereo_pairs[{i}]"
        if isinstance(p, (list, tuple)):
            if len(p) != 2:
                raise err(key, f"expected [left, right], got {describe(p)}")
            left, right, extra = p[0], p[1], {}
        elif isinstance(p, dict):
            refuse_unknown_keys(p, PAIR_KEYS, key, err)
            if "left" not in p or "right" not in p:
                raise err(key, "expected `left` and `right` camera names")
            left, right = p["left"], p["right"]
            extra = {k: p[k] for k in ("baseline_m", "depth_check", "sanity_10m") if k in p}
            if "baseline_m" in extra:
                extra["baseline_m"] = positive_number(extra["baseline_m"], f"{key}.baseline_m", err)
            for k in ("depth_check", "sanity_10m"):
                check_finite_tree(extra.get(k), f"{key}.{k}", err)
        else:
            raise err(key, f"expected [left, right], got {describe(p)}")
        for side, n in (("left", left), ("right", right)):
            if not isinstance(n, str) or n not in cameras:
                what = shorten(repr(n), 60) if isinstance(n, str) else describe(n)
                raise err(key, f"{side} camera {what} is not declared under cameras ({', '.join(cameras)})")
        if left == right:
            raise err(key, f"a pair needs two different cameras, got {left!r} twice")
        T_l, T_r = cameras[left].T_body_cam, cameras[right].T_body_cam
        with np.errstate(over="ignore"):  # positions of +-1e308 differ by inf, which is fine
            same_place = T_l is not None and T_r is not None and np.abs(T_l[:3, 3] - T_r[:3, 3]).max() < 1e-9
        if same_place:
            raise err(key, f"{left} and {right} are at the same position; a stereo pair needs a baseline")
        pairs.append(StereoPair(left=left, right=right, **extra))
    return tuple(pairs)


# ----------------------------------------------------------------------------- saving


def _pose_keys(T: np.ndarray) -> dict[str, Any]:
    # `+ 0.0` turns -0.0 into 0.0 so files read cleanly.
    return {"position": [float(x) + 0.0 for x in T[:3, 3]],
            "rotation": [[float(x) + 0.0 for x in row] for row in T[:3, :3]],
            "quaternion": [float(x) + 0.0 for x in geo.quat_from_R(T[:3, :3])]}


def _imu_to_dict(imu: Imu) -> dict[str, Any]:
    d: dict[str, Any] = {**_pose_keys(imu.T_body_imu), "update_rate": float(imu.update_rate)}
    d.update({k: float(v) for k, v in zip(IMU_NOISE_KEYS, imu.noise)})
    if imu.calibration is not None:
        d["calibration"] = _plain(imu.calibration)
    return d


def _mag_to_dict(mag: Magnetometer) -> dict[str, Any]:
    d: dict[str, Any] = {**_pose_keys(mag.T_body_mag), "update_rate": float(mag.update_rate),
                         "noise_density": float(mag.noise_density)}
    if mag.imu is not None:
        d["imu"] = mag.imu
    if mag.time_offset_s is not None:
        d["time_offset_s"] = float(mag.time_offset_s)
    if mag.earth_field_uT is not None:
        d["earth_field_uT"] = float(mag.earth_field_uT)
    if mag.calibration is not None:
        d["calibration"] = _plain(mag.calibration)
    return d


def rig_to_dict(rig: Rig) -> dict:
    """The calibrated-file form: every posed camera and every IMU gets `rotation` and
    `quaternion`; `imus`, `time_offset_s` and `line_delay_s` only when the rig has them."""
    cams = {}
    for c in rig.cameras:
        m = c.intrinsics
        d: dict[str, Any] = {
            "model": m.model,
            "resolution": [m.width, m.height],
            "intrinsics": {"fx": float(m.fx), "fy": float(m.fy), "cx": float(m.cx), "cy": float(m.cy)},
            "distortion": [float(x) for x in m.dist],
        }
        if c.T_body_cam is not None:
            d.update(_pose_keys(c.T_body_cam))
        if c.time_offset_s is not None:
            d["time_offset_s"] = float(c.time_offset_s)
        if c.line_delay_s is not None:
            d["line_delay_s"] = float(c.line_delay_s)
        if c.calibration is not None:
            d["calibration"] = _plain(c.calibration)
        cams[c.name] = d
    out: dict[str, Any] = {"rig": rig.name, "body_frame": rig.body_frame}
    if rig.imus:
        out["imus"] = {i.name: _imu_to_dict(i) for i in rig.imus}
    if rig.magnetometers:
        out["magnetometers"] = {m.name: _mag_to_dict(m) for m in rig.magnetometers}
    out["cameras"] = cams
    if rig.stereo_pairs:
        pairs = []
        for p in rig.stereo_pairs:
            if p.baseline_m is None and p.depth_check is None and p.sanity_10m is None:
                pairs.append([p.left, p.right])
            else:
                e: dict[str, Any] = {"left": p.left, "right": p.right}
                if p.baseline_m is not None:
                    e["baseline_m"] = float(p.baseline_m)
                if p.depth_check is not None:
                    e["depth_check"] = _plain(p.depth_check)
                if p.sanity_10m is not None:
                    e["sanity_10m"] = _plain(p.sanity_10m)
                pairs.append(e)
        out["stereo_pairs"] = pairs
    if rig.calibration is not None:
        out["calibration"] = _plain(rig.calibration)
    return out


def _plain(v: Any) -> Any:
    """numpy scalars/arrays -> plain Python so yaml.safe_dump accepts them."""
    if isinstance(v, Mapping):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_plain(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


def dump_rig(rig: Rig) -> str:
    return yaml.safe_dump(rig_to_dict(rig), sort_keys=False, default_flow_style=None, width=120)


def save_rig(rig: Rig, path: str | Path) -> None:
    """Write atomically: the file is complete or absent, never half-written."""
    atomic_write_text(path, dump_rig(rig))
