"""Same calibration before and after a change: `rigcal calibrate` on a fixed set of
datasets, its calibrated YAMLs compared as data.

A reshaping of the pipeline must leave every calibrated parameter the same
to 1e-9. This runs the command line itself (not the package's internals, which are
what changes) on the benchmark's datasets: the four `bench.accuracy` scenarios (seed 0),
the demo's render (seed 7), the real sets in samples/real and those that
samples/real/make_datasets.py links from ../shared. The datasets are made once into
DATA (renders are slow; later code must read the very same images), then

    python -m bench.same_outputs run DATA OUT          # calibrate each into OUT/<name>.yaml
    python -m bench.same_outputs compare OLD NEW       # every number, relative 1e-9

Full-precision fields (intrinsics, distortion, position, quaternion, baselines) are
compared at RTOL; the statistics calibrate rounds for printing (sigmas, RMS, depth
checks) may differ by one unit of their last printed digit, since a 1e-12 change can
round either way. Strings, keys and list lengths must match, except the dataset path.
"""

from __future__ import annotations

import argparse
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator

import yaml

from .common import ROOT, SCENARIOS, get_dataset, md_table, say

RTOL = 1e-9
ATOL = 1e-12  # entries that are zero in exact arithmetic (quaternion components of an axis-aligned camera)
FULL_PRECISION = {"intrinsics", "distortion", "position", "quaternion", "rotation", "baseline_m", "T_body_cam"}
DEMO_SEED = 7


def _real_sets() -> dict[str, Path]:
    sets = {n: ROOT / "samples" / "real" / n for n in ("bumblebee2", "opencv_stereo")}
    linked = ROOT / "bench" / "out" / "real"
    script = ROOT / "samples" / "real" / "make_datasets.py"
    for n in ("wideangle", "trinocular", "caliscope", "caliscope_b", "euroc"):
        if not (linked / n / "rig.yaml").is_file() and script.is_file():
            subprocess.run([sys.executable, str(script), str(linked), n], capture_output=True)
        if (linked / n / "rig.yaml").is_file():
            sets[n] = linked / n
    return sets


def make_data(data: Path) -> None:
    """Copy (renders: make) every dataset into DATA/<name>; symlinked images stay links."""
    data.mkdir(parents=True, exist_ok=True)
    for scn in SCENARIOS:
        dst = data / scn.name
        if not dst.is_dir():
            ds = get_dataset(scn, 0, keep_images=True, log=say)
            shutil.copytree(ds.path, dst, symlinks=True, ignore=shutil.ignore_patterns("detections.pkl"))
    demo = data / "demo"
    if not demo.is_dir():
        subprocess.run([sys.executable, "-m", "rigcal", "simulate", str(ROOT / "rigs" / "drone-stereo-back.yaml"),
                        "--out", str(demo), "--seed", str(DEMO_SEED)], check=True)
    for name, src in _real_sets().items():
        if not (data / name).is_dir():
            shutil.copytree(src, data / name, symlinks=True)


def run(data: Path, out: Path) -> list[dict]:
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for d in sorted(p for p in data.iterdir() if (p / "rig.yaml").is_file()):
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "rigcal", "calibrate", str(d), "--out", str(out / f"{d.name}.yaml")],
                           capture_output=True, text=True)
        rows.append({"set": d.name, "exit": r.returncode, "seconds": time.perf_counter() - t0})
        say(f"  {d.name}: exit {r.returncode}, {rows[-1]['seconds']:.1f} s")
        if r.returncode not in (0, 1):
            say(r.stderr.strip().splitlines()[-1] if r.stderr.strip() else "(no stderr)")
    return rows


def _walk(a: Any, b: Any, path: str, full: bool) -> Iterator[tuple[str, str, float]]:
    """(path, kind, size) for each difference; kind 'num' carries the relative difference."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            yield path, f"keys {sorted(set(a) ^ set(b))}", math.inf
            return
        for k in a:
            if path.endswith("calibration") and k == "dataset":
                continue
            yield from _walk(a[k], b[k], f"{path}.{k}", full or k in FULL_PRECISION)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield path, f"length {len(a)} != {len(b)}", math.inf
            return
        for i, (x, y) in enumerate(zip(a, b)):
            yield from _walk(x, y, f"{path}[{i}]", full)
    elif isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str) or isinstance(b, str) or a is None or b is None:
        if a != b:
            yield path, f"{a!r} != {b!r}", math.inf
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)):
        diff = abs(a - b)
        if full:
            rel = diff / max(abs(a), abs(b), 1e-300)
            if diff > RTOL * max(abs(a), abs(b)) + ATOL:
                yield path, "num", rel
        elif diff > _last_digit(a) + _last_digit(b):
            yield path, f"rounded {a} != {b}", math.inf
    else:
        yield path, f"type {type(a).__name__} != {type(b).__name__}", math.inf


def _last_digit(x: float) -> float:
    """One unit of the last digit of a number as printed (0.0046 -> 1e-4, 6.0e-05 -> 1e-6)."""
    s = repr(float(x)).lower()
    mant, _, exp = s.partition("e")
    decimals = len(mant.partition(".")[2].rstrip("0")) if "." in mant else 0
    return 10.0 ** (-decimals + (int(exp) if exp else 0))


def compare(old: Path, new: Path) -> int:
    rows, bad = [], 0
    for f in sorted(old.glob("*.yaml")):
        g = new / f.name
        if not g.is_file():
            rows.append([f.stem, "missing", ""])
            bad += 1
            continue
        diffs = list(_walk(yaml.safe_load(f.read_text()), yaml.safe_load(g.read_text()), "", False))
        worst = max((d for d in diffs if d[1] == "num"), key=lambda d: d[2], default=None)
        other = [d for d in diffs if d[1] != "num"]
        bad += bool(diffs)
        rows.append([f.stem, "same" if not diffs else f"{len(diffs)} differ",
                     "; ".join(([f"{worst[0]} rel {worst[2]:.1e}"] if worst else []) + [f"{p}: {k}" for p, k, _ in other[:3]])])
    print(md_table(["set", "result", f"worst (rtol {RTOL:g})"], rows))
    return 1 if bad else 0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("data", type=Path)
    r.add_argument("out", type=Path)
    c = sub.add_parser("compare")
    c.add_argument("old", type=Path)
    c.add_argument("new", type=Path)
    a = ap.parse_args(argv)
    if a.cmd == "run":
        make_data(a.data)
        run(a.data, a.out)
    else:
        sys.exit(compare(a.old, a.new))


if __name__ == "__main__":
    main()
