"""Monte Carlo check of the reported uncertainty.

Is the sigma rigcal writes per camera (rotation about body F, L, U in deg; position
along F, L, U in mm) the real spread of its errors? Over many seeds of the SAME scene
(same rig, same board and frame poses; only the pixel noise changes) the fraction of
true errors inside the predicted +-2 sigma should be about 95 % (goal 90-98 %) for every
extrinsic parameter, and RMS(error / sigma) about 1.

Frame: the calibrated rig is expressed in the body frame fitted to the DECLARED rig
(body_frame.reference_transform, --reference aligned), so each calibrated pose is compared
with the TRUE rig re-expressed by the same rule, not with truth.yaml's own body frame.

Two sources:

* synthetic (default 30 seeds, with --distortion auto and with the truth's own model): exact projections of four wall boards around the
  drone-stereo-back rig (30 frames), plus white Gaussian noise of 0.1 px;
* rendered: the noise-limit runs (bench/noise_limit.py: 10 seeds x 4 scenes, each
  seed a different scene), pooled; there the detector's errors are what they are.

    python -m bench.montecarlo [--seeds 40] [--sigma 0.1]
"""

from __future__ import annotations

import argparse

import numpy as np

import rigcal
from rigcal.sim.synthetic import room_scene, with_noise

from .common import RIGS, Timer, calibrate, md_table, perturbed_truth, pose_errors_body, run_pool, say, write_json
from .noise_limit import truth_model

PARAMS = ("rot F", "rot L", "rot U", "pos F", "pos L", "pos U")
RIG = "drone-stereo-back.yaml"
FRAMES = 30
_SCENE = {}


def _scene():
    """The fixed scene (built once per process; seeded, so every worker builds the same)."""
    if not _SCENE:
        rig = rigcal.load_rig(RIGS / RIG)
        truth_rig = perturbed_truth(rig, 0)
        _SCENE["v"] = (rig, truth_rig, room_scene(truth_rig, np.random.default_rng([0, 3]), FRAMES))
    return _SCENE["v"]


def run_seed(seed: int, sigma_px: float, distortion: str) -> dict:
    rig, truth_rig, sc = _scene()
    views = with_noise(sc.views, sigma_px, np.random.default_rng([seed, 11]))
    with Timer() as t:
        cal = calibrate(views, rig, sc.corners, distortion)
    err = pose_errors_body(cal, truth_rig)
    out = {}
    for n in cal.cam_names:
        st = cal.stats[n]
        out[n] = {"error": err[n].tolist(), "sigma": np.concatenate([st.sigma_rotation_deg,
                                                                     st.sigma_position_mm]).tolist()}
    return {"seed": seed, "cameras": out, "seconds": t.wall, "residual_sigma_px": cal.sigma_px,
            "models": [cal.stats[n].distortion_model for n in cal.cam_names]}


def run(seeds: int = 30, sigma_px: float = 0.1, log=say) -> dict:
    """Both --distortion auto (what a user gets) and the truth's own model (radtan5:
    k1, k2, p1, p2 non-zero, k3 = 0), to tell covariance errors from model-selection bias."""
    variants = ("auto", truth_model(_scene()[1]))
    log(f"monte carlo: {seeds} seeds x {len(variants)} models of one synthetic scene ({RIG}, {FRAMES} frames, "
        f"{sigma_px} px noise) ...")
    with Timer() as t:
        runs = run_pool(run_seed, [(s, sigma_px, v) for v in variants for s in range(seeds)])
    out = {"seeds": seeds, "sigma_px": sigma_px, "variants": {}, "seconds": t.wall}
    for k, v in enumerate(variants):
        rs = runs[k * seeds:(k + 1) * seeds]
        samples = {}
        for r in rs:
            for n, c in r["cameras"].items():
                samples.setdefault(n, []).append((c["error"], c["sigma"]))
        models = {}
        for r in rs:
            for m in r["models"]:
                models[m] = models.get(m, 0) + 1
        out["variants"][v] = {"coverage": coverage(samples), "runs": rs, "models_chosen": models}
    return out


def coverage(samples: dict) -> dict:
    """{camera: {param: {within_2sigma, rms_normalised, n}}} from (error, sigma) 6-vectors."""
    out = {}
    for n, s in samples.items():
        e = np.array([x[0] for x in s])
        sg = np.array([x[1] for x in s])
        z = e / np.maximum(sg, 1e-300)
        out[n] = {p: {"within_2sigma": float(np.mean(np.abs(z[:, i]) <= 2.0)),
                      "rms_normalised": float(np.sqrt(np.mean(z[:, i] ** 2))), "n": int(len(z))}
                  for i, p in enumerate(PARAMS)}
    return out


def rendered_samples(noise_limit: dict, key: str = "coverage") -> dict:
    """Pool the noise-limit runs' (error, sigma) per scenario/camera."""
    samples = {}
    for r in noise_limit["runs"]:
        for n, c in (r.get(key) or {}).items():
            samples.setdefault(f"{r['scenario']}: {n}", []).append((c["error"], c["sigma"]))
    return samples


def _rows(cov: dict) -> list[list]:
    rows = []
    for n, c in cov.items():
        rows.append([n, c[PARAMS[0]]["n"]] + [f"{100 * c[p]['within_2sigma']:.0f} % ({c[p]['rms_normalised']:.2f})"
                                              for p in PARAMS])
    return rows


def _pooled(cov: dict) -> list:
    """Across cameras, per parameter: weighted mean coverage and RMS(z)."""
    row = []
    for p in PARAMS:
        n = np.array([c[p]["n"] for c in cov.values()])
        w = np.array([c[p]["within_2sigma"] for c in cov.values()])
        z = np.array([c[p]["rms_normalised"] for c in cov.values()])
        row.append(f"{100 * np.sum(w * n) / n.sum():.0f} % ({np.sqrt(np.sum(z**2 * n) / n.sum()):.2f})")
    return row


def tables(res: dict, noise_limit: dict | None = None) -> str:
    head = ["camera", "seeds"] + [f"{p}" for p in PARAMS]
    parts = []
    for v, r in res["variants"].items():
        cov = r["coverage"]
        rows = _rows(cov) + [["all cameras", sum(c[PARAMS[0]]["n"] for c in cov.values())] + _pooled(cov)]
        chosen = ", ".join(f"{m} x{k}" for m, k in sorted(r["models_chosen"].items()))
        parts.append(md_table(head, rows, f"Monte Carlo, synthetic, --distortion {v} ({res['seeds']} noise seeds of "
                                          f"one scene, {RIG}, {res['sigma_px']} px white noise; models chosen: "
                                          f"{chosen}): share of true errors within the predicted +-2 sigma "
                                          f"(RMS error/sigma); goal 90-98 %"))
    if noise_limit:
        for key, label in (("coverage", "detected corners"), ("gauss_coverage", "true projections + white noise")):
            c = coverage(rendered_samples(noise_limit, key))
            if not c:
                continue
            by_scn = {}
            for k, v in c.items():
                by_scn.setdefault(k.split(":")[0], {})[k] = v
            rows = [[s, sum(v[PARAMS[0]]["n"] for v in cc.values())] + _pooled(cc) for s, cc in by_scn.items()]
            parts.append(md_table(["scenario (all cameras)", "samples"] + list(PARAMS), rows,
                                  f"Monte Carlo, rendered (noise-limit runs, one scene per seed), {label}"))
    return "\n".join(parts)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--sigma", type=float, default=0.1)
    a = ap.parse_args(argv)
    res = run(a.seeds, a.sigma)
    say(tables(res))
    write_json("montecarlo", res)


if __name__ == "__main__":
    main()
