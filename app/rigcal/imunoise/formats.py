"""The noise figures in the files other programs read. Pure: ImuNoise in, text out.

Every format takes Kalibr's continuous-time figures (white noise density, bias random
walk) in the same units, only the key names differ:

- kalibr: Kalibr's IMU input imu.yaml: accelerometer_noise_density, accelerometer_random_walk,
  gyroscope_noise_density, gyroscope_random_walk, update_rate, rostopic;
- openvins: kalibr_imu_chain.yaml, `imu0:` with the same four keys, T_i_b, rostopic,
  time_offset, update_rate, model;
- vins: VINS-Fusion's config (OpenCV YAML): acc_n, gyr_n, acc_w, gyr_w;
- orbslam3: ORB-SLAM3's settings (OpenCV YAML): IMU.NoiseGyro, IMU.NoiseAcc, IMU.GyroWalk,
  IMU.AccWalk, IMU.Frequency;
- basalt: calibration JSON `value0`: accel_noise_std, gyro_noise_std, accel_bias_std,
  gyro_bias_std (per axis), imu_update_rate.

Basalt's `*_noise_std` are continuous-time densities (it multiplies them by sqrt(rate) for
the discrete noise) and `*_bias_std` continuous random walks, per axis: it gets each
axis' own figure. The others get one figure per sensor: the largest axis (estimate).
`inflate` multiplies every figure and the file says so.
"""

from __future__ import annotations

import json
import re

import numpy as np

from rigcal.imunoise.estimate import ImuNoise

FORMATS = ("kalibr", "rig", "basalt", "openvins", "vins", "orbslam3")


def _g(x: float) -> str:
    """A float as OpenCV's and YAML's readers both take it (always a '.' or an exponent)."""
    s = repr(float(x))
    return s if ("." in s or "e" in s or "inf" in s or "nan" in s) else s + ".0"


def header(noise: ImuNoise, inflate: float) -> list[str]:
    c = noise.checked
    lines = [f"# IMU noise figures of {noise.name} from `rigcal imu-noise`: {c.recording.source}, "
             f"{(c.recording.t_ns[-1] - c.recording.t_ns[0]) * 1e-9:.0f} s still at {c.rate_hz:.1f} Hz",
             "# (Allan deviation; each sensor's figure is its largest axis')"]
    if inflate != 1.0:
        measured = ", ".join(f"{k} {_g(v)}" for k, v in noise.kalibr().items())
        lines.append(f"# every noise figure below is the measured one multiplied by --inflate {inflate:g} "
                     f"(measured: {measured})")
    return lines


def _interval_comment(noise: ImuNoise, key: str, inflate: float) -> str:
    sensor = noise.gyroscope if key.startswith("gyro") else noise.accelerometer
    f = sensor.white if key.endswith("noise_density") else sensor.random_walk
    return f"  # 95 % interval of the measured figure [{f.lo:.3g}, {f.hi:.3g}]" + (
        f", x{inflate:g}" if inflate != 1.0 else "")


def kalibr(noise: ImuNoise, inflate: float = 1.0, rostopic: str | None = None) -> str:
    figs = noise.kalibr(inflate)
    lines = header(noise, inflate)
    lines += [f"{k}: {_g(v)}{_interval_comment(noise, k, inflate)}" for k, v in figs.items()]
    lines += [f"update_rate: {_g(round(noise.checked.rate_hz, 3))}", f"rostopic: {rostopic or '/' + noise.name}"]
    return "\n".join(lines) + "\n"


def openvins(noise: ImuNoise, inflate: float = 1.0, rostopic: str | None = None) -> str:
    figs = noise.kalibr(inflate)
    lines = ["%YAML:1.0"] + header(noise, inflate) + ["", "imu0:", "  T_i_b:"]
    lines += [f"    - [{', '.join(_g(x) for x in row)}]" for row in np.eye(4)]
    lines += [f"  {k}: {_g(v)}" for k, v in figs.items()]
    lines += [f"  rostopic: {rostopic or '/' + noise.name}", "  time_offset: 0.0",
              f"  update_rate: {_g(round(noise.checked.rate_hz, 3))}", '  model: "kalibr"']
    return "\n".join(lines) + "\n"


def vins(noise: ImuNoise, inflate: float = 1.0, rostopic: str | None = None) -> str:
    f = noise.kalibr(inflate)
    lines = ["%YAML:1.0"] + header(noise, inflate) + [
        f"acc_n: {_g(f['accelerometer_noise_density'])}", f"gyr_n: {_g(f['gyroscope_noise_density'])}",
        f"acc_w: {_g(f['accelerometer_random_walk'])}", f"gyr_w: {_g(f['gyroscope_random_walk'])}"]
    return "\n".join(lines) + "\n"


def orbslam3(noise: ImuNoise, inflate: float = 1.0, rostopic: str | None = None) -> str:
    f = noise.kalibr(inflate)
    lines = ["%YAML:1.0"] + header(noise, inflate) + [
        f"IMU.NoiseGyro: {_g(f['gyroscope_noise_density'])}", f"IMU.NoiseAcc: {_g(f['accelerometer_noise_density'])}",
        f"IMU.GyroWalk: {_g(f['gyroscope_random_walk'])}", f"IMU.AccWalk: {_g(f['accelerometer_random_walk'])}",
        f"IMU.Frequency: {_g(round(noise.checked.rate_hz, 3))}"]
    return "\n".join(lines) + "\n"


def basalt(noise: ImuNoise, inflate: float = 1.0, rostopic: str | None = None) -> str:
    def per_axis(sensor, term):
        return [getattr(a, term).value * inflate for a in sensor.axes]

    doc = {"value0": {"imu_update_rate": round(noise.checked.rate_hz, 3),
                      "accel_noise_std": per_axis(noise.accelerometer, "white"),
                      "gyro_noise_std": per_axis(noise.gyroscope, "white"),
                      "accel_bias_std": per_axis(noise.accelerometer, "random_walk"),
                      "gyro_bias_std": per_axis(noise.gyroscope, "random_walk")}}
    if inflate != 1.0:
        doc["rigcal_note"] = f"noise figures multiplied by --inflate {inflate:g}"
    return json.dumps(doc, indent=2) + "\n"


WRITERS = {"kalibr": kalibr, "openvins": openvins, "vins": vins, "orbslam3": orbslam3, "basalt": basalt}


def _edit_block(text: str, name: str, figs: dict[str, float]) -> str | None:
    """The rig text with imus.<name>'s four figures replaced in place (comments and layout
    kept), or None when the block is not laid out as plain block-style YAML."""
    lines = text.splitlines()
    try:
        top = next(i for i, ln in enumerate(lines) if re.match(r"^imus:\s*(#.*)?$", ln))
    except StopIteration:
        return None
    start = indent = None
    for i in range(top + 1, len(lines)):
        ln = lines[i]
        if ln.strip() and not ln.startswith((" ", "#")):
            break
        if ln.strip().split("#")[0].strip() == f"{name}:":
            start, indent = i, len(ln) - len(ln.lstrip())
            break
    if start is None:
        return None
    end, inner = start + 1, None
    while end < len(lines):
        ln = lines[end]
        if ln.strip() and not ln.lstrip().startswith("#"):
            ind = len(ln) - len(ln.lstrip())
            if ind <= indent:
                break
            inner = ind if inner is None else inner
        end += 1
    if inner is None:
        return None
    todo = dict(figs)
    for i in range(start + 1, end):
        key = lines[i].strip().split(":", 1)[0]
        if key in todo and len(lines[i]) - len(lines[i].lstrip()) == inner:
            comment = lines[i].split("#", 1)[1] if "#" in lines[i] else None
            lines[i] = " " * inner + f"{key}: {_g(todo.pop(key))}" + (f"  # {comment.strip()}" if comment else "")
    lines[end:end] = [" " * inner + f"{k}: {_g(v)}" for k, v in todo.items()]
    return "\n".join(lines) + "\n"


def rig_with_noise(text: str, label: str, noises: list[ImuNoise], inflate: float = 1.0) -> str:
    """The rig YAML text with each IMU's four figures (x inflate) in its `imus:` entry, the
    rest as it was; InputError when the rig does not declare an IMU measured."""
    import yaml

    from rigcal.core.rig import IMU_NOISE_KEYS, load_yaml, parse_rig, rig_from_dict
    from rigcal.errors import InputError

    rig = parse_rig(text, label)
    declared = [i.name for i in rig.imus]
    for n in noises:
        if n.name not in declared:
            raise InputError(f"{label}: imus: no IMU {n.name!r} (it declares {', '.join(declared) or 'none'}); name "
                             f"the recording's IMU with --imu NAME=... or add it under `imus:`")
    out = text
    for n in noises:
        figs = {k: n.kalibr(inflate)[k] for k in IMU_NOISE_KEYS}
        edited = _edit_block(out, n.name, figs)
        if edited is None:  # flow-style or unusual layout: rewrite the document (comments are lost)
            doc = load_yaml(out, label)
            doc["imus"][n.name].update(figs)
            edited = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120)
        out = edited
    check = {i.name: i for i in rig_from_dict(load_yaml(out, label), label).imus}
    for n in noises:
        got = dict(zip(IMU_NOISE_KEYS, check[n.name].noise))
        want = n.kalibr(inflate)
        if any(not np.isclose(got[k], want[k], rtol=1e-12) for k in IMU_NOISE_KEYS):
            raise AssertionError(f"{label}: imus.{n.name}: the edited rig does not read back the figures written")
    if inflate != 1.0:
        out = f"# imus {', '.join(n.name for n in noises)}: noise figures from rigcal imu-noise multiplied by " \
              f"--inflate {inflate:g}\n" + out
    return out
