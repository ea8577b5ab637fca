"""The fisheye noise-limit excess, re-measured on images from the independent renderer.

This measures the DETECTOR's corners (`rigcal calibrate --guided off`): it was written to
find where the fisheye excess came from, before the guided pass (rigcal.detect.guided, the
default for fisheye cameras) removed it; bench.noise_limit and bench.archive.guided measure that.

bench.noise_limit finds the fisheye stereo pair's relative rotation 1.6x its Cramér-Rao
bound on rigcal's own renders (pinhole rigs 0.7-1.3x). Is that rigcal's renderer
(texture level choice, sampling of the compressed periphery) or its detector? Here the
images come from tests/support/indie_render.py (OpenCV and the spec only, exact rays, S x S
box-filtered supersampling) and everything after the render is noise_limit's own
machinery: rigcal detects (detect_dataset on list_dataset), bench.common.calibrate
calibrates, the bound is crb_pairs with the measured corner noise (detected vs true
projection, measured_corner_noise), and the same corners replaced by true projection +
white noise of that sigma (gaussian_views) give the solver's own ratio.

Five scenes per seed. Two are indie_render.waved_scene (a board waved before a static
pair, 20 frames, lossless grey PNGs, no dropped or corrupt files):
  fisheye  fisheye=True: rigs/fisheye-stereo.yaml's pair (800 x 800, f 250, 0.08 m) and
           simulate.py's `board` scene board for it (11 x 8 squares of 0.216 m, 0.5-3 m)
  pinhole  the pinhole stereo pair (640 x 480, f 420, 0.15 m), the control: ~1.0 if the
           machinery is right
and, the decisive pair, noise_limit's own fisheye-stereo datasets (bench.common.get_dataset,
20 frames, same seeds: rigcal's planner, truth and renderer) against the SAME true rig,
board and board poses rendered by indie_render:
  rigcal-render  rigcal's images (what noise_limit measures)
  rigcal-poses   indie_render's images of that very scene
and the cross cell, which separates the planner's geometry from the renderer:
  fisheye-rigcal-render  indie's waved fisheye truth (cameras, board, the 20 poses of
                 `fisheye` above) rendered by rigcal's own renderer (rigcal.sim.simulate's
                 board-scene rendering, simulate_dataset's noise 2 and no blur)

Ratios are RMS(error over seeds) / RMS(bound over seeds), as noise_limit reports them;
one seed's error / bound strays a lot (0.2-2.6 over 10 seeds), so a third table gives
the per-seed quartiles and a 90 % bootstrap interval (over seeds) of the RMS ratio.
The truth's distortion is cut to the length of the model rigcal chose when the cut
coefficients are zero (indie's pinhole truth has k3 = 0, rigcal picks radtan4):
rigcal.camcal.bounds.true_state takes the truth's length, and a bound with a free k3 the
calibration did not have is too large (the ratio comes out too small).

S = 4 (4 x 4 samples per pixel) by default: 10 seeds of the first four scenes take ~10 min
on 2 processes; fisheye-rigcal-render costs ~12 s of CPU a seed. --scenes and --first-seed
run some scenes and seeds only and keep the last JSON's other runs (same samples, frames).

    python -m bench.indie_noise [--seeds 10] [--first-seed 0] [--samples 4] [--scenes a,b] [--tables]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

import rigcal
from rigcal.camcal.bounds import measured_corner_noise
from rigcal.data.truth import load_truth
from rigcal.errors import RigcalError

from .common import (OUT, Timer, calibrate, gaussian_views, md_table, run_pool, say, true_projections,
                     write_json)
from .noise_limit import error_to_bound, pair_stats, view_offsets

from tests.support import indie_render as ir

FRAMES = 20
SCENES = ("fisheye", "pinhole", "rigcal-render", "rigcal-poses", "fisheye-rigcal-render")
WORK = OUT / "indie_noise"


def scene_from_rigcal(seed: int) -> tuple:
    """noise_limit's fisheye-stereo dataset for `seed` (rendered by rigcal, cached) and an
    indie_render Scene of the same truth: cameras (K, distortion, T_body_cam; the field cut
    where rigcal cuts it, min(monotonic, 110 deg)), board and per-frame board poses.
    Returns (bench.common.Dataset, Scene)."""
    import yaml

    from .common import get_dataset, scenario

    ds = get_dataset(scenario("fisheye-stereo").with_frames(FRAMES), seed, jobs=1)
    cams = []
    for c in ds.truth.rig.cameras:
        m = c.intrinsics
        K = np.array([[m.fx, 0, m.cx], [0, m.fy, m.cy], [0, 0, 1.0]])
        k = np.array(m.dist, float)
        cams.append(ir.Camera(c.name, "fisheye", (m.width, m.height), K, k, c.T_body_cam, ir._fisheye_limit_deg(k)))
    t = yaml.safe_load((ds.path / "target.yaml").read_text(encoding="utf-8"))["boards"][0]
    board = ir.Board(t["name"], tuple(t["squares"]), t["square_length"], t["marker_length"], t["first_marker_id"],
                     t.get("legacy_pattern", False), t["dictionary"])
    stems = tuple(sorted(ds.truth.T_world_body))
    declared = yaml.safe_load((ds.path / "rig.yaml").read_text(encoding="utf-8"))
    scene = ir.Scene(declared, tuple(cams), (board,), stems, {s: ds.truth.T_world_body[s] for s in stems},
                     {s: {board.name: ds.truth.board_pose(s, board.name)} for s in stems}, False,
                     {c.name: ir.Photometry(0.6, 2.0, 1.0, 2.2, 0.25) for c in cams})
    return ds, scene


def render_indie_scene_with_rigcal(scene, out: Path, seed: int) -> None:
    """Write `scene` (an indie_render Scene: true cameras, board, per-frame poses) as a
    dataset under `out` whose images come from rigcal's own renderer (rigcal.sim.simulate's
    board-scene rendering with simulate_dataset's defaults: noise 2, no blur) instead of
    rigcal's planner: the scene's truth.yaml is read back as rigcal's truth and its poses
    become a simulate.Scene. rig.yaml, target.yaml and truth.yaml are indie_render's."""
    from rigcal.sim.simulate import RenderSettings, Scene, render_all
    from rigcal.core.target import load_target

    out.mkdir(parents=True)
    ir._write_yaml(out / "rig.yaml", scene.declared)
    ir._write_yaml(out / "target.yaml", {"boards": [b.yaml_entry() for b in scene.boards]})
    ir._write_yaml(out / "truth.yaml", ir._truth_doc(scene))
    truth = load_truth(out / "truth.yaml")
    target = load_target(out / "target.yaml")
    stems = tuple(sorted(truth.T_world_body))
    plan = Scene(name="board", target=target, frames=stems,
                 T_world_body=np.stack([truth.T_world_body[s] for s in stems]),
                 T_world_board=np.stack([[truth.board_pose(s, b.name) for b in target.boards] for s in stems]),
                 moving_boards=True)
    render_all(truth.rig, plan, RenderSettings(seed=seed, noise=2.0, blur=0.0), out, jobs=1, progress=False)


def _rigcal_dataset(seed: int) -> None:
    from .common import get_dataset, scenario

    get_dataset(scenario("fisheye-stereo").with_frames(FRAMES), seed, jobs=1)


def render_and_detect(kind: str, seed: int, S: int) -> tuple:
    """Render one seeded scene with indie_render and detect it with rigcal.
    Returns (declared rig, truth, board corners {name: (N, 3)}, views, render s, detect s)."""
    from rigcal.data.dataset import list_dataset
    from rigcal.detect.detect import detect_dataset
    from rigcal.core.target import load_target

    if kind == "rigcal-render":
        ds = scene_from_rigcal(seed)[0]
        return ds.rig, ds.truth, ds.corners, ds.views, ds.sim_s, ds.det_s
    d = WORK / f"{kind}-s{seed}"
    shutil.rmtree(d, ignore_errors=True)
    if kind == "rigcal-poses":
        scene = scene_from_rigcal(seed)[1]
    else:
        scene = ir.waved_scene(n_frames=FRAMES, seed=seed, fisheye=kind.startswith("fisheye"))
    with Timer() as tr:
        if kind == "fisheye-rigcal-render":
            render_indie_scene_with_rigcal(scene, d, seed)
        else:
            ir.write_dataset(scene, d, seed=seed, S=S, drop=0, corrupt=False, formats=((".png", False),))
    rig = rigcal.load_rig(d / "rig.yaml")
    target = load_target(d / "target.yaml")
    with Timer() as td:
        det = detect_dataset(list_dataset(d, rig), target, rig=rig, jobs=1, progress=False)
    views = list(det.views)
    truth = load_truth(d / "truth.yaml")
    shutil.rmtree(d, ignore_errors=True)
    return rig, truth, {b.name: b.corners for b in target.boards}, views, tr.wall, td.wall


def trimmed_truth(cal, truth):
    """truth with each camera's distortion cut to the calibrated model's length when the
    coefficients cut are exactly zero (the same lens), else unchanged."""
    cams = []
    for c in truth.rig.cameras:
        m = c.intrinsics
        n = cal.state.intrinsics[cal.cam_names.index(c.name)].n_dist if c.name in cal.cam_names else len(m.dist)
        if len(m.dist) > n and not any(m.dist[n:]):
            c = replace(c, intrinsics=replace(m, dist=tuple(m.dist[:n])))
        cams.append(c)
    return replace(truth, rig=truth.rig.with_cameras(cams))


def periphery(cal, truth) -> dict:
    """Where the used corners sit: share with distorted radius theta_d = |(uv - c) / f|
    (rad; about the angle from the axis for a fisheye) above 1.0 and 1.4."""
    th = np.zeros(len(cal.obs))
    for ci, n in enumerate(cal.cam_names):
        m = truth.rig.camera(n).intrinsics
        k = cal.obs.cam == ci
        th[k] = np.hypot((cal.obs.uv[k, 0] - m.cx) / m.fx, (cal.obs.uv[k, 1] - m.cy) / m.fy)
    th = th[cal.inliers]
    return {"share_theta_d_gt_1.0": float(np.mean(th > 1.0)), "share_theta_d_gt_1.4": float(np.mean(th > 1.4))}


def run_seed(kind: str, seed: int, S: int) -> dict:
    """One (scene, seed) in a worker process; a failure is reported, not raised."""
    try:
        return _run_seed(kind, seed, S)
    except (np.linalg.LinAlgError, RigcalError, ValueError) as e:
        return {"scene": kind, "seed": seed, "failed": f"{type(e).__name__}: {e}"}


def _run_seed(kind: str, seed: int, S: int) -> dict:
    rig, truth, corners, views, render_s, detect_s = render_and_detect(kind, seed, S)
    with Timer() as tc:
        cal = calibrate(views, rig, corners)
    truth = trimmed_truth(cal, truth)
    sigma = measured_corner_noise(cal, truth)
    uv_true = true_projections(cal, truth)
    rng = np.random.default_rng([seed, 7])
    gcal = calibrate(gaussian_views(cal, uv_true, corners, sigma, rng), rig, corners)
    return {"scene": kind, "seed": seed, "sigma_px": sigma, "render_s": render_s, "detect_s": detect_s,
            "calibration_s": tc.wall, "models": [cal.stats[n].distortion_model for n in cal.cam_names],
            "corners_used": len(cal.obs), "corners_detected": int(sum(len(v.ids) for v in views)),
            "auto": pair_stats(cal, truth, sigma), "gauss": pair_stats(gcal, truth, sigma),
            **view_offsets(cal, uv_true, sigma), **periphery(cal, truth)}


def run(seeds: int = 10, S: int = 4, scenes: tuple[str, ...] = SCENES, keep: list[dict] | None = None,
        first_seed: int = 0, log=say) -> dict:
    """Run `scenes` x range(first_seed, seeds); `keep`: earlier runs (the last JSON's),
    carried into the result unless re-run, so a scene can be added or given more seeds
    without re-running the rest."""
    tasks = [(k, s, S) for k in scenes for s in range(first_seed, seeds)]
    log(f"indie noise: {len(tasks)} (scene, seed) runs, {S}x{S} samples per pixel: render, detect, calibrate 2x ...")
    with Timer() as t:
        if {"rigcal-render", "rigcal-poses"} & set(scenes):
            # rigcal's renders first (cached), so two tasks of one seed never render the same folder at once
            run_pool(_rigcal_dataset, [(s,) for s in range(first_seed, seeds)])
        runs = run_pool(run_seed, tasks)
    done = {(k, s) for k, s, _ in tasks}
    runs = [r for r in keep or [] if (r["scene"], r["seed"]) not in done] + runs
    return {"runs": runs, "summary": summarise(runs), "seconds": t.wall, "seeds": seeds, "samples": S,
            "frames": FRAMES, "scenes_run": list(scenes)}


def per_seed_spread(rs: list[dict], q: str = "rot_deg", pair: str = "left/right", n_boot: int = 2000) -> dict:
    """How far one seed's error / its bound strays: quartiles and extremes of the per-seed
    ratios, and a 90 % bootstrap interval (over seeds, seeded) of the RMS-over-seeds ratio,
    which is what the tables quote."""
    a = np.array([(r["auto"][pair][q], r["auto"][pair][f"bound_{q}"]) for r in rs if pair in r["auto"]])
    per = a[:, 0] / a[:, 1]
    idx = np.random.default_rng(0).integers(0, len(a), (n_boot, len(a)))
    boot = np.sqrt(np.mean(a[idx, 0] ** 2, axis=1) / np.mean(a[idx, 1] ** 2, axis=1))
    return {"min": float(per.min()), "q25": float(np.percentile(per, 25)), "median": float(np.median(per)),
            "q75": float(np.percentile(per, 75)), "max": float(per.max()),
            "rms_ratio_90": [float(np.percentile(boot, 5)), float(np.percentile(boot, 95))]}


def summarise(runs: list[dict]) -> dict:
    out = {}
    for kind in SCENES:
        rs = [r for r in runs if r["scene"] == kind and "failed" not in r]
        if not rs:
            continue
        out[kind] = {"seeds": len(rs), "sigma_px": float(np.mean([r["sigma_px"] for r in rs])),
                     "view_offset_rms_px": float(np.sqrt(np.mean([r["view_offset_rms_px"] ** 2 for r in rs]))),
                     "white_expectation_px": float(np.sqrt(np.mean([r["white_expectation_px"] ** 2 for r in rs]))),
                     **{k: float(np.mean([r[k] for r in rs])) for k in ("share_theta_d_gt_1.0", "share_theta_d_gt_1.4")},
                     **{v: {q: error_to_bound(rs, v, q) for q in ("rot_deg", "trans_mm")} for v in ("auto", "gauss")},
                     "spread": {q: per_seed_spread(rs, q) for q in ("rot_deg", "trans_mm")}}
    return out


def tables(res: dict) -> str:
    out = [f"\n## Noise limit on independent renders (up to {res['seeds']} seeds, {res['frames']} frames, "
           f"{res['samples']}x{res['samples']} samples per pixel)\n"]
    rows = []
    for r in res["runs"]:
        if "failed" in r:
            rows.append([r["scene"], r["seed"], "-", "-", "-", "-", "-", f"FAILED: {r['failed']}"])
            continue
        for pair, v in r["auto"].items():
            g = r["gauss"].get(pair, {})
            rows.append([r["scene"], r["seed"], r["sigma_px"], v["rot_deg"] / v["bound_rot_deg"],
                         v["trans_mm"] / v["bound_trans_mm"],
                         g["rot_deg"] / g["bound_rot_deg"] if g else None,
                         g["trans_mm"] / g["bound_trans_mm"] if g else None, "/".join(r["models"])])
    out.append(md_table(["scene", "seed", "sigma px", "rot / CRB", "trans / CRB", "white: rot / CRB",
                         "white: trans / CRB", "models"], rows, "per seed (one seed's error / its bound)"))
    rows = []
    for kind, s in res["summary"].items():
        for pair in s["auto"]["rot_deg"]:
            a, g = s["auto"], s["gauss"]
            rows.append([kind, pair, s["seeds"], s["sigma_px"], a["rot_deg"][pair]["ratio"],
                         a["trans_mm"][pair]["ratio"], g["rot_deg"].get(pair, {}).get("ratio"),
                         g["trans_mm"].get(pair, {}).get("ratio"), s["view_offset_rms_px"],
                         s["white_expectation_px"], s["share_theta_d_gt_1.0"], s["share_theta_d_gt_1.4"]])
    out.append(md_table(["scene", "pair", "seeds", "sigma px", "rot / CRB", "trans / CRB", "white: rot / CRB",
                         "white: trans / CRB", "view offset px", "white expect. px", "theta_d > 1", "> 1.4"], rows,
                        "over seeds: RMS error / RMS bound (white: detected corners replaced by truth + white noise)"))
    rows = []
    for kind, s in res["summary"].items():
        for q in ("rot_deg", "trans_mm"):
            sp = s.get("spread", {}).get(q)
            if sp:
                rows.append([kind, q, s["seeds"], s["auto"][q]["left/right"]["ratio"], *sp["rms_ratio_90"], sp["min"],
                             sp["q25"], sp["median"], sp["q75"], sp["max"]])
    out.append(md_table(["scene", "quantity", "seeds", "RMS ratio", "90 % lo", "90 % hi", "seed min", "q25",
                         "median", "q75", "seed max"], rows,
                        "spread over seeds (left/right): bootstrap interval of the RMS ratio, per-seed error / bound"))
    out.append(f"\n{res['seconds']:.0f} s on 2 processes")
    return "\n".join(out)


def main(argv=None) -> None:
    """Run and print; --tables reprints bench/out/indie_noise.json without running."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--samples", type=int, default=4, help="S: S x S box-filtered samples per pixel")
    ap.add_argument("--first-seed", type=int, default=0, help="run seeds first-seed .. seeds - 1")
    ap.add_argument("--scenes", default=",".join(SCENES),
                    help="comma-separated scenes to run; the last JSON's other runs are kept")
    ap.add_argument("--tables", action="store_true", help="reprint the tables of the last run's JSON")
    a = ap.parse_args(argv)
    last = OUT / "indie_noise.json"
    if a.tables:
        res = json.loads(last.read_text(encoding="utf-8"))
        res["summary"] = summarise(res["runs"])  # JSONs from before the spread columns
        say(tables(res))
        return
    scenes = tuple(x for x in a.scenes.split(",") if x)
    if not scenes or set(scenes) - set(SCENES):
        ap.error(f"--scenes: expected some of {', '.join(SCENES)}, got {a.scenes!r}")
    keep = None
    if (set(scenes) != set(SCENES) or a.first_seed > 0) and last.is_file():
        old = json.loads(last.read_text(encoding="utf-8"))
        if old.get("samples") == a.samples and old.get("frames") == FRAMES:
            keep = old["runs"]
    res = run(a.seeds, a.samples, scenes, keep, a.first_seed)
    write_json("indie_noise", res)
    say(tables(res))


if __name__ == "__main__":
    main()
