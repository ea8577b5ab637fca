"""`rigcal imu-noise SOURCE --out FILE`: an IMU's noise figures from a static recording.

SOURCE is one of: an IMU csv (EuRoC's format, rigcal's `imu/<imu>.csv`); a dataset folder
with `imu/`; a EuRoC folder (`mav0/<imu>/data.csv` with a sensor.yaml of sensor_type imu);
a ROS 1 / ROS 2 bag (sensor_msgs/Imu topics chosen with --imu NAME=TOPIC). Everything is
read, checked and estimated before anything is written; the outputs (the file and the
report) are then written together, whole or not at all.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Group
from rich.table import Table

from rigcal.core.io import atomic_write_texts
from rigcal.data.ingest import parse_pairs
from rigcal.data.ingest.bag import BagRecording, is_bag, open_bag, topic_table, topics
from rigcal.data.ingest.euroc import find_mav0, read_sensor_yaml
from rigcal.errors import InputError
from rigcal.imunoise import formats, report
from rigcal.imunoise.estimate import AXES, ImuNoise, estimate
from rigcal.imunoise.recording import ImuRecording, check, read_imu_file, samples_recording


@dataclass(frozen=True)
class Source:
    """One IMU to measure: its rig name, its recording and (bags) its topic."""

    name: str
    recording: ImuRecording
    rostopic: str | None = None


def _safe_name(stem: str) -> str:
    name = "".join(ch if ch.isalnum() else "_" for ch in stem.lower())
    return name or "imu0"


def _from_files(files: dict[str, Path], chosen: dict[str, str], where: Path) -> list[Source]:
    """files: name -> csv. chosen (--imu NAME=FILE): a subset, renamed; FILE names a file
    (relative to `where`) or one of the names."""
    if not chosen:
        return [Source(n, read_imu_file(p)) for n, p in files.items()]
    out = []
    for name, f in chosen.items():
        p = files.get(f) or files.get(Path(f).stem) or (where / f if (where / f).is_file() else None)
        if p is None:
            raise InputError(f"--imu {name}={f}: no such IMU in {where} (there are: {', '.join(files) or 'none'})")
        out.append(Source(name, read_imu_file(p)))
    return out


def _euroc_imus(mav0: Path) -> dict[str, Path]:
    out = {}
    for d in sorted(p for p in mav0.iterdir() if p.is_dir() and (p / "sensor.yaml").is_file()):
        if str(read_sensor_yaml(d / "sensor.yaml").get("sensor_type", "")).lower() == "imu" and \
                (d / "data.csv").is_file():
            out[d.name] = d / "data.csv"
    return out


def _from_bag(source: Path, chosen: dict[str, str]) -> list[Source]:
    with open_bag(source) as reader:
        if not chosen:
            rows = [r for r in topics(reader) if r.msgtype.endswith("/Imu")]
            raise InputError(" ".join(topic_table(source, rows).split("\n")) + "; nothing written: name the IMU with "
                             "--imu NAME=TOPIC")
        rec = BagRecording(reader, source, {}, chosen)
        parts: dict[str, list] = {n: [] for n in chosen}
        for _, name, block in rec.items():
            parts[name].append((block.t_ns, block.gyro, block.accel))
    out = []
    for name, blocks in parts.items():
        where = f"{source}:{chosen[name]}"
        if not blocks:
            raise InputError(f"{where}: no message")
        t, g, a = (np.concatenate([b[k] for b in blocks]) for k in range(3))
        out.append(Source(name, samples_recording(where, t, g, a), chosen[name]))
    return out


def sources(source: Path, imus: list[str] | None) -> list[Source]:
    """The IMUs SOURCE holds (those --imu names, or all)."""
    chosen = parse_pairs(imus, "--imu")
    if not source.exists():
        raise InputError(f"{source}: does not exist")
    if is_bag(source):
        return _from_bag(source, chosen)
    if source.is_file():
        if source.suffix.lower() != ".csv":
            raise InputError(f"{source}: expected an IMU .csv, a dataset folder with imu/, a EuRoC folder or a ROS bag "
                             f"(.bag, .db3, .mcap, ROS 2 bag folder)")
        if len(chosen) > 1:
            raise InputError(f"--imu: one file holds one IMU; got {len(chosen)}")
        name = next(iter(chosen), _safe_name(source.stem))
        return [Source(name, read_imu_file(source))]
    if (source / "imu").is_dir():
        files = {p.stem: p for p in sorted((source / "imu").glob("*.csv")) if not p.name.startswith(".")}
        if not files:
            raise InputError(f"{source / 'imu'}: no <imu>.csv file")
        return _from_files(files, chosen, source / "imu")
    mav0 = find_mav0(source)
    if mav0 is not None:
        files = _euroc_imus(mav0)
        if not files:
            raise InputError(f"{mav0}: no IMU folder (a sensor.yaml with sensor_type: imu and a data.csv)")
        found = _from_files(files, chosen, mav0)
        return [s if chosen else Source(_safe_name(s.name), s.recording) for s in found]
    raise InputError(f"{source}: not a dataset folder with imu/, a EuRoC folder (mav0/<imu>/data.csv + sensor.yaml) "
                     f"or a ROS 2 bag folder")


def _ci(f) -> str:
    """value (-a/+b %): the 95 % interval relative to the value."""
    lo, hi = 100 * (1 - f.lo / f.value), 100 * (f.hi / f.value - 1)
    return f"{f.value:.4g} (-{lo:.2g}/+{hi:.2g} %)"


def table(noise: ImuNoise) -> Table:
    c = noise.checked
    span = (c.recording.t_ns[-1] - c.recording.t_ns[0]) * 1e-9
    caption = (f"{c.recording.source}: {len(c.recording.t_ns)} samples, {span:.0f} s at {c.rate_hz:.2f} Hz, gaps "
               f"{c.n_gaps}; stillness: consecutive one-second means differ by at most {c.accel_motion:.2g} m/s^2, "
               f"{c.gyro_motion:.2g} rad/s"
               + (f"; temperature change {c.temp_change_c:+.1f} C" if c.temp_change_c is not None else "")
               + ". Units: gyroscope rad/s/sqrt(Hz), rad/s^2/sqrt(Hz), rad/s; accelerometer m/s^2/sqrt(Hz), "
                 "m/s^3/sqrt(Hz), m/s^2. 'used': the largest axis (Kalibr takes one figure per sensor).")
    t = Table(title=f"IMU {noise.name}: noise figures from the Allan deviation (95 % interval)", caption=caption)
    for col in ("sensor", "axis", "white noise density", "random walk", "bias instability",
                "tau fitted (s): white / walk / flat", "recording for +-10 %"):
        t.add_column(col, justify="left" if col in ("sensor", "axis") else "right")
    for s in noise.sensors():
        rows = [(ax, a.white, a.random_walk, a.bias_instability) for ax, a in zip(AXES, s.axes)]
        rows.append(("used", s.white, s.random_walk, s.bias_instability))
        for ax, w, rw, bi in rows:
            bound = "" if bi.dominant else " (bound)"
            t.add_row(s.sensor, ax, _ci(w), _ci(rw), f"{bi.value:.3g}{bound}",
                      f"{w.tau_lo:.2g}-{w.tau_hi:.3g} / {rw.tau_lo:.3g}-{rw.tau_hi:.3g} / {bi.tau_lo:.3g}",
                      f"{_dur(w.needed_s)} / {_dur(rw.needed_s)}")
    return t


def _dur(s: float) -> str:
    return f"{s / 3600:.1f} h" if s >= 3600 else f"{s / 60:.1f} min" if s >= 60 else f"{max(s, 1):.0f} s"


def run(source: Path, out_path: Path, *, imus=None, rig_path: Path | None = None, report_path: Path | None = None,
        fmt: str | None = None, inflate: float = 1.0):
    """The command: returns what to print (tables and notes)."""
    if fmt is None:
        fmt = "rig" if rig_path is not None else "kalibr"
    if fmt not in formats.FORMATS:
        raise InputError(f"--format {fmt}: expected one of {', '.join(formats.FORMATS)}")
    if fmt == "rig" and rig_path is None:
        raise InputError("--format rig: needs --rig R (the rig whose imus entry takes the figures)")
    if fmt != "rig" and rig_path is not None:
        raise InputError(f"--rig: only with --format rig (got --format {fmt})")
    if not (inflate >= 1.0 and np.isfinite(inflate)):
        raise InputError(f"--inflate {inflate}: expected a factor >= 1 (figures are only ever inflated)")
    rig_text = None
    if rig_path is not None:
        try:
            rig_text = Path(rig_path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise InputError(f"--rig {rig_path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    found = sources(Path(source), imus)
    if fmt != "rig" and len(found) > 1:
        raise InputError(f"{source}: holds IMUs {', '.join(s.name for s in found)}; --format {fmt} takes one: choose "
                         f"it with --imu NAME=...")
    sources_read = {Path(s.recording.source).resolve() for s in found if Path(s.recording.source).is_file()}
    outs = [Path(out_path)] + ([Path(report_path)] if report_path is not None else [])
    for o in outs:
        if o.resolve() in sources_read:
            raise InputError(f"--out/--report {o}: is the recording being read; choose another file")
    if report_path is not None and Path(report_path).resolve() == Path(out_path).resolve():
        raise InputError(f"--report {report_path}: the same file as --out")
    noises, notes = [], []
    for s in found:
        checked = check(s.recording)
        notes += checked.notes
        noises.append(estimate(s.name, checked))
    if fmt == "rig":
        text = formats.rig_with_noise(rig_text, str(rig_path), noises, inflate)
    else:
        text = formats.WRITERS[fmt](noises[0], inflate, found[0].rostopic)
    items = [(out_path, text)] + ([(report_path, report.page(noises))] if report_path is not None else [])
    atomic_write_texts(items)
    lines = [f"note: {n}" for n in notes]
    if inflate != 1.0:
        lines.append(f"note: every figure written is the measured one x {inflate:g} (--inflate); the tables show the "
                     f"measured figures")
    lines.append(f"wrote {out_path} ({fmt})" + (f" and {report_path}" if report_path is not None else ""))
    return Group(*[table(n) for n in noises], "\n".join(lines))
