"""Rig files (../shared/spec/rig-yaml.md): every file in rigs/ loads and round-trips, a
calibrated-style file round-trips, and each kind of bad input is refused with one
stderr line naming the file and the key, exit code 2, through the CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

import rigcal
from rigcal.core import geometry as geo
from rigcal.cli import app
from rigcal.errors import RigFileError
from rigcal.core.rig import dump_rig, load_rig, parse_rig, save_rig

ROOT = Path(__file__).resolve().parents[2]
RIG_FILES = sorted((ROOT / "rigs").glob("*.yaml"))

BASE = """\
rig: test
cameras:
  front_left:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}
    distortion: [0, 0, 0, 0, 0]
    position: [0.10, 0.05, 0.01]
    axes: [-L, -U, F]
  front_right:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}
    distortion: [0, 0, 0, 0, 0]
    position: [0.10, -0.05, 0.01]
    look: forward
stereo_pairs:
  - [front_left, front_right]
"""

CALIBRATED = """\
rig: drone-stereo-back
body_frame: FLU
cameras:
  front_left:
    model: pinhole
    resolution: [640, 480]
    intrinsics: {fx: 301.25, fy: 300.75, cx: 319.5, cy: 241.25}
    distortion: [-0.0312, 0.0121, 0.00042, -0.00031, 0.0]
    position: [0.1012, 0.0497, 0.0103]
    rotation: [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    quaternion: [0.5, -0.5, 0.5, -0.5]
    calibration:
      reprojection_rms_px: 0.12
      observations: 8123
      frames: 57
      outliers: 3
      sigma:
        position_mm: [0.21, 0.19, 0.35]
        rotation_deg: [0.004, 0.005, 0.003]
        intrinsics: {fx: 0.08, fy: 0.08, cx: 0.11, cy: 0.1}
  front_right:
    model: fisheye
    resolution: [640, 480]
    intrinsics: {fx: 300.5, fy: 300.25, cx: 320.5, cy: 239.5}
    distortion: [0.01, -0.002, 0.0003, -0.0001]
    position: [0.0998, -0.0503, 0.0099]
    rotation: [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    quaternion: [0.5, -0.5, 0.5, -0.5]
  spare:
    model: pinhole
    resolution: [320, 240]
    intrinsics: {fx: 200.0, fy: 200.0, cx: 160.0, cy: 120.0}
    distortion: [-0.1, 0.02]
stereo_pairs:
  - left: front_left
    right: front_right
    baseline_m: 0.1001
    depth_check:
      bands: [{range_m: [0.5, 2.0], count: 512, median_rel: 0.0012, p95_rel: 0.004}]
      vertical_rms_px: 0.05
      reference: board
calibration:
  tool: rigcal 0.1.0
  dataset: sim/run1
  reference: aligned-to-declared
  reprojection_rms_px: 0.12
"""


# ----------------------------------------------------------------------------- loading and round trips


def test_the_shipped_rigs_are_all_here():
    names = {p.stem for p in RIG_FILES}
    assert {"drone-stereo-back", "stereo-forward", "surround-6", "fisheye-stereo", "down-nav"} <= names


@pytest.mark.parametrize("path", RIG_FILES, ids=[p.stem for p in RIG_FILES])
def test_every_rig_file_loads_and_round_trips(path, tmp_path):
    text = path.read_text()
    assert text.startswith("#"), "every rig file starts with a comment saying what it is"
    rig = load_rig(path)
    assert all(c.has_pose for c in rig.cameras)
    again = parse_rig(dump_rig(rig))
    assert again == rig
    save_rig(rig, tmp_path / "out.yaml")
    assert load_rig(tmp_path / "out.yaml") == rig
    # the written form is the calibrated one: rotation and quaternion for every camera
    doc = yaml.safe_load(dump_rig(rig))
    for cam in doc["cameras"].values():
        assert "rotation" in cam and "quaternion" in cam
        assert not {"look", "axes"} & set(cam)


def test_round_trip_equality_can_fail():
    rig = load_rig(ROOT / "rigs" / "drone-stereo-back.yaml")
    moved = rig.with_cameras([rig.cameras[0]] + [
        rigcal.Camera(c.name, c.intrinsics, c.T_body_cam + np.pad([[1e-12]], ((0, 3), (3, 0))))
        for c in rig.cameras[1:]])
    assert moved != rig


def test_calibrated_file_round_trips():
    rig = parse_rig(CALIBRATED, "cal.yaml")
    assert parse_rig(dump_rig(rig)) == rig
    assert rig.camera("front_left").calibration["sigma"]["position_mm"] == [0.21, 0.19, 0.35]
    assert not rig.camera("spare").has_pose
    pair = rig.stereo_pairs[0]
    assert (pair.left, pair.right, pair.baseline_m) == ("front_left", "front_right", 0.1001)
    assert pair.depth_check["bands"][0]["count"] == 512
    assert rig.calibration["tool"] == "rigcal 0.1.0"
    # and a second trip writes the same text
    assert dump_rig(parse_rig(dump_rig(rig))) == dump_rig(rig)


def test_orientation_forms_agree():
    R = geo.R_from_look("left")
    q = geo.quat_from_R(R)
    forms = {
        "look: left": "look: left",
        "axes": "axes: [F, -U, L]",
        "axes vectors": "axes: [[1, 0, 0], [0, 0, -1], [0, 1, 0]]",
        "rotation": "rotation: " + str(R.tolist()),
        "quaternion": "quaternion: " + str(q.tolist()),
    }
    Rs = []
    for line in forms.values():
        text = f"cameras:\n  a:\n    resolution: [64, 48]\n    intrinsics: {{focal: 50}}\n    position: [0, 0, 0]\n    {line}\n"
        Rs.append(parse_rig(text).camera("a").T_body_cam[:3, :3])
    for R_i in Rs:
        np.testing.assert_allclose(R_i, R, atol=1e-15)


def test_defaults():
    rig = parse_rig("cameras:\n  a:\n    resolution: [640, 480]\n    intrinsics: {focal: 300}\n"
                    "  f:\n    model: fisheye\n    resolution: [800, 600]\n    intrinsics: {fx: 250, fy: 251}\n")
    a, f = rig.camera("a").intrinsics, rig.camera("f").intrinsics
    assert (a.model, a.fx, a.fy, a.cx, a.cy, a.dist) == ("pinhole", 300.0, 300.0, 320.0, 240.0, (0.0,) * 5)
    assert (f.cx, f.cy, f.dist) == (400.0, 300.0, (0.0,) * 4)
    assert rig.name == "rig" and rig.body_frame == "FLU" and rig.stereo_pairs == ()


def test_date_like_text_stays_text():
    # PyYAML would build a date (or raise ValueError for 2001-13-01); a rig file has no dates
    assert parse_rig(edit("rig: test", "rig: 2001-13-01")).name == "2001-13-01"
    assert parse_rig(edit("rig: test", "rig: 2024-05-01")).name == "2024-05-01"


def test_rotation_and_quaternion_must_agree():
    text = CALIBRATED.replace("quaternion: [0.5, -0.5, 0.5, -0.5]", "quaternion: [0.5, 0.5, 0.5, 0.5]", 1)
    with pytest.raises(RigFileError, match=r"cal\.yaml: cameras\.front_left\.quaternion: does not match"):
        parse_rig(text, "cal.yaml")


# ----------------------------------------------------------------------------- bad input, through the CLI


def edit(old: str, new: str, text: str = BASE, count: int = 1) -> str:
    assert old in text, old
    return text.replace(old, new, count)


BAD = {
    "not yaml": ("cameras: [front_left\n  a: {", "", "not valid YAML at line"),
    "not a mapping": ("- front_left\n- front_right\n", "", "expected a mapping"),
    "empty file": ("", "", "expected a mapping"),
    "missing cameras": ("rig: test\nstereo_pairs: []\n", "cameras", "missing"),
    "cameras empty": ("cameras: {}\n", "cameras", "non-empty mapping of camera name -> camera, got an empty"),
    "typo postion": (edit("    position: [0.10, 0.05", "    postion: [0.10, 0.05"),
                     "cameras.front_left.postion", "did you mean `position`"),
    "typo top level": (edit("stereo_pairs:", "stereo_pair:"), "stereo_pair", "did you mean `stereo_pairs`"),
    "two orientation keys": (edit("    axes: [-L, -U, F]", "    axes: [-L, -U, F]\n    look: forward"),
                             "cameras.front_left", "exactly one orientation key"),
    "axes left-handed": (edit("axes: [-L, -U, F]", "axes: [L, -U, F]"), "cameras.front_left.axes", "right-handed"),
    "axes not orthonormal": (edit("axes: [-L, -U, F]", "axes: [-L, -U, L]"), "cameras.front_left.axes",
                             "orthonormal"),
    "axes skewed vectors": (edit("axes: [-L, -U, F]", "axes: [[0, -1, 0], [0, 0.1, -1], [1, 0, 0]]"),
                            "cameras.front_left.axes", "orthonormal"),
    "quaternion not unit": (edit("axes: [-L, -U, F]", "quaternion: [0.5, -0.5, 0.5, -0.4]"),
                            "cameras.front_left.quaternion", "unit quaternion"),
    "rotation reflection": (edit("axes: [-L, -U, F]", "rotation: [[0, 0, 1], [1, 0, 0], [0, -1, 0]]"),
                            "cameras.front_left.rotation", "reflection"),
    "look unknown": (edit("look: forward", "look: sideways"), "cameras.front_right.look", "forward"),
    "negative focal": (edit("{fx: 300.0, fy: 300.0", "{fx: -300.0, fy: 300.0"),
                       "cameras.front_left.intrinsics.fx", "positive"),
    "zero focal": (edit("intrinsics: {fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}", "intrinsics: {focal: 0}"),
                   "cameras.front_left.intrinsics.focal", "positive"),
    "focal and fx": (edit("{fx: 300.0, fy: 300.0", "{focal: 300, fx: 300.0, fy: 300.0"),
                     "cameras.front_left.intrinsics", "not both"),
    "resolution one number": (edit("resolution: [640, 480]", "resolution: [640]"),
                              "cameras.front_left.resolution", "two positive integers"),
    "resolution zero": (edit("resolution: [640, 480]", "resolution: [640, 0]"),
                        "cameras.front_left.resolution", "two positive integers"),
    "resolution float": (edit("resolution: [640, 480]", "resolution: [640.5, 480]"),
                         "cameras.front_left.resolution", "two positive integers"),
    "resolution text": (edit("resolution: [640, 480]", "resolution: 640x480"),
                        "cameras.front_left.resolution", "two positive integers"),
    "distortion length pinhole": (edit("distortion: [0, 0, 0, 0, 0]", "distortion: [0, 0, 0]"),
                                  "cameras.front_left.distortion", "2, 4, 5, 8 or 12"),
    "distortion length fisheye": (edit("model: pinhole", "model: fisheye"), "cameras.front_left.distortion",
                                  "4 (k1 k2 k3 k4)"),
    "distortion not numbers": (edit("distortion: [0, 0, 0, 0, 0]", "distortion: [0, 0, a, 0, 0]"),
                               "cameras.front_left.distortion[2]", "expected a number"),
    "unknown model": (edit("model: pinhole", "model: pinhole2"), "cameras.front_left.model", "pinhole, fisheye"),
    "pair names a missing camera": (edit("[front_left, front_right]", "[front_left, front_centre]"),
                                    "stereo_pairs[0]", "'front_centre' is not declared"),
    "pair of one camera": (edit("[front_left, front_right]", "[front_left, front_left]"),
                           "stereo_pairs[0]", "two different cameras"),
    "pair without baseline": (edit("position: [0.10, -0.05, 0.01]", "position: [0.10, 0.05, 0.01]"),
                              "stereo_pairs[0]", "same position"),
    "duplicate camera names": (edit("  front_right:\n", "  front_left:\n"), "cameras",
                               "duplicate camera name 'front_left'"),
    "duplicate key": (edit("    look: forward", "    look: forward\n    model: pinhole"),
                      "cameras.front_right.model", "duplicate key"),
    "bad camera name": (edit("  front_right:", "  Front-Right:"), "cameras.Front-Right", "[a-z0-9_]+"),
    "orientation without position": (edit("    position: [0.10, -0.05, 0.01]\n", ""),
                                     "cameras.front_right.position", "missing"),
    "position without orientation": (edit("    look: forward\n", ""), "cameras.front_right",
                                     "missing orientation"),
    "nan position": (edit("position: [0.10, 0.05, 0.01]", "position: [.nan, 0.05, 0.01]"),
                     "cameras.front_left.position[0]", "finite"),
    "inf focal": (edit("{fx: 300.0, fy: 300.0", "{fx: .inf, fy: 300.0"), "cameras.front_left.intrinsics.fx",
                  "finite"),
    "nan distortion": (edit("distortion: [0, 0, 0, 0, 0]", "distortion: [0, .nan, 0, 0, 0]"),
                       "cameras.front_left.distortion[1]", "finite"),
    "nan cx": (edit("cx: 320.0", "cx: .NaN"), "cameras.front_left.intrinsics.cx", "finite"),
    "inf quaternion": (edit("axes: [-L, -U, F]", "quaternion: [.inf, 0, 0, 0]"),
                       "cameras.front_left.quaternion[0]", "finite"),
    "nan axes vector": (edit("axes: [-L, -U, F]", "axes: [[0, -1, 0], [0, 0, -1], [.nan, 0, 0]]"),
                        "cameras.front_left.axes[2][0]", "finite"),
    "nan in calibration": (BASE + "calibration:\n  reprojection_rms_px: .nan\n", "calibration.reprojection_rms_px",
                           "finite"),
    "huge integer": (edit("cx: 320.0", "cx: " + "9" * 400), "cameras.front_left.intrinsics.cx", "finite"),
    "rig name a list": (edit("rig: test", "rig: [2001-13-01]"), "rig", "expected a name"),
    "recursive alias": (BASE + "calibration: &c\n  again: *c\n", "calibration.again", "contains itself"),
    "tagged garbage": (edit("cx: 320.0", "cx: !!float abc"), "", "not valid YAML"),
}


def write_bad(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad-rig.yaml"
    path.write_text(text)
    return path


def assert_one_line_exit_2(result, path: Path, key: str, expected: str) -> None:
    assert result.exit_code == 2, (result.exit_code, result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    line = lines[0]
    assert str(path) in line
    assert f"{path}: {key}: " in line if key else f"{path}: " in line
    assert expected in line, line
    assert "Traceback" not in result.stderr + result.stdout
    assert result.stdout == ""


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_rig_via_project(case, tmp_path):
    text, key, expected = BAD[case]
    path = write_bad(tmp_path, text)
    r = CliRunner().invoke(app, ["project", str(path), "--position", "0", "0", "0", "--heading", "0",
                                 "--point", "1", "0", "0"])
    assert_one_line_exit_2(r, path, key, expected)


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_rig_via_view_writes_nothing(case, tmp_path):
    text, key, expected = BAD[case]
    path = write_bad(tmp_path, text)
    out = tmp_path / "rig.html"
    r = CliRunner().invoke(app, ["view", str(path), "--out", str(out)])
    assert_one_line_exit_2(r, path, key, expected)
    assert not out.exists()


def test_the_bad_inputs_start_from_a_good_file(tmp_path):
    # guards the table above: without the edit, the file loads
    path = write_bad(tmp_path, BASE)
    r = CliRunner().invoke(app, ["project", str(path), "--position", "0", "0", "0", "--heading", "0",
                                 "--point", "0", "10", "0"])
    assert r.exit_code == 0, r.stderr


def test_alias_bomb_is_refused_quickly():
    levels = ["a0: &a0 [1, 2, 3, 4, 5, 6, 7, 8, 9]"]
    for i in range(1, 10):
        levels.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    text = BASE + "calibration:\n" + "\n".join("  " + line for line in levels) + "\n"
    with pytest.raises(RigFileError, match="expands to more than"):
        parse_rig(text, "bomb.yaml")


def test_shared_anchors_are_fine():
    text = edit("intrinsics: {fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}",
                "intrinsics: &k {fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}")
    text = edit("intrinsics: {fx: 300.0, fy: 300.0, cx: 320.0, cy: 240.0}", "intrinsics: *k", text)
    rig = parse_rig(text)
    assert rig.camera("front_left").intrinsics == rig.camera("front_right").intrinsics


def test_error_lines_stay_one_line_with_odd_keys():
    text = edit("    model: pinhole", '    "mo\\ndel": pinhole')
    with pytest.raises(RigFileError) as e:
        parse_rig(text, "odd.yaml")
    assert "\n" not in str(e.value) and "mo\\ndel" in str(e.value)


@pytest.mark.parametrize("depth", [1000, 100_000])
def test_deep_nesting_is_refused_not_crashed(depth):
    # (libyaml's C composer would overflow the C stack here and kill the interpreter)
    text = BASE + "calibration: {x: " + "[" * depth + "]" * depth + "}\n"
    with pytest.raises(RigFileError, match="deep.yaml: not valid YAML: nested too deeply"):
        parse_rig(text, "deep.yaml")


def test_fast_and_pure_python_yaml_loaders_agree():
    """load_yaml takes libyaml's parser for texts that cannot nest deeply (rig._loader_for)
    and the pure-Python one otherwise: same document, same errors."""
    from rigcal.core import rig as rig_mod

    assert rig_mod._loader_for(BASE) is rig_mod._FastStrictLoader
    long_line = BASE + "# " + "x" * (rig_mod.FAST_YAML_MAX_LINE + 1) + "\n"
    assert rig_mod._loader_for(long_line) is rig_mod._StrictLoader
    many = BASE + "calibration: {x: [" + "[], " * rig_mod.FAST_YAML_MAX_BRACKETS + "]}\n"
    assert rig_mod._loader_for(many) is rig_mod._StrictLoader
    assert parse_rig(BASE, "a.yaml") == parse_rig(long_line, "a.yaml")
    dup = edit("    model: pinhole", "    model: pinhole\n    model: fisheye")
    for text in (dup, dup + "# " + "x" * (rig_mod.FAST_YAML_MAX_LINE + 1) + "\n"):
        with pytest.raises(RigFileError, match="duplicate"):
            parse_rig(text, "dup.yaml")


def test_rig_file_encodings_and_folders(tmp_path):
    """UTF-16 with a byte order mark (Windows PowerShell's `>`) is YAML and loads; other
    bytes and a folder get one line saying so, not a Python exception's text."""
    src = ROOT / "rigs" / "drone-stereo-back.yaml"
    text = src.read_text(encoding="utf-8")
    wide = tmp_path / "utf16.yaml"
    wide.write_bytes(text.encode("utf-16"))
    assert load_rig(wide) == load_rig(src)
    latin = tmp_path / "latin1.yaml"
    latin.write_bytes(("# caméra\n" + text).encode("latin-1"))
    with pytest.raises(RigFileError, match=r"latin1\.yaml: not UTF-8 text \(byte 0xe9 at offset 5\); expected a YAML "
                                            r"file saved as UTF-8$"):
        load_rig(latin)
    with pytest.raises(RigFileError, match=r": is a folder; expected a YAML file$"):
        load_rig(tmp_path)
