"""Benchmark: `rigcal imu-noise` on a real IMU's static recordings beside its datasheet and the
Allan deviation its recordings' publishers computed.

    python -m bench.imu_noise_real [--data DIR]

The IMU: an Analog Devices ADIS16405 (MEMS, 14-bit outputs: gyroscope 0.05 deg/s and
accelerometer 3.33 mg a count), six static recordings of about 2.8 h at 100 Hz each
(1,000,000 samples, gyroscope deg/s and accelerometer g, no time stamps), from the
Department of Geomatics Engineering, University of Calgary, published in the R package
imudata (github.com/SMAC-Group/imudata, data/adis_16405_imu1.rda .. imu6.rda, commit
eec6e5b; CC BY-NC-SA 4.0). The published Allan result: the maximum-overlap Allan variance of
one of them in the R package avar (github.com/SMAC-Group/avar, data/adis_av.rda, commit
899afb1; AGPL-3). Neither is shipped with rigcal: put the seven .rda files in --data
(default bench/out/cache/imudata); without them the section says so and is skipped. The R
files are read with the `rdata` package (the `bench` extra: pip install -e '.[bench]').

The datasheet (ADIS16405 data sheet, Analog Devices, Table 1, 25 deg C; the same figures as
NaveGo's ADIS16405 error profile): gyroscope angular random walk 2.0 deg/sqrt(h), in-run bias
stability 0.007 deg/s, rate noise density 0.05 deg/s/sqrt(Hz) rms (no filtering, at 25 Hz);
accelerometer velocity random walk 0.2 m/s/sqrt(h), in-run bias stability 0.2 mg, noise
density 0.5 mg/sqrt(Hz) rms (no filtering). The random walk (Kalibr's `*_random_walk`) is not
on the datasheet.

What runs:
1. each recording written as rigcal's IMU csv (time = sample index / 100 Hz, deg/s -> rad/s,
   g -> m/s^2 with g = 9.80665) and `rigcal imu-noise` run on it (its exit code and message);
2. the same Allan curves through rigcal.imunoise's own steps, per axis: the white noise
   density N and bias instability B with their 95 % intervals, the white-noise line read
   straight off the curve at the octave tau nearest 1 s, and the random walk K where some
   tau shows it (where none does, a 95 % upper bound from the longest tau: what `rigcal
   imu-noise` refuses to turn into a figure);
3. the six recordings pooled as one recording with gaps between them (as `rigcal imu-noise`
   pools the stretches between gaps), also end to end;
4. rigcal's Allan deviation of each recording beside avar's published one at the same taus;
5. what the IMU's own filter does, on simulated chips whose truth is known
   (tests/support/imu_static.filtered_axis: white noise at 800 Hz through a 16-tap moving
   average or a one-pole 10 ms filter, every 8th sample kept, plus a random walk; 1 h at
   100 Hz per seed, the rig's gyroscope figures): N / its low-frequency truth and how often
   the 95 % interval holds it. Runs without the .rda files.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from rigcal.imunoise.allan import ALPHA, AllanCurve, curve_edf, pooled_allan_deviation
from rigcal.imunoise.estimate import SENSORS
from rigcal.imunoise.recording import ImuRecording, check
from rigcal.imunoise.terms import FLAT, fit_bias_instability, fit_term, joint_fit, settled_curve
from rigcal.sim.static_imu import write_imu_csv

from .common import CACHE, OUT, md_table, say, write_json

ROOT = Path(__file__).resolve().parents[1]
DATA = CACHE / "imudata"
RECORDINGS = tuple(f"adis_16405_imu{i}" for i in range(1, 7))
PUBLISHED = "adis_av"
RATE_HZ = 100.0  # imudata's documentation; the files hold no time stamps
G = 9.80665  # m/s^2 per g (imudata's accelerometer columns are in g)
DEG = math.pi / 180.0
SOURCES = {
    "recordings": "github.com/SMAC-Group/imudata data/adis_16405_imu{1..6}.rda (commit eec6e5b, CC BY-NC-SA 4.0)",
    "published": "github.com/SMAC-Group/avar data/adis_av.rda (commit 899afb1, AGPL-3)",
    "datasheet": "ADIS16405 data sheet (Analog Devices), Table 1 at 25 deg C",
}


def datasheet() -> dict[str, dict[str, float]]:
    """The datasheet's figures in Kalibr's units. Its random walks (ARW deg/sqrt(h), VRW
    m/s/sqrt(h)) are the Allan deviation's white-noise line at tau = 1 s, Kalibr's noise
    density N; its noise densities are one-sided rms spectral densities n of the unfiltered
    output, whose Allan line is n / sqrt(2) (white noise of one-sided PSD n^2: sigma^2(tau) =
    n^2 / (2 tau)). Its in-run bias stability is set beside both the minimum of the Allan
    deviation and rigcal's B (that minimum / 0.664, IEEE Std 952's flicker factor): the
    measured minimum is what matches it."""
    return {
        "gyroscope": {"N_arw": 2.0 * DEG / 60.0, "N_density": 0.05 * DEG / math.sqrt(2.0), "B": 0.007 * DEG},
        "accelerometer": {"N_arw": 0.2 / 60.0, "N_density": 0.5e-3 * G / math.sqrt(2.0), "B": 0.2e-3 * G},
    }


def read_rda(path: Path):
    """The one object an .rda file holds, converted by `rdata` (R's imu matrix -> an xarray
    DataArray with the column names; avar's list -> a dict)."""
    import warnings

    import rdata

    with warnings.catch_warnings():  # rdata warns that it has no constructor for R's class "imu"
        warnings.simplefilter("ignore")
        return next(iter(rdata.read_rda(path).values()))


def adis_samples(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_ns, gyro rad/s, accel m/s^2) of an imudata ADIS16405 matrix (N, 6): gyroscope x y z
    deg/s then accelerometer x y z g, one row per 1 / RATE_HZ."""
    x = np.asarray(x, float)
    if x.ndim != 2 or x.shape[1] != 6:
        raise ValueError(f"expected an (N, 6) matrix of gyroscope deg/s and accelerometer g, got {x.shape}")
    t_ns = np.arange(len(x), dtype=np.int64) * int(round(1e9 / RATE_HZ))
    return t_ns, x[:, :3] * DEG, x[:, 3:] * G


def max_random_walk(curve: AllanCurve, p: np.ndarray) -> float:
    """A 95 % upper bound on the random walk K where the curve shows none: at the longest tau,
    K^2 tau / 3 may not exceed the measured Allan variance's 95 % upper limit (chi-square with
    the random walk's edf there) less the fitted white noise."""
    tau, var = float(curve.tau[-1]), float(curve.adev[-1]) ** 2
    nu = float(curve_edf(ALPHA["random_walk"], curve, curve.m[-1:])[0])
    upper = var * nu / chi2.ppf(0.05, nu)
    return math.sqrt(max(upper - p[1] / tau, 0.0) * 3.0 / tau)


def axis_figures(curve: AllanCurve) -> dict:
    """rigcal's terms of one axis (terms.fit_axis's steps, without its refusal when a term is
    not seen); `first_tau` the first tau read (after the taus the IMU's filter shapes)."""
    read, step = settled_curve(curve)
    p, nu = joint_fit(read)
    white, rw = fit_term(read, p, nu, 1, step), fit_term(read, p, nu, 3, step)
    bias = fit_bias_instability(read, p)
    out = {"N": None if white is None else (white.value, white.lo, white.hi, white.tau_lo, white.tau_hi),
           "B": (bias.value, bias.lo, bias.hi, bias.dominant),
           "K": None if rw is None else (rw.value, rw.lo, rw.hi, rw.tau_lo, rw.tau_hi, rw.needed_s),
           "K_max": max_random_walk(curve, p), "model": p.tolist(), "first_tau": float(read.tau[0]),
           "N_needed_s": None if white is None else white.needed_s,
           "min": (bias.value * math.sqrt(FLAT), bias.lo * math.sqrt(FLAT), bias.hi * math.sqrt(FLAT), True),
           "N_1s": curve_at_1s(curve)}
    return out


def curve_at_1s(curve: AllanCurve) -> tuple[float, float]:
    """(sigma(tau) sqrt(tau) at the octave tau nearest 1 s, that tau): the white-noise line
    read straight off the curve, with nothing subtracted (IEEE Std 952's reading of N)."""
    i = int(np.argmin(np.abs(np.log(curve.tau))))
    return float(curve.adev[i] * math.sqrt(curve.tau[i])), float(curve.tau[i])


def curves_of(parts: list[tuple[np.ndarray, np.ndarray]]) -> list[AllanCurve]:
    """Per sensor and axis (gyroscope x y z, accelerometer x y z) the Allan curve of the parts
    (one recording, or several pooled as stretches between gaps)."""
    return [pooled_allan_deviation([(g if s == 0 else a)[:, k] for g, a in parts], RATE_HZ)
            for s in (0, 1) for k in range(3)]


def run_cli(csv: Path, out: Path) -> dict:
    """`rigcal imu-noise csv --out out` in a child process: exit code, stderr's last line,
    wall and CPU time."""
    t0 = time.perf_counter()
    r0 = os.times()
    res = subprocess.run([sys.executable, "-m", "rigcal", "imu-noise", str(csv), "--out", str(out)],
                         capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT / "app")})
    r1 = os.times()
    lines = [ln for ln in res.stderr.strip().splitlines() if ln.strip()]
    return {"exit": res.returncode, "message": lines[-1] if lines else "", "wall_s": time.perf_counter() - t0,
            "cpu_s": (r1.children_user - r0.children_user) + (r1.children_system - r0.children_system),
            "written": out.exists()}


def lag1(x: np.ndarray) -> float:
    x = x - x.mean()
    return float(np.dot(x[:-1], x[1:]) / np.dot(x, x))


def published_curve(path: Path) -> dict:
    """avar's adis_av: per axis (Gyro. X .. Accel. Z) tau s and Allan deviation (deg/s, g)."""
    av = read_rda(path)
    out = {}
    for name, c in av["avar"].items():
        out[str(name)] = (np.asarray(c["levels"], float), np.asarray(c["adev"], float))
    return {"sensor": str(np.asarray(av["sensor"]).ravel()[0]), "n": int(np.asarray(av["n"]).ravel()[0]),
            "freq": float(np.asarray(av["freq"]).ravel()[0]), "curves": out}


def compare_published(curves: list[AllanCurve], pub: dict) -> dict:
    """rigcal's deviation / avar's at the taus both have, per axis (in avar's units)."""
    names = ("Gyro. X", "Gyro. Y", "Gyro. Z", "Accel. X", "Accel. Y", "Accel. Z")
    ratios = []
    for k, (c, name) in enumerate(zip(curves, names)):
        tau_p, adev_p = pub["curves"][name]
        unit = DEG if k < 3 else G
        common = [(i, int(np.argmin(np.abs(tau_p - t)))) for i, t in enumerate(c.tau)
                  if np.min(np.abs(tau_p - t)) < 1e-6 * t]
        ratios.append([float(c.adev[i] / unit / adev_p[j]) for i, j in common])
    flat = np.concatenate([np.asarray(r) for r in ratios])
    return {"ratios": ratios, "taus": len(flat) // 6 if len(flat) else 0,
            "max_dev": float(np.max(np.abs(flat - 1.0))) if len(flat) else None,
            "median": float(np.median(flat)) if len(flat) else None}


FILTERS = ("moving average", "one pole")


def filtered_coverage(seeds: int, hours: float = 1.0, n_density: float = 1.7e-4, k_walk: float = 1.9e-5) -> dict:
    """Per filter kind: N / truth (median, min, max), intervals holding the truth, the first
    tau read (s): simulated chips whose samples are filtered and decimated as a real IMU's."""
    from rigcal.imunoise.terms import TooShort, fit_axis
    from tests.support.imu_static import filtered_axis

    out = {}
    for kind in FILTERS:
        ratios, inside, first, refused = [], 0, [], 0
        for seed in range(seeds):
            x, truth = filtered_axis(hours * 3600, RATE_HZ, n_density, k_walk, kind, seed=3000 + seed)
            try:
                a = fit_axis(pooled_allan_deviation([x], RATE_HZ))
            except TooShort:
                refused += 1
                continue
            ratios.append(a.white.value / truth)
            inside += a.white.lo <= truth <= a.white.hi
            first.append(a.white.tau_lo)
        out[kind] = {"seeds": seeds, "refused": refused, "inside": inside, "ratio": ratios, "first_tau": first}
    return out


def run(data: Path = DATA, filtered_seeds: int = 30) -> dict:
    files = [data / f"{name}.rda" for name in RECORDINGS]
    filtered = filtered_coverage(filtered_seeds) if filtered_seeds else {}
    if not all(f.exists() for f in files):
        return {"skipped": f"{data}: the ADIS16405 recordings ({SOURCES['recordings']}) are not there",
                "filtered": filtered}
    t_start = time.perf_counter()
    parts, per = [], []
    for name, f in zip(RECORDINGS, files):
        t_ns, g, a = adis_samples(read_rda(f).values)
        parts.append((g, a))
        csv = data / f"{name}.csv"
        if not csv.exists():
            write_imu_csv(csv, t_ns, g, a)
        checked = check(ImuRecording(name, t_ns, g, a))
        curves = curves_of([(g, a)])
        per.append({"name": name, "samples": len(t_ns), "hours": len(t_ns) / RATE_HZ / 3600,
                    "mean": np.concatenate([g.mean(0) / DEG, a.mean(0) / G]).tolist(),
                    "sd": np.concatenate([g.std(0) / DEG, a.std(0) / G]).tolist(),
                    "lag1": [lag1(x) for x in np.hstack([g, a]).T],
                    "motion": (checked.accel_motion, checked.gyro_motion),
                    "axes": [axis_figures(c) for c in curves], "curves": curves,
                    "cli": run_cli(csv, data / f"{name}.imu.yaml")})
    # the six as one recording with a 60 s gap between each: rigcal pools the stretches
    pooled_csv = data / "adis_16405_pooled.csv"
    if not pooled_csv.exists():
        step, gap = int(round(1e9 / RATE_HZ)), 60 * 10 ** 9
        t_all, start = [], 0
        for g, _ in parts:
            t_all.append(start + np.arange(len(g), dtype=np.int64) * step)
            start = int(t_all[-1][-1]) + gap
        write_imu_csv(pooled_csv, np.concatenate(t_all), np.vstack([g for g, _ in parts]),
                      np.vstack([a for _, a in parts]))
    pooled_curves = curves_of(parts)
    pooled = {"hours": sum(len(g) for g, _ in parts) / RATE_HZ / 3600,
              "axes": [axis_figures(c) for c in pooled_curves],
              "cli": run_cli(pooled_csv, data / "adis_16405_pooled.imu.yaml")}
    pub_path = data / f"{PUBLISHED}.rda"
    published = None
    if pub_path.exists():
        pub = published_curve(pub_path)
        published = {"sensor": pub["sensor"], "n": pub["n"], "freq": pub["freq"],
                     "vs": {r["name"]: compare_published(r["curves"], pub) for r in per}}
    for r in per:
        r["curves"] = [{"tau": c.tau.tolist(), "adev": c.adev.tolist()} for c in r["curves"]]
    return {"sources": SOURCES, "rate_hz": RATE_HZ, "datasheet": datasheet(), "recordings": per, "pooled": pooled,
            "published": published, "filtered": filtered, "seconds": time.perf_counter() - t_start,
            "load_avg": os.getloadavg()[0]}


# ----------------------------------------------------------------------------- tables
def _unit(sensor: str, term: str) -> tuple[float, str]:
    """Display scale and unit: datasheet units (deg/sqrt(h), deg/h; m/s/sqrt(h), mg)."""
    if term == "min":
        term = "B"
    if sensor == "gyroscope":
        return {"N": (60.0 / DEG, "deg/sqrt(h)"), "B": (3600.0 / DEG, "deg/h"),
                "K": (3600.0 * 60.0 / DEG, "deg/h/sqrt(h)")}[term]
    return {"N": (60.0, "m/s/sqrt(h)"), "B": (1e3 / G, "mg"), "K": (60.0e3 / G, "mg/sqrt(h)")}[term]


def _span(vals: list[float], fmt: str = "{:.3g}") -> str:
    v = np.asarray(vals, float)
    return f"{fmt.format(np.median(v))} [{fmt.format(v.min())}, {fmt.format(v.max())}]"


def _cell(f, scale: float, interval: bool) -> str:
    if f is None:
        return "not seen"
    text = f"{f[0] * scale:.3g}"
    return text + (f" [{f[1] * scale:.3g}, {f[2] * scale:.3g}]" if interval else "")


ROWS = (  # (term key, label, datasheet key or None)
    ("N", "N (white-noise line, rigcal)", "N_arw"),
    ("N_1s", "N read off the curve at 1.28 s (sigma sqrt(tau))", "N_arw"),
    ("min", "minimum of the Allan deviation (0.664 B)", "B"),
    ("B", "B (minimum / 0.664)", "B"),
    ("K", "K (random walk)", None),
)


def figure_table(r: dict) -> str:
    ds = r["datasheet"]
    rows = []
    for s, sensor in enumerate(SENSORS):
        for term, label, sheet_key in ROWS:
            scale, unit = _unit(sensor, "N" if term == "N_1s" else term)
            sheet = "-" if sheet_key is None else f"{ds[sensor][sheet_key] * scale:.3g}"
            cells = []
            for k in range(3):
                figs = [rec["axes"][3 * s + k][term] for rec in r["recordings"]]
                seen = [f[0] * scale for f in figs if f is not None]
                if term == "K":
                    kmax = max(rec["axes"][3 * s + k]["K_max"] for rec in r["recordings"]) * scale
                    cells.append(f"not seen (at most {kmax:.2g})" if not seen else
                                 _span(seen) + ("" if len(seen) == len(figs) else
                                                f" in {len(seen)} of {len(figs)}; elsewhere at most {kmax:.2g}"))
                else:
                    cells.append(_span(seen))
            for k in range(3):
                f = r["pooled"]["axes"][3 * s + k][term]
                cell = _cell(f, scale, term not in ("N_1s",))
                if term == "K" and f is None:
                    cell += f" (at most {r['pooled']['axes'][3 * s + k]['K_max'] * scale:.2g})"
                if term == "B" and not f[3]:
                    cell += " bound"
                cells.append(cell)
            rows.append([f"{sensor} {label} ({unit})", sheet] + cells)
    return md_table(["figure", "datasheet", "x: 6 recordings, median [min, max]", "y", "z",
                     f"x: the 6 pooled ({r['pooled']['hours']:.1f} h), 95 % interval", "y", "z"], rows,
                    title="ADIS16405, six static recordings of 2.8 h at 100 Hz: rigcal's figures per axis beside the "
                          "datasheet (N: its ARW / VRW; in-run bias stability beside the Allan minimum and B)")


def filtered_table(f: dict) -> str:
    rows = [[kind, f"{len(v['ratio'])} of {v['seeds']}", _span(v["ratio"], "{:.4f}") if v["ratio"] else "-",
             f"{v['inside']} of {len(v['ratio'])}", _span(v["first_tau"], "{:.2g}") if v["first_tau"] else "-"]
            for kind, v in f.items()]
    return md_table(["chip filter (800 Hz, every 8th sample kept)", "read (not refused)", "N / low-frequency truth",
                     "95 % intervals holding it", "first tau read s: median [min, max]"], rows,
                    title="simulated filtered IMUs, 1 h at 100 Hz each (the curve's first taus are the filter's; "
                          "white noise alone is read from 0.01 s)")


def tables(r: dict) -> str:
    if "skipped" in r:
        text = f"\n**imu_noise_real: skipped** ({r['skipped']})\n"
        return text + (filtered_table(r["filtered"]) if r.get("filtered") else "")
    out = [figure_table(r)]
    if r.get("filtered"):
        out.append(filtered_table(r["filtered"]))
    rows = []
    for rec in r["recordings"] + [dict(name="the 6 pooled", **r["pooled"])]:
        c = rec["cli"]
        msg = c["message"].split(".csv: ", 1)[-1]
        rows.append([rec["name"], c["exit"], "yes" if c["written"] else "no", msg,
                     f"{c['wall_s']:.1f} / {c['cpu_s']:.1f}"])
    out.append(md_table(["recording", "exit", "written", "rigcal imu-noise says", "wall / CPU s"], rows,
                        title="`rigcal imu-noise` end to end on each recording's csv"))
    rows = []
    for rec in r["recordings"]:
        rows.append([rec["name"], f"{rec['hours']:.2f}",
                     " ".join(f"{m:+.3f}" for m in rec["mean"][:3]),
                     " ".join(f"{m * 1e3:+.1f}" for m in rec["mean"][3:]),
                     " ".join(f"{v:.3f}" for v in rec["sd"][:3]), " ".join(f"{v * 1e3:.2f}" for v in rec["sd"][3:]),
                     " ".join(f"{v:+.2f}" for v in rec["lag1"])])
    out.append(md_table(["recording", "h", "gyro mean deg/s", "accel mean mg (z: 1 g)", "gyro sd deg/s",
                         "accel sd mg", "lag-1 autocorrelation (gx gy gz ax ay az)"], rows,
                        title="the recordings: biases, sample spread, and how correlated consecutive samples are"))
    rec = r["recordings"][0]
    rows = [[f"{t:g}"] + [f"{rec['curves'][k]['adev'][i] * math.sqrt(t) / (DEG if k < 3 else G / 1e3):.4g}"
                          for k in range(6)] for i, t in enumerate(rec["curves"][0]["tau"])]
    out.append(md_table(["tau s", "gx deg/sqrt(s)", "gy", "gz", "ax mg/sqrt(s)", "ay", "az"], rows,
                        title=f"{rec['name']}: sigma(tau) sqrt(tau), flat where white noise rules"))
    if r["published"]:
        rows = [[name, v["taus"], f"{v['median']:.4f}", f"{100 * v['max_dev']:.2g} %"]
                for name, v in r["published"]["vs"].items()]
        out.append(md_table(["recording", "common taus per axis", "rigcal / avar: median", "largest difference"], rows,
                            title=f"rigcal's Allan deviation / avar's published one ({r['published']['sensor']}, "
                                  f"n = {r['published']['n']}, at the same taus)"))
    out.append(f"\n({r['seconds']:.0f} s, load average {r['load_avg']:.1f})\n")
    return "\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DATA, help="the folder holding the .rda files")
    ap.add_argument("--filtered-seeds", type=int, default=30, help="simulated filtered IMUs per filter (0: skip)")
    a = ap.parse_args(argv)
    r = run(a.data, a.filtered_seeds)
    write_json("imu_noise_real", r)
    text = tables(r)
    say(text)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "imu_noise_real.md").write_text(text + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
