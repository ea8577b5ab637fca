"""`corners/<camera>.csv` input (dataset.md): corners detected elsewhere. A synthetic
AprilGrid room written as corner files calibrates back to its truth; bad files give one
line naming file and row; the EuRoC imu_april corners calibrate camera-only."""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rigcal.core import geometry as geo
from rigcal.cli import app
from rigcal.data import corners as corners_mod
from rigcal.data.corners import read_corners
from rigcal.errors import DatasetError
from rigcal.core.rig import load_rig
from rigcal.sim.synthetic import board_view, random_body_pose, wall_boards
from rigcal.core.target import load_target, parse_target

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "samples" / "real"))
import make_datasets  # noqa: E402  (samples/real/make_datasets.py)

euroc = pytest.mark.skipif(not make_datasets.EUROC.is_dir(), reason="../shared/data/real/euroc_imu_april is not here")

TARGET = "boards:\n" + "".join(
    f"  - {{name: g{k}, type: aprilgrid, tags: [5, 4], tag_size: 0.08, tag_spacing: 0.3, first_tag_id: {20 * k}}}\n"
    for k in range(4))


def _write_room(ds: Path, n_frames: int = 30, noise: float = 0.1, seed: int = 3) -> None:
    """rigs/stereo-forward.yaml as the truth, four AprilGrids on the walls (Kalibr's frame:
    z out of the print, towards the rig), every camera's corners in corners/<camera>.csv."""
    rng = np.random.default_rng(seed)
    rig = load_rig(ROOT / "rigs" / "stereo-forward.yaml")
    target = parse_target(TARGET)
    board = target.boards[0]
    p_print = geo.transform(geo.inv_T(board.T_board_print), board.corners)
    walls = wall_boards(4, p_print.mean(0), 1.6)  # print frames, facing the origin
    lines = {c.name: ["#frame,board,corner_id,x_px,y_px"] for c in rig.cameras}
    for f in range(n_frames):
        T_world_body = random_body_pose(rng)
        for cam in rig.cameras:
            T_cam_world = geo.inv_T(cam.T_body_cam) @ geo.inv_T(T_world_body)
            for k, T_world_print in enumerate(walls.values()):
                T_cam_board = T_cam_world @ T_world_print @ geo.inv_T(board.T_board_print)
                seen = board_view(cam, T_cam_board, board.corners, 8)
                if seen is None:
                    continue
                ids, uv = seen
                uv = uv + rng.normal(0.0, noise, uv.shape)
                lines[cam.name] += [f"{f:04d},g{k},{i},{x:.5f},{y:.5f}" for i, (x, y) in zip(ids, uv)]
    (ds / "corners").mkdir(parents=True)
    for name, rows in lines.items():
        (ds / "corners" / f"{name}.csv").write_text("\n".join(rows) + "\n")
    (ds / "target.yaml").write_text(TARGET)
    shutil.copy(ROOT / "rigs" / "stereo-forward.yaml", ds / "rig.yaml")


def test_aprilgrid_corner_files_calibrate_back_to_the_truth(tmp_path):
    ds = tmp_path / "ds"
    _write_room(ds)
    res = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml"), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    assert "corners detected elsewhere" in res.output
    truth, cal = load_rig(ds / "rig.yaml"), load_rig(tmp_path / "cal.yaml")
    for name in ("left", "right"):
        t, c = truth.camera(name).intrinsics, cal.camera(name).intrinsics
        np.testing.assert_allclose([c.fx, c.fy, c.cx, c.cy], [t.fx, t.fy, t.cx, t.cy], atol=1.0)
    T_t = geo.inv_T(truth.camera("left").T_body_cam) @ truth.camera("right").T_body_cam
    T_c = geo.inv_T(cal.camera("left").T_body_cam) @ cal.camera("right").T_body_cam
    assert np.linalg.norm(T_c[:3, 3] - T_t[:3, 3]) < 0.5e-3
    dR = T_t[:3, :3].T @ T_c[:3, :3]
    assert np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))) < 0.05


def test_a_camera_with_images_and_corners_uses_the_corners_and_says_so(tmp_path):
    ds = tmp_path / "ds"
    _write_room(ds)
    for cam in ("left", "right"):
        (ds / "images" / cam).mkdir(parents=True)
        (ds / "images" / cam / "0000.png").write_bytes(b"not an image: never read")
    res = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml"), "--jobs", "1",
                                   "--guided", "on"])
    assert res.exit_code == 0, res.output
    assert "images in images/left/ are not used" in res.output
    assert "guided pass needs images" in res.output


GOOD = "#frame,board,corner_id,x_px,y_px\n0001,g0,0,10.5,20.25\n0001,g0,1,11.5,20.25\n"


@pytest.mark.parametrize("text, where", [
    (GOOD + "0001,nope,2,1,2\n", "row 4: board 'nope' is not in the target"),
    (GOOD + "0001,g0,80,1,2\n", "row 4: corner_id 80 is outside board 'g0' (ids 0..79)"),
    (GOOD + "0001,g0,2,abc,2\n", "row 4: x_px: expected a number, got 'abc'"),
    (GOOD + "0001,g0,2.5,1,2\n", "row 4: corner_id: expected a non-negative integer"),
    (GOOD + "0001,g0,2,1,nan\n", "row 4: y_px: expected a finite number"),
    (GOOD + "0001,g0,2,1\n", "row 4: expected 5 columns"),
    (GOOD + "0001,g0,1,3,4\n", "row 4: frame 0001, board g0, corner_id 1 already given in row 3"),
    ("#frame,board,corner_id,x_px,y_px\n", "no corners"),
    # rows that are not clean (read_corners' column-at-a-time reading returns None) reach the
    # row-by-row reading, which names them
    (GOOD + "0001,g0,1e300,1,2\n", "row 4: corner_id: expected a non-negative integer, got '1e300'"),
    (GOOD + "0001,g0,-1,1,2\n", "row 4: corner_id: expected a non-negative integer, got '-1'"),
    (GOOD + "0001,g0,2,1,2,\n", "row 4: expected 5 columns"),
    (GOOD + "0001,g0,2,1,2\n0001,g0,3\n0001,g0,4,1,2,3,4\n", "row 5: expected 5 columns"),
    (GOOD + "0001,g0,2,1,inf\n", "row 4: y_px: expected a finite number, got 'inf'"),
    (GOOD + "0001, g0 ,1, 3,4\n", "row 4: frame 0001, board g0, corner_id 1 already given in row 3"),
    (GOOD + "0002,g0,0,1,2\n0001,g1,0,1,2\n0002,g0,0,1,2\n", "row 6: frame 0002, board g0, corner_id 0 already given in row 4"),
    (GOOD + "0001,g0,2,1\x00,2\n", "row 4: x_px: expected a number"),
])
def test_bad_corner_files_give_one_line_naming_file_and_row(text, where, tmp_path):
    p = tmp_path / "left.csv"
    p.write_text(text)
    with pytest.raises(DatasetError) as e:
        read_corners(p, parse_target(TARGET))
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p)) and where in msg, msg


def _row_by_row(monkeypatch, p, target):
    monkeypatch.setattr(corners_mod, "_parse_clean", lambda text, target: None)
    out = read_corners(p, target)
    monkeypatch.undo()
    return out


def _same_views(a, b) -> bool:
    return len(a) == len(b) and all(
        x[0] == y[0] and x[1] == y[1] and x[2].dtype == y[2].dtype and np.array_equal(x[2], y[2])
        and x[3].dtype == y[3].dtype and np.array_equal(x[3], y[3]) for x, y in zip(a, b))


@pytest.mark.parametrize("text", [
    GOOD,
    "#frame,board,corner_id,x_px,y_px\n7,g1,5,1,1\n7,g0,3,2,2\n7,g1,2,3,3\n8,g1,0,4,4\n9,g3,79,-1.5e2,1_0\n",
    # not clean: indented, CRLF, blank lines, comments between rows, spaces in cells
    "# corners\r\n\r\n 7, g1 ,5,1,1\r\n  # more\r\n7,g0,3,2.0,+2\r\n\t\n8,g1,0,4,4 \r\n",
])
def test_column_and_row_reading_give_the_same_views(text, tmp_path, monkeypatch):
    p = tmp_path / "left.csv"
    p.write_text(text)
    target = parse_target(TARGET)
    fast = read_corners(p, target)
    assert fast and _same_views(fast, _row_by_row(monkeypatch, p, target))


def test_column_reading_of_a_large_shuffled_file_matches_row_reading(tmp_path, monkeypatch):
    rng = np.random.default_rng(5)
    rows = [f"{f:05d},g{b},{i},{x:.6f},{y:.6f}" for f in range(300) for b in range(4) if rng.random() < 0.7
            for i in rng.choice(80, 12, replace=False) for x, y in [rng.uniform(0, 752, 2)]]
    rng.shuffle(rows)
    p = tmp_path / "left.csv"
    p.write_text("#frame,board,corner_id,x_px,y_px\n" + "\n".join(rows) + "\n")
    target = parse_target(TARGET)
    assert corners_mod._parse_clean(p.read_text(), target) is not None
    fast = read_corners(p, target)
    assert _same_views(fast, _row_by_row(monkeypatch, p, target))
    assert sum(len(v[2]) for v in fast) == len(rows)


def test_bad_corner_file_exits_2_and_writes_nothing(tmp_path):
    ds = tmp_path / "ds"
    _write_room(ds, n_frames=4)
    with open(ds / "corners" / "right.csv", "a") as f:
        f.write("0003,g9,0,1,1\n")
    out = tmp_path / "cal.yaml"
    res = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(out)])
    assert res.exit_code == 2
    assert "right.csv: row" in res.output and "board 'g9'" in res.output and "Traceback" not in res.output
    assert not out.exists()


def test_corners_file_of_an_undeclared_camera_is_an_error(tmp_path):
    ds = tmp_path / "ds"
    _write_room(ds, n_frames=2)
    shutil.copy(ds / "corners" / "left.csv", ds / "corners" / "middle.csv")
    res = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml")])
    assert res.exit_code == 2 and "middle.csv is not a camera of the rig" in res.output


def test_views_group_by_frame_and_board_with_ids_ascending(tmp_path):
    p = tmp_path / "left.csv"
    p.write_text("#frame,board,corner_id,x_px,y_px\n7,g1,5,1,1\n7,g0,3,2,2\n7,g1,2,3,3\n8,g1,0,4,4\n")
    views = read_corners(p, parse_target(TARGET))
    assert [(f, b, list(i)) for f, b, i, _ in views] == [("7", "g1", [2, 5]), ("7", "g0", [3]), ("8", "g1", [0])]
    np.testing.assert_allclose(views[0][3], [[3, 3], [1, 1]])


# ----------------------------------------------------------------------------- EuRoC


def _rel(rig, a: str, b: str) -> np.ndarray:
    return geo.inv_T(rig.camera(a).T_body_cam) @ rig.camera(b).T_body_cam


EUROC_EVERY = 10  # 142 of the 1,416 frames with corners: 3 s; the full set is bench.real's euroc row (~45 s)


@pytest.fixture(scope="module")
def euroc_calibrated(tmp_path_factory):
    d = tmp_path_factory.mktemp("euroc")
    ds = make_datasets.build_euroc(d / "ds", every=EUROC_EVERY)
    t0 = time.perf_counter()
    res = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(d / "cal.yaml"), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    return load_rig(d / "cal.yaml"), time.perf_counter() - t0


@pytest.mark.slow
@euroc
def test_euroc_corners_baseline(euroc_calibrated):
    cal, _ = euroc_calibrated
    base_mm = 1000 * np.linalg.norm(_rel(cal, "cam0", "cam1")[:3, 3])
    assert abs(base_mm - make_datasets.EUROC_BASELINE_MM) < 0.3, base_mm  # measured 109.98


@euroc
@pytest.mark.xfail(strict=True, reason=(
    "not met: EuRoC's published principal points do not fit these corners: rigcal gives cx 4-7 px lower; "
    "per-frame PnP fits rigcal's intrinsics to 0.40/0.43 px (best 98 %) against 0.48/0.49 px for EuRoC's, and "
    "on the sharpest frames OpenCV's own calibrateCamera also gives cx 357.3/371.0 against EuRoC's "
    "367.2/380.0 (docs/accuracy.md, Real image sets)"))
def test_euroc_corners_intrinsics_within_half_a_percent_of_eurocs(euroc_calibrated):
    cal, _ = euroc_calibrated
    ref = yaml.safe_load((make_datasets.EUROC / "reference.yaml").read_text())
    for cam in make_datasets.EUROC_CAMERAS:
        m = cal.camera(cam).intrinsics
        got = np.array([m.fx, m.fy, m.cx, m.cy])
        want = np.array(ref[cam]["intrinsics"])
        assert np.all(np.abs(got - want) <= 0.005 * want), (cam, got, want)


@euroc
def test_euroc_corner_file_matches_kalibrs_layout():
    target = load_target(make_datasets.EUROC / "kalibr_target.yaml")
    raw = make_datasets.read_yac(make_datasets.EUROC / "corners" / "cam0.csv.gz")[:5000]
    ids = (4 * raw[:, 1] + raw[:, 2]).astype(int)
    np.testing.assert_allclose(target.boards[0].corners[ids], raw[:, 5:8], atol=1e-6)
    assert yaml.safe_load((make_datasets.EUROC / "kalibr_target.yaml").read_text())["target_type"] == "aprilgrid"


def test_a_declared_board_absent_from_the_corner_files_is_named_as_such(tmp_path):
    """Corners detected elsewhere: a declared board no corners file mentions is named, and
    the warning does not send the user to the board's dictionary (nothing was detected here)."""
    ds = tmp_path / "ds"
    _write_room(ds, n_frames=12)
    (ds / "target.yaml").write_text(
        TARGET + "  - {name: spare, type: aprilgrid, tags: [5, 4], tag_size: 0.08, tag_spacing: 0.3, "
        "first_tag_id: 200}\n")
    res = CliRunner().invoke(app, ["calibrate", str(ds), "--out", str(tmp_path / "cal.yaml"), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    assert "board spare: no corners of it in the corners files" in res.output
    assert "never detected" not in res.output and "dictionary" not in res.output
