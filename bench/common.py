"""Shared pieces of the benchmarks: scenarios, the render + detect cache, calibration
runs, table printing and JSON output. Synthetic corner observations (no rendering) come
from rigcal.sim.synthetic.

Every random draw is seeded. Renders and detections are cached per (scenario, frames,
seed) under bench/out/cache, keyed by a hash of the code that produces them
(CODE_FILES: the renderer and the detection stages), so reruns are fast and a change in that
code re-renders instead of reusing stale corners.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import rigcal
from rigcal.core import geometry as geo
from rigcal.results.compare import compare_rigs
from rigcal.data.truth import Truth, load_truth
from rigcal.camcal.body_frame import reference_transform
from rigcal.camcal.pipeline import Calibration, calibrate_views
from rigcal.core.observations import BoardView
from rigcal.core.rig import Rig

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "out"
CACHE = OUT / "cache"
RIGS = ROOT / "rigs"
JOBS = 2  # the machine the figures are quoted for has 2 cores
# the code whose output the cache holds: the renderer and every detection stage
CODE_FILES = ("simulate.py", "render.py", "target.py", "camera.py", "detect.py", "image_read.py",
              "board_detectors.py", "overlap.py", "april.py", "corner_refine.py", "corner_grid.py", "corner_fit.py")
# what a cached detection holds: 2 = (camera, frame, board, ids, uv, ambiguous, sigma);
# 1 had no sigma. Part of the cache key, so no old file is read as the new format.
CACHE_FORMAT = 2


@dataclass(frozen=True)
class Scenario:
    """A simulated scene: rig file, scene kind and number of frames."""

    name: str
    rig: str  # file under rigs/
    scene: str  # room | board
    frames: int

    @property
    def rig_path(self) -> Path:
        return RIGS / self.rig

    def with_frames(self, frames: int) -> "Scenario":
        return Scenario(self.name, self.rig, self.scene, frames)


SCENARIOS = (
    Scenario("drone-stereo-back", "drone-stereo-back.yaml", "room", 60),
    Scenario("stereo-forward", "stereo-forward.yaml", "board", 40),
    Scenario("surround-6", "surround-6.yaml", "room", 60),
    Scenario("fisheye-stereo", "fisheye-stereo.yaml", "board", 40),
)


def scenario(name: str) -> Scenario:
    for s in SCENARIOS:
        if s.name == name:
            return s
    raise KeyError(name)


# ----------------------------------------------------------------------------- render + detect cache


@dataclass
class Dataset:
    """One simulated dataset with its detections (from the cache or freshly made)."""

    scenario: Scenario
    seed: int
    path: Path  # the dataset folder (images may have been removed)
    rig: Rig  # declared
    truth: Truth
    corners: dict[str, np.ndarray]  # board name -> (N, 3)
    views: list[BoardView]
    n_images: int
    sim_s: float  # wall seconds to render (when it was made)
    det_s: float  # wall seconds to detect (when it was made)
    cached: bool = False
    images_kept: bool = False

    @property
    def det_rate(self) -> float:
        return self.n_images / self.det_s if self.det_s > 0 else float("nan")


def code_hash() -> str:
    """Short hash of the code whose output the cache holds."""
    h = hashlib.sha256(f"{rigcal.__version__} cache {CACHE_FORMAT}".encode())
    src = Path(rigcal.__file__).parent
    for name in CODE_FILES:  # by name anywhere in the package (sim/, detect/, core/, data/)
        paths = sorted(src.rglob(name))
        if not paths:
            raise FileNotFoundError(f"bench.common.CODE_FILES: {name} is not in {src}")
        for path in paths:
            h.update(path.read_bytes())
    return h.hexdigest()[:10]


def dataset_dir(scn: Scenario, seed: int) -> Path:
    """The cache folder. BENCH_REUSE_CACHE=1 takes the newest cached render of the same
    scenario, frames and seed whatever code made it (for iterating on the analysis
    while the renderer or detector changes; never for quoted figures)."""
    stem = f"{scn.name}-f{scn.frames}-s{seed}"
    if os.environ.get("BENCH_REUSE_CACHE") == "1":
        old = sorted(CACHE.glob(f"{stem}-*/detections.pkl"), key=lambda p: p.stat().st_mtime)
        if old:
            return old[-1].parent
    return CACHE / f"{stem}-{code_hash()}"


def get_dataset(scn: Scenario, seed: int, keep_images: bool | None = None, log=None, jobs: int = JOBS) -> Dataset:
    """Render (seeded) and detect one scenario, or load both from the cache.

    keep_images: leave the PNGs on disk (needed to time `rigcal calibrate` on them, and
    for the guided pass); otherwise only rig.yaml, target.yaml, truth.yaml and the
    detections are kept. None (default): keep them when `--guided auto` would read
    them again (a rig with fisheye cameras)."""
    from rigcal.detect.guided import guided_cameras

    if keep_images is None:
        keep_images = bool(guided_cameras(rigcal.load_rig(scn.rig_path), "auto"))
    from rigcal.data.dataset import list_dataset
    from rigcal.detect.detect import detect_dataset
    from rigcal.sim.simulate import simulate_dataset
    from rigcal.core.target import load_target

    d = dataset_dir(scn, seed)
    meta_path = d / "detections.pkl"
    has_images = (d / "images").is_dir()
    if meta_path.is_file() and (has_images or not keep_images):
        with open(meta_path, "rb") as f:
            meta = pickle.load(f)
        return _dataset_from(scn, seed, d, meta, cached=True, images_kept=has_images)
    if log:
        log(f"  rendering {scn.name} ({scn.frames} frames, seed {seed}) ...")
    rig = rigcal.load_rig(scn.rig_path)
    d.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    simulate_dataset(rig, d, scene=scn.scene, frames=scn.frames, seed=seed, jobs=jobs, force=True,
                     rig_text=scn.rig_path.read_text(encoding="utf-8"), label=str(scn.rig_path))
    sim_s = time.perf_counter() - t0
    target = load_target(d / "target.yaml")
    images = list_dataset(d, rig)
    det = detect_dataset(images, target, rig=rig, jobs=jobs, progress=False)
    meta = {"views": view_tuples(det.views), "n_images": images.n_images, "sim_s": sim_s, "det_s": det.seconds}
    tmp = meta_path.with_suffix(".tmp")
    with open(tmp, "wb") as f:
        pickle.dump(meta, f)
    os.replace(tmp, meta_path)
    if not keep_images:
        shutil.rmtree(d / "images", ignore_errors=True)
    return _dataset_from(scn, seed, d, meta, cached=False, images_kept=keep_images)


def view_tuples(views) -> list[tuple]:
    """BoardView -> the cache's plain tuples (CACHE_FORMAT 2)."""
    return [(v.camera, v.frame, v.board, np.asarray(v.ids), np.asarray(v.uv, float), bool(v.ambiguous),
             None if v.sigma is None else np.asarray(v.sigma, float)) for v in views]


def _dataset_from(scn: Scenario, seed: int, d: Path, meta: dict, cached: bool, images_kept: bool) -> Dataset:
    from rigcal.core.target import load_target

    rig = rigcal.load_rig(d / "rig.yaml")
    target = load_target(d / "target.yaml")
    views = [BoardView(*v) for v in meta["views"]]
    return Dataset(scn, seed, d, rig, load_truth(d / "truth.yaml"), {b.name: b.corners for b in target.boards},
                   views, meta["n_images"], meta["sim_s"], meta["det_s"], cached, images_kept)


# ----------------------------------------------------------------------------- calibration + errors


def calibrate(views: list[BoardView], rig: Rig, corners: dict, distortion: str = "auto",
              weight_corners: bool = False, rerefine=None) -> Calibration:
    """pipeline.calibrate_views on detections alone: no guided pass unless `rerefine` (see
    calibrate_dataset, which does what `rigcal calibrate` does)."""
    return calibrate_views(views, rig, corners, distortion=distortion, weight_corners=weight_corners,
                           rerefine=rerefine)


def folder_hook(folder: Path, rig: Rig, mode: str = "auto", jobs: int = 1):
    """The rerefine hook `rigcal calibrate --guided MODE` builds for the dataset in `folder`
    (its images and target.yaml), or None when MODE guides none of rig's cameras."""
    from rigcal.data.dataset import list_dataset
    from rigcal.detect.guided import guided_cameras, rerefiner
    from rigcal.core.target import load_target

    if not guided_cameras(rig, mode):
        return None
    return rerefiner(list_dataset(folder, rig), rig, load_target(folder / "target.yaml"), jobs, mode)


def guided_hook(ds: Dataset, mode: str = "auto", jobs: int = 1):
    """folder_hook for a rendered dataset. Raises if it would guide a camera but the
    render's images were not kept: a benchmark must not quietly measure the detector's
    corners where the command line would re-measure them."""
    from rigcal.detect.guided import guided_cameras

    if guided_cameras(ds.rig, mode) and not ds.images_kept:
        raise RuntimeError(f"{ds.path}: --guided {mode} needs the images; get_dataset(keep_images=True)")
    return folder_hook(ds.path, ds.rig, mode, jobs)


def calibrate_dataset(ds: Dataset, distortion: str = "auto", guided: str = "auto", jobs: int = 1,
                      weight_corners: bool = False) -> Calibration:
    """What `rigcal calibrate` does with the dataset's detections, the guided pass
    (--guided, default auto: fisheye cameras) included."""
    return calibrate(ds.views, ds.rig, ds.corners, distortion, weight_corners, guided_hook(ds, guided, jobs))


def truth_in_output_frame(cal: Calibration, truth_rig: Rig) -> dict[str, np.ndarray]:
    """The true T_body_cam of every camera re-expressed in the frame the calibration
    reports in: the true rig aligned to the DECLARED rig by the same rule
    (body_frame.reference_transform), not truth.yaml's own body frame."""
    T_true = np.array([truth_rig.camera(n).T_body_cam for n in cal.cam_names])
    T_out_true = reference_transform(T_true, cal.declared, cal.reference)
    return {n: T_out_true @ T for n, T in zip(cal.cam_names, T_true)}


def pose_errors_body(cal: Calibration, truth_rig: Rig) -> dict[str, np.ndarray]:
    """Per camera 6-vector [rotation error about body F, L, U (deg), position error along
    F, L, U (mm)], calibrated minus truth, both in the output body frame; the same
    parameterisation as the solver's covariance (body_frame._pose_error_vector)."""
    ref = truth_in_output_frame(cal, truth_rig)
    out = {}
    for c in cal.rig.cameras:
        T_t = ref[c.name]
        rot = geo.rotvec_from_R(c.T_body_cam[:3, :3] @ T_t[:3, :3].T)
        out[c.name] = np.concatenate([np.degrees(rot), 1000.0 * (c.T_body_cam[:3, 3] - T_t[:3, 3])])
    return out


MIN_FRAME_CORNERS = 4


def crb_pairs(cal: Calibration, truth: Truth, sigma_px: float) -> tuple[dict, int]:
    """rigcal.camcal.bounds.pair_bounds, robust to frames the calibration left with fewer than
    MIN_FRAME_CORNERS inlier corners: such a frame's 6 pose unknowns absorb its few
    residuals exactly, so it carries no information about the cameras, but its singular
    block makes pair_bounds raise (rigcal.camcal.solve.camera_covariance inverts every frame
    block). Their corners are left out of the bound. Returns (bounds, frames left out)."""
    from dataclasses import replace

    from rigcal.camcal.bounds import pair_bounds

    o = cal.obs
    n = np.bincount(o.frame[cal.inliers], minlength=len(cal.frames))
    weak = n < MIN_FRAME_CORNERS
    use = cal.inliers & ~weak[o.frame]
    dropped = int(np.sum(weak & (n > 0)))
    target = cal if dropped == 0 else replace(cal, inliers=use)
    try:
        return pair_bounds(target, truth, sigma_px), dropped
    except np.linalg.LinAlgError:
        return {}, dropped


def rig_scale_ppm(cal: Calibration, truth_rig: Rig) -> float:
    """Least-squares scale error of the calibrated camera positions about their centroid
    against the truth (output frame), parts per million: a rig that came out uniformly
    too big or too small (a systematic error no white noise produces)."""
    ref = truth_in_output_frame(cal, truth_rig)
    P = np.array([ref[n][:3, 3] for n in cal.cam_names])
    Q = np.array([cal.rig.camera(n).T_body_cam[:3, 3] for n in cal.cam_names])
    Pc, Qc = P - P.mean(0), Q - Q.mean(0)
    return float(1e6 * np.sum(Pc * (Qc - Pc)) / np.sum(Pc**2))


def true_projections(cal: Calibration, truth: Truth) -> np.ndarray | None:
    """(M, 2) exact projections of every observation the calibration was given,
    through the true rig and true board/frame poses (None when truth has no poses)."""
    from rigcal.camcal.bounds import true_state
    from rigcal.camcal.solve import Problem

    st = true_state(cal, truth)
    if st is None:
        return None
    pb = Problem(cal.obs, st, cal.problem.gauge_cam, cal.problem.gauge_board)
    r = pb.residuals(pb.x0()).reshape(-1, 2)
    return cal.obs.uv + r


def gaussian_views(cal: Calibration, uv_true: np.ndarray, corners: dict, sigma: float,
                   rng: np.random.Generator) -> list[BoardView]:
    """The calibration's views with the detected corners replaced by their true
    projections plus isotropic Gaussian noise of `sigma` px (ids recovered by matching
    board points, so the views are the same corners the detector found)."""
    o = cal.obs
    uv = uv_true + rng.normal(0.0, sigma, uv_true.shape)
    out = []
    for k in np.unique(o.view):
        m = np.nonzero(o.view == k)[0]
        board = cal.boards[int(o.board[m[0]])]
        P = corners[board]
        # row of the board's corner table for each observation's board point
        d = np.linalg.norm(P[None, :, :] - o.p_board[m][:, None, :], axis=2)
        ids = np.argmin(d, axis=1)
        out.append(BoardView(cal.cam_names[int(o.cam[m[0]])], cal.frames[int(o.frame[m[0]])], board, ids, uv[m]))
    return out


def pair_key(a: str, b: str) -> str:
    return f"{a}/{b}"


def rig_errors(est: Rig, truth_rig: Rig) -> dict:
    """compare_rigs with string keys (JSON-ready)."""
    r = compare_rigs(est, truth_rig)
    return {"cameras": r["cameras"], "pairs": {pair_key(*k): v for k, v in r["pairs"].items()},
            "stereo": {pair_key(*k): v for k, v in r["stereo"].items()}}


# ----------------------------------------------------------------------------- the true rig


def perturbed_truth(rig: Rig, seed: int) -> Rig:
    """The library's own mounting/lens perturbation (what `rigcal simulate` applies)."""
    from rigcal.sim.simulate import perturb_rig

    return perturb_rig(rig, np.random.default_rng([seed, 1]))


# ----------------------------------------------------------------------------- output


def md_table(headers: list[str], rows: list[list], title: str | None = None) -> str:
    """A markdown table (readable in a terminal, pasteable into the README)."""
    cells = [[str(h) for h in headers]] + [[_cell(x) for x in r] for r in rows]
    w = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    line = lambda r: "| " + " | ".join(c.ljust(w[i]) for i, c in enumerate(r)) + " |"  # noqa: E731
    out = [f"\n**{title}**\n"] if title else []
    out.append(line(cells[0]))
    out.append("|" + "|".join("-" * (x + 2) for x in w) + "|")
    out.extend(line(r) for r in cells[1:])
    return "\n".join(out)


def _cell(x) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        if not np.isfinite(x):
            return "-"
        a = abs(x)
        if a == 0:
            return "0"
        if a >= 100:
            return f"{x:.1f}"
        if a >= 1:
            return f"{x:.2f}"
        if a >= 0.01:
            return f"{x:.3f}"
        if a >= 0.001:
            return f"{x:.4f}"
        return f"{x:.1e}"
    return str(x)


def write_json(name: str, data) -> Path:
    OUT.mkdir(parents=True, exist_ok=True)
    p = OUT / f"{name}.json"
    tmp = p.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1, default=_json_default), encoding="utf-8")
    os.replace(tmp, p)
    return p


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, tuple):
        return list(o)
    raise TypeError(type(o).__name__)


def say(*parts) -> None:
    print(*parts, flush=True)


def machine() -> dict:
    """What the figures were measured on (load average: other work inflates wall times)."""
    import platform

    try:
        load = os.getloadavg()
    except OSError:
        load = (float("nan"),) * 3
    return {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform(),
            "load_avg_1_5_15": [round(x, 2) for x in load], "date": time.strftime("%Y-%m-%d %H:%M %Z"),
            "opencv": __import__("cv2").__version__, "numpy": np.__version__}


@dataclass
class Timer:
    """Wall and CPU seconds (this process and its waited-for children) of a block."""

    wall: float = 0.0
    cpu: float = 0.0
    _t: tuple = field(default=(), repr=False)

    def __enter__(self):
        self._t = (time.perf_counter(), _cpu())
        return self

    def __exit__(self, *exc):
        self.wall = time.perf_counter() - self._t[0]
        self.cpu = _cpu() - self._t[1]


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


if __name__ == "__main__":  # pragma: no cover
    print(code_hash(), file=sys.stderr)


# ----------------------------------------------------------------------------- parallel runs


def run_pool(fn, tasks: list, workers: int = JOBS) -> list:
    """fn(*task) for every task in `workers` forked processes, results in task order.

    Renders and detections inside a task run with one process each, so two tasks keep
    both cores busy through the serial parts (calibration) too."""
    if workers <= 1 or len(tasks) <= 1:
        return [fn(*t) for t in tasks]
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    ctx = mp.get_context("fork")
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=ctx) as pool:
        futures = [pool.submit(fn, *t) for t in tasks]
        return [f.result() for f in futures]


# ----------------------------------------------------------------------------- sizes in their own processes


def run_sizes(module: str, sizes, log, label: str) -> list[dict]:
    """`python -m <module> --one N` for each N in sizes, each in its own process (so its
    peak resident memory is that size's alone); the JSON each prints last."""
    import subprocess

    out = []
    for n in sizes:
        log(f"{label} x {n} frames ...")
        p = subprocess.run([sys.executable, "-m", module, "--one", str(n)], cwd=ROOT, capture_output=True,
                           text=True, check=True)
        out.append(json.loads(p.stdout.strip().splitlines()[-1]))
    return out


def sizes_main(argv, doc: str, frames, one, run, tables, name: str) -> None:
    """The command line of a benchmark over sizes: --frames N ... (all, a table and
    bench/out/<name>.json) or --one N (one size, its JSON on stdout)."""
    import argparse

    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, nargs="+", default=list(frames))
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(one(a.one)))
        return
    res = run(a.frames)
    say(tables(res))
    write_json(name, {"results": res})
