"""Detection and the guided pass on a Dask cluster (`--scheduler`): the same results as the
local process pool, on a LocalCluster of worker processes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rigcal.cli import app
from rigcal.core.rig import load_rig

distributed = pytest.importorskip("distributed")

RIGS = Path(__file__).resolve().parents[2] / "rigs"


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=40) as c:
        yield c.scheduler_address


@pytest.fixture(scope="module")
def fisheye_pair(tmp_path_factory):
    # a fisheye pair: `--guided auto` re-measures its corners, so both stages run remotely
    from rigcal.sim.simulate import simulate_dataset

    d = tmp_path_factory.mktemp("cluster") / "fe"
    simulate_dataset(load_rig(RIGS / "fisheye-stereo.yaml"), d, frames=8, seed=2, jobs=2)
    return d


def _worker_tokens(address: str) -> set:
    """The pool token each cluster worker process last initialised for (None: never used)."""
    def token():
        import rigcal.core.workers
        return rigcal.core.workers._CLUSTER_INIT

    with distributed.Client(address, set_as_default=False) as client:
        return set(client.run(token).values())


@pytest.mark.slow
def test_detection_on_the_cluster_equals_the_local_pool(cluster, fisheye_pair):
    from rigcal.data.dataset import list_dataset
    from rigcal.detect.detect import detect_dataset
    from rigcal.core.target import load_target

    rig, target = load_rig(fisheye_pair / "rig.yaml"), load_target(fisheye_pair / "target.yaml")
    images = list_dataset(fisheye_pair, rig)
    local = detect_dataset(images, target, rig=rig, jobs=2, progress=False)
    before = _worker_tokens(cluster)
    remote = detect_dataset(images, target, rig=rig, jobs=2, progress=False, scheduler=cluster)
    assert _worker_tokens(cluster) - before - {None}, "the cluster's workers did no detection"
    assert len(local.views) == len(remote.views) > 0
    for a, b in zip(local.views, remote.views):
        assert (a.camera, a.frame, a.board) == (b.camera, b.frame, b.board)
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_allclose(b.uv, a.uv, rtol=0, atol=1e-12)
        np.testing.assert_allclose(b.sigma, a.sigma, rtol=1e-12, atol=1e-15)


def _numbers(doc, path=""):
    """Every number of a YAML document by key path."""
    if isinstance(doc, dict):
        return {k: v for key, sub in doc.items() for k, v in _numbers(sub, f"{path}.{key}").items()}
    if isinstance(doc, list):
        return {k: v for i, sub in enumerate(doc) for k, v in _numbers(sub, f"{path}[{i}]").items()}
    return {path: doc} if isinstance(doc, (int, float)) and not isinstance(doc, bool) else {}


@pytest.mark.slow
def test_calibrate_with_scheduler_writes_the_local_calibration(cluster, fisheye_pair, tmp_path):
    runner = CliRunner()
    r_local = runner.invoke(app, ["calibrate", str(fisheye_pair), "--out", str(tmp_path / "local.yaml"), "--jobs", "2"])
    assert r_local.exit_code == 0, r_local.output
    before = _worker_tokens(cluster)
    r = runner.invoke(app, ["calibrate", str(fisheye_pair), "--out", str(tmp_path / "remote.yaml"),
                            "--scheduler", cluster])
    assert r.exit_code == 0, r.output
    assert _worker_tokens(cluster) - before - {None}, "the cluster's workers did nothing"
    assert "guided refinement:" in r.output  # the second stage ran (on the cluster) too
    local = _numbers(yaml.safe_load((tmp_path / "local.yaml").read_text()))
    remote = _numbers(yaml.safe_load((tmp_path / "remote.yaml").read_text()))
    assert local.keys() == remote.keys() and len(local) > 50
    # "seconds" timings differ run to run; every other number is the calibration
    for key in (k for k in local if "seconds" not in k and not k.endswith("_s")):
        assert math.isclose(remote[key], local[key], rel_tol=1e-12, abs_tol=1e-12), (key, local[key], remote[key])


def test_unreachable_scheduler_is_one_line_and_exit_2(fisheye_pair, tmp_path):
    r = CliRunner().invoke(app, ["calibrate", str(fisheye_pair), "--out", str(tmp_path / "x.yaml"),
                                 "--scheduler", "tcp://127.0.0.1:9"])
    assert r.exit_code == 2, r.output
    assert r.stderr.count("\n") == 1 and "cannot reach a Dask scheduler" in r.stderr
    assert not (tmp_path / "x.yaml").exists()
