"""rigcal on scenes from an independent renderer (tests/support/indie_render.py: OpenCV and the spec
only, no rigcal code), errors against its truth.

Three scenes, rendered with 4 x 4 samples per pixel into bench/out/indie/ and calibrated
with `rigcal calibrate` in a subprocess, as a user runs it:

  room     forward pinhole pair + backward fisheye, 7 boards on four walls, rig turning
           through every heading (40 frames; png/jpg/bmp/tif, grey and colour, links,
           missing frames, one corrupt image)
  waved    a pinhole stereo pair, one board waved in front of it (30 frames)
  forward  the room with boards on the front and back walls only, rig yawing +-20 deg:
           the back camera shares no board with the front pair (hand-eye case, 30 frames)

Per camera pair: relative rotation and translation error, and the same divided by the
1-sigma rigcal reports (root-sum-square of the two cameras'); per camera the intrinsics
errors.

    python -m bench.indie
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from rigcal.results.compare import compare_rigs

from rigcal.data.truth import load_truth
from rigcal.core.rig import load_rig

from .common import OUT, md_table, say, write_json

from tests.support import indie_render as ir

BIN = Path(sys.executable).parent / "rigcal"
SCENES = (
    ("room", lambda: ir.room_scene(n_frames=40, seed=0), {}),
    ("waved", lambda: ir.waved_scene(n_frames=30, seed=0), {"corrupt": False}),
    ("forward", lambda: ir.room_scene(n_frames=30, seed=3, headings="forward"), {"corrupt": False}),
)


def run(log=say) -> dict:
    results = {}
    for name, make, kw in SCENES:
        ds = OUT / "indie" / name
        shutil.rmtree(ds, ignore_errors=True)
        t0 = time.perf_counter()
        ir.write_dataset(make(), ds, seed=0, S=4, **kw)
        render_s = time.perf_counter() - t0
        log(f"indie: {name} rendered in {render_s:.0f} s; calibrating ...")
        out = ds / "calibrated.yaml"
        t0 = time.perf_counter()
        p = subprocess.run([str(BIN) if BIN.exists() else "rigcal", "calibrate", str(ds), "--out", str(out),
                            "--jobs", "2"], capture_output=True, text=True)
        r = {"render_s": render_s, "calibrate_s": time.perf_counter() - t0}
        if p.returncode != 0:
            lines = (p.stdout + p.stderr).strip().splitlines()
            r["error"] = lines[-1] if lines else f"exit {p.returncode}"
            results[name] = r
            continue
        cal = yaml.safe_load(out.read_text())
        res = compare_rigs(load_rig(out), load_truth(ds / "truth.yaml").rig)
        r["pairs"] = {}
        for (a, b), e in res["pairs"].items():
            sa, sb = (cal["cameras"][n]["calibration"]["sigma"] for n in (a, b))
            s_rot = float(np.sqrt(np.sum(np.square(sa["rotation_deg"])) + np.sum(np.square(sb["rotation_deg"]))))
            s_pos = float(np.sqrt(np.sum(np.square(sa["position_mm"])) + np.sum(np.square(sb["position_mm"]))))
            r["pairs"][f"{a}/{b}"] = {**e, "sigma_rot_deg": s_rot, "sigma_trans_mm": s_pos}
        r["cameras"] = {n: {**{k: e[k] for k in ("fx", "fy", "cx", "cy", "proj_rms_px")},
                            "model": cal["cameras"][n]["model"],
                            "rms_px": cal["cameras"][n]["calibration"]["reprojection_rms_px"],
                            "views_frames": cal["cameras"][n]["calibration"]["frames"]}
                        for n, e in res["cameras"].items()}
        results[name] = r
    return results


def tables(results: dict) -> str:
    out = ["\n## Independent renderer (tests/support/indie_render.py)\n"]
    rows, cams = [], []
    for name, r in results.items():
        if "error" in r:
            rows.append([name, "-", "-", "-", "-", "-", f"FAILED: {r['error']}"])
            continue
        for pair, e in r["pairs"].items():
            rows.append([name, pair, f"{e['rot_deg']:.4f}", f"{e['rot_deg'] / e['sigma_rot_deg']:.1f}",
                         f"{e['trans_mm']:.3f}", f"{e['trans_mm'] / e['sigma_trans_mm']:.1f}", ""])
        for n, c in r["cameras"].items():
            cams.append([name, n, c["model"], f"{c['rms_px']:.3f}", *(f"{c[k]:+.3f}" for k in ("fx", "fy", "cx", "cy")),
                         f"{c['proj_rms_px']:.3f}"])
    out.append(md_table(["scene", "pair", "rot err deg", "/ sigma", "trans err mm", "/ sigma", "note"], rows,
                        "camera pairs vs truth (sigma: rigcal's reported 1-sigma, both cameras)"))
    out.append(md_table(["scene", "camera", "model", "rms px", "fx err", "fy err", "cx err", "cy err",
                         "proj. diff rms px"], cams, "intrinsics vs truth"))
    out.append("\n" + ", ".join(f"{n}: render {r['render_s']:.0f} s, calibrate {r['calibrate_s']:.0f} s"
                                for n, r in results.items()))
    return "\n".join(out)


def main() -> None:
    res = run()
    write_json("indie", res)
    say(tables(res))


if __name__ == "__main__":
    main()
