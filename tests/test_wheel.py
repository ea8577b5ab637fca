"""The wheel installs on its own and does the main job without the source tree.

The wheel is built from this checkout and installed into a fresh virtual environment;
rigcal's dependencies come from the test environment through a path file (so the test
needs no network), which adds their folders to sys.path but runs none of their `.pth`
hooks: the editable install of the source tree stays invisible. Every command runs in
an empty folder outside the source tree, and the test checks that `rigcal` was imported
from the new environment.
"""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent


def _run(args: list, cwd: Path, env: dict) -> subprocess.CompletedProcess:
    r = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, f"{args}: exit {r.returncode}\n{r.stdout}\n{r.stderr}"
    return r


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, Path, dict]:
    """(bin folder of an environment with only the wheel installed, an empty work folder, env vars)."""
    tmp = tmp_path_factory.mktemp("wheel")
    # Build from a copy so the checkout gets no build/ or egg-info folders.
    src = tmp / "src"
    anywhere = shutil.ignore_patterns(".venv*", ".git", "*.egg-info", "__pycache__")
    top_only = {"build", "site", "demo-out", "sim", "bench", "tests", "samples"}  # rigcal/sim is the package's

    def ignore(folder: str, names: list[str]) -> set[str]:
        return set(anywhere(folder, names)) | (top_only & set(names) if Path(folder) == ROOT else set())

    shutil.copytree(ROOT, src, symlinks=True, ignore=ignore)
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", tmp / "dist", src],
         tmp, dict(os.environ))
    wheels = list((tmp / "dist").glob("rigcal-*.whl"))
    assert len(wheels) == 1, wheels
    envdir = tmp / "env"
    venv.create(envdir, with_pip=False)
    bin_dir = envdir / ("Scripts" if os.name == "nt" else "bin")
    _run([sys.executable, "-m", "pip", "--python", bin_dir / "python", "install", "-q", "--no-deps", wheels[0]],
         tmp, dict(os.environ))
    purelib = Path(subprocess.check_output([bin_dir / "python", "-c",
                                            "import sysconfig; print(sysconfig.get_path('purelib'))"], text=True).strip())
    deps = {sysconfig.get_path("purelib"), sysconfig.get_path("platlib"), *site.getsitepackages()}
    (purelib / "zz_test_dependencies.pth").write_text("".join(f"{d}\n" for d in sorted(deps)))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    work = tmp / "work"
    work.mkdir()
    return bin_dir, work, env


@pytest.mark.slow
def test_wheel_imports_rigcal_from_its_own_environment(installed):
    bin_dir, work, env = installed
    where = _run([bin_dir / "python", "-c", "import rigcal, sys; print(rigcal.__file__)"], work, env).stdout.strip()
    assert Path(where).resolve().is_relative_to((bin_dir.parent).resolve()), where
    assert not Path(where).resolve().is_relative_to(ROOT), where


def test_wheel_ships_the_rigs(installed):
    bin_dir, work, env = installed
    names = _run([bin_dir / "python", "-c", "from rigcal.core.rig import shipped_rig_names; print(*shipped_rig_names())"],
                 work, env).stdout.split()
    assert sorted(names) == sorted(p.stem for p in (ROOT / "rigs").glob("*.yaml"))


@pytest.mark.slow
def test_wheel_runs_help_simulate_calibrate_compare(installed):
    bin_dir, work, env = installed
    rigcal = bin_dir / "rigcal"
    assert "calibrate" in _run([rigcal, "--help"], work, env).stdout
    _run([rigcal, "simulate", "drone-stereo-back", "--out", "sim", "--frames", "12", "--seed", "3", "--jobs", "2"],
         work, env)
    assert sorted(p.name for p in (work / "sim" / "images").iterdir()) == ["back", "front_left", "front_right"]
    _run([rigcal, "calibrate", "sim", "--out", "cal.yaml", "--jobs", "2"], work, env)
    cal = yaml.safe_load((work / "cal.yaml").read_text())
    assert set(cal["cameras"]) == {"back", "front_left", "front_right"}
    out = _run([rigcal, "compare", "cal.yaml", "sim/truth.yaml"], work, env).stdout
    assert "front_left" in out and "baseline" in out
    true = yaml.safe_load((work / "sim" / "truth.yaml").read_text())["rig"]["cameras"]

    def baseline(cams):
        return np.linalg.norm(np.subtract(cams["front_left"]["position"], cams["front_right"]["position"]))
    assert abs(baseline(cal["cameras"]) - baseline(true)) < 1e-3  # metres: a calibration, not an echo


def test_unknown_rig_name_lists_the_shipped_ones(installed):
    bin_dir, work, env = installed
    r = subprocess.run([bin_dir / "rigcal", "simulate", "no-such-rig", "--out", "x"], cwd=work, env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "no-such-rig: file not found" in r.stderr and "drone-stereo-back" in r.stderr
    assert not (work / "x").exists()
