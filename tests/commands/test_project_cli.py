"""The golden example of ../shared/spec/cli.md, through the Python API and `rigcal project`."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import rigcal
from rigcal.cli import app

ROOT = Path(__file__).resolve().parents[2]
GOLDEN_RIG = ROOT / "rigs" / "drone-stereo-back.yaml"
POSITION, POINT = [100.0, 300.0, 10.0], [103.0, 310.0, 12.0]
POSES = {"heading": ["--heading", "0"], "axes": ["--axes", "N", "-E", "U"]}


def golden_pose(how: str) -> np.ndarray:
    if how == "heading":
        return rigcal.T_nav_body_from_heading(POSITION, 0.0)
    return rigcal.T_nav_body_from_axes(POSITION, ["N", "-E", "U"])


@pytest.mark.parametrize("how", sorted(POSES))
def test_golden_numbers_through_the_python_api(how):
    rig = rigcal.load_rig(GOLDEN_RIG)
    T_nav_body = golden_pose(how)
    p_nav = np.array([POINT])
    np.testing.assert_allclose(rigcal.transform(rigcal.inv_T(T_nav_body), p_nav), [[10, -3, 2]], atol=1e-12)
    seen = rig.project(p_nav, T_nav_body)
    np.testing.assert_allclose(seen["front_left"].p_cam, [[3.05, -1.99, 9.9]], atol=1e-12)
    np.testing.assert_allclose(seen["front_right"].p_cam, [[2.95, -1.99, 9.9]], atol=1e-12)
    # pixels: u = 320 + 300 x / z, v = 240 + 300 y / z
    np.testing.assert_allclose(seen["front_left"].uv, [[320 + 300 * 3.05 / 9.9, 240 - 300 * 1.99 / 9.9]], atol=1e-9)
    np.testing.assert_allclose(seen["front_right"].uv, [[320 + 300 * 2.95 / 9.9, 240 - 300 * 1.99 / 9.9]], atol=1e-9)
    # the spec's printed pixels, to their last printed digit
    np.testing.assert_allclose(seen["front_left"].uv, [[412.42, 179.70]], atol=0.005)
    np.testing.assert_allclose(seen["front_right"].uv, [[409.39, 179.70]], atol=0.005)
    back = seen["back"]
    assert not back.valid[0] and not back.in_image[0] and np.isnan(back.uv).all()
    assert back.reason(0) == "behind the camera"
    sd = rig.stereo_depth(rig.stereo_pairs[0], p_nav, T_nav_body)
    assert sd.disparity[0] == pytest.approx(300 * 0.1 / 9.9, abs=1e-9)  # 3.0303 px
    assert sd.depth[0] == pytest.approx(9.9, abs=1e-9)
    assert sd.baseline_m == pytest.approx(0.1, abs=1e-12)


_NUMBER = re.compile(r"-?\d+(?:\.\d+)?")
# The spec's lines with their numbers exact (cli.md's golden example), not as printed.
FL = [3.05, -1.99, 9.9, 320 + 300 * 3.05 / 9.9, 240 - 300 * 1.99 / 9.9]
FR = [2.95, -1.99, 9.9, 320 + 300 * 2.95 / 9.9, 240 - 300 * 1.99 / 9.9]
STEREO = [300 * 0.1 / 9.9, 9.9, 0.1, 300.0]


def assert_printed(out: str, template: str, expected: list[float]) -> None:
    """A line of `out` reads `template` with its '#' replaced by numbers equal to `expected`
    to the last digit printed: numbers are compared as numbers, never as text."""
    for line in out.splitlines():
        if _NUMBER.sub("#", line) == template:
            printed = _NUMBER.findall(line)
            assert len(printed) == len(expected), line
            for text, want in zip(printed, expected):
                decimals = len(text.split(".")[1]) if "." in text else 0
                assert abs(float(text) - want) <= 0.5 * 10.0**-decimals + 1e-12, (line, text, want)
            return
    raise AssertionError(f"no line reads {template!r} in:\n{out}")


def invoke(*args: str):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.mark.parametrize("how", sorted(POSES))
def test_golden_numbers_through_the_cli(how):
    r = invoke("project", GOLDEN_RIG, "--position", *map(str, POSITION), *POSES[how], "--point", *map(str, POINT))
    assert r.exit_code == 0, r.stderr
    out = r.stdout
    assert_printed(out, "body frame (FLU): (#, #, #)", [10, -3, 2])
    assert_printed(out, "front_left: camera frame (#, #, #)  pixel (#, #)", FL)
    assert_printed(out, "front_right: camera frame (#, #, #)  pixel (#, #)", FR)
    assert "back: not visible (behind the camera)" in out
    back_line = next(line for line in out.splitlines() if line.startswith("back:"))
    assert "pixel" not in back_line  # never a pixel for a point behind the camera
    assert_printed(out, "stereo front_left/front_right: disparity # px, depth # m "
                        "(Z = B f / d with baseline # m, f # px)", STEREO)
    assert r.stderr == ""


def test_heading_turns_the_body():
    # flying east (90 deg): 10 m east is ahead, 3 m south is to the right -> the golden body point again
    r = invoke("project", GOLDEN_RIG, "--position", "100", "300", "10", "--heading", "90", "--point", "110", "297", "12")
    assert r.exit_code == 0, r.stderr
    assert_printed(r.stdout, "body frame (FLU): (#, #, #)", [10, -3, 2])
    assert_printed(r.stdout, "front_left: camera frame (#, #, #)  pixel (#, #)", FL)


def test_rig_without_poses_is_reported_not_crashed(tmp_path):
    rig = tmp_path / "half.yaml"
    rig.write_text(
        "cameras:\n"
        "  a: {resolution: [640, 480], intrinsics: {focal: 300}, position: [0.1, 0.05, 0], look: forward}\n"
        "  b: {resolution: [640, 480], intrinsics: {focal: 300}}\n"
        "stereo_pairs: [[a, b]]\n")
    r = invoke("project", rig, "--position", "0", "0", "0", "--heading", "0", "--point", "0", "10", "0")
    assert r.exit_code == 0, r.stderr
    assert "b: no pose in the rig file" in r.stdout
    assert "stereo a/b: no disparity (b has no pose)" in r.stdout
    assert "a: camera frame" in r.stdout and "pixel" in r.stdout


def test_point_outside_one_image_gives_no_disparity():
    r = invoke("project", GOLDEN_RIG, "--position", "0", "0", "0", "--heading", "0", "--point", "-20", "10", "0")
    assert r.exit_code == 0, r.stderr
    assert "not visible (outside the image)" in r.stdout
    assert "not seen by both cameras; no disparity" in r.stdout


@pytest.mark.parametrize("args, expected", [
    (["--heading", "0", "--axes", "N", "-E", "U"], "exactly one of --heading"),
    ([], "exactly one of --heading"),
    (["--axes", "N", "N", "U"], "--axes"),
    (["--axes", "N", "-E", "D"], "--axes"),
    (["--heading", "nan"], "--heading"),
])
def test_bad_body_pose_is_one_line_exit_2(args, expected):
    r = invoke("project", GOLDEN_RIG, "--position", "0", "0", "0", *args, "--point", "1", "1", "1")
    assert r.exit_code == 2
    assert len(r.stderr.strip().splitlines()) == 1 and expected in r.stderr
    assert "Traceback" not in r.stderr + r.stdout


def test_missing_rig_file_is_exit_2(tmp_path):
    r = invoke("project", tmp_path / "nope.yaml", "--position", "0", "0", "0", "--heading", "0", "--point", "1", "1", "1")
    assert r.exit_code == 2
    assert "nope.yaml: file not found" in r.stderr


def test_help_lists_the_options():
    r = invoke("project", "--help")
    assert r.exit_code == 0
    for opt in ("--position", "--heading", "--axes", "--point"):
        assert opt in r.stdout
