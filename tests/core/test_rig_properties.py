"""Property tests for the rig loader: whatever a file holds, parse_rig / rig_from_dict
either return a Rig that round-trips through the writer or raise RigFileError, never
anything else; generated valid rigs always load and round-trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rigcal.core import geometry as geo
from rigcal.errors import RigFileError
from rigcal.core.rig import dump_rig, parse_rig, rig_from_dict

ROOT = Path(__file__).resolve().parents[2]
VALID_DOCS = [yaml.safe_load(p.read_text()) for p in sorted((ROOT / "rigs").glob("*.yaml"))]
VALID_TEXTS = [p.read_text() for p in sorted((ROOT / "rigs").glob("*.yaml"))]

SETTINGS = settings(max_examples=200, derandomize=True, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
# Whole-rig examples cost a YAML write and two reads each: fewer of them.
SETTINGS_RIGS = settings(SETTINGS, max_examples=100)
FAST_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # test inputs only; dump_rig's format is its own


def to_yaml(doc) -> str:
    return yaml.dump(doc, Dumper=FAST_DUMPER, allow_unicode=True)

KEYWORDS = ["rig", "body_frame", "cameras", "stereo_pairs", "calibration", "model", "resolution", "intrinsics",
            "distortion", "position", "look", "axes", "rotation", "quaternion", "fx", "fy", "cx", "cy", "focal",
            "left", "right", "baseline_m", "pinhole", "fisheye", "FLU", "forward", "down", "F", "-L", "-U"]

scalars = st.one_of(
    st.none(), st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30), st.integers(min_value=10**300, max_value=10**400),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0, 1, -1, 0.5, 640, 480, 300.0, 1e-300]),
    st.text(max_size=12), st.sampled_from(KEYWORDS))
keys = st.one_of(st.sampled_from(KEYWORDS), st.text(max_size=8), st.integers(-3, 3), st.booleans(), st.none())
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                       st.dictionaries(keys, inner, max_size=5)), max_leaves=25)


def only_rig_file_errors(load, *args):
    """Call the loader; a RigFileError is fine; a Rig must round-trip through the writer."""
    try:
        rig = load(*args)
    except RigFileError as e:
        assert "\n" not in str(e)
        return None
    assert parse_rig(dump_rig(rig)) == rig
    return rig


# ----------------------------------------------------------------------------- arbitrary documents


@SETTINGS
@given(values)
def test_arbitrary_documents_only_raise_rig_file_errors(doc):
    only_rig_file_errors(rig_from_dict, doc, "any.yaml")


@SETTINGS
@given(values)
def test_arbitrary_yaml_text_only_raises_rig_file_errors(doc):
    try:
        text = to_yaml(doc)
    except yaml.YAMLError:
        return  # not representable (e.g. a key YAML cannot write); nothing to load
    only_rig_file_errors(parse_rig, text, "any.yaml")


@SETTINGS
@given(st.text(alphabet=st.sampled_from(list("abcFLU-_:[]{},&*!|>'\"#%@ \n\t.0123456789")) | st.characters(),
               max_size=200))
def test_arbitrary_text_only_raises_rig_file_errors(text):
    only_rig_file_errors(parse_rig, text, "any.yaml")


TAGGED = ["!!float abc", "!!int x", "!!bool maybe", "!!timestamp x", "!!binary ===", "!!set {a: 1}",
          "!!omap [a: 1]", "!!pairs [a: 1]", "!!python/object:os.system x", "&a [*a]", "2001-13-01",
          "*undefined", "!!str 1", "!!null x", "!!merge x", "{<<: 1}", "[" * 300]


@SETTINGS
@given(st.sampled_from(range(len(VALID_TEXTS))), st.data())
def test_valid_files_with_a_line_replaced_only_raise_rig_file_errors(i, data):
    lines = VALID_TEXTS[i].splitlines()
    n = data.draw(st.integers(0, len(lines) - 1))
    indent = len(lines[n]) - len(lines[n].lstrip())
    key = lines[n].strip().split(":")[0]
    new = data.draw(st.one_of(st.sampled_from(TAGGED), st.text(max_size=20)))
    lines[n] = " " * indent + f"{key}: {new}"
    only_rig_file_errors(parse_rig, "\n".join(lines), "mutated.yaml")


# ----------------------------------------------------------------------------- mutations of valid rigs


from tests.support.doc_paths import mutated_docs as shared_mutated_docs  # noqa: E402 (shared with the other loader's properties)


NUMBER_EDITS = [0, -1.0, 1e-320, 1e308, float("nan"), float("inf"), -0.0, 10**400, True, "1", None, [], {}]


def mutated_docs():
    return shared_mutated_docs(VALID_DOCS, NUMBER_EDITS, keys, values)


@SETTINGS
@given(mutated_docs())
def test_mutated_rigs_only_raise_rig_file_errors(doc):
    only_rig_file_errors(rig_from_dict, doc, "mutated.yaml")


@SETTINGS
@given(mutated_docs())
def test_mutated_rigs_through_yaml_only_raise_rig_file_errors(doc):
    try:
        text = to_yaml(doc)
    except yaml.YAMLError:
        return
    only_rig_file_errors(parse_rig, text, "mutated.yaml")


# ----------------------------------------------------------------------------- valid rigs


finite = st.floats(min_value=-10, max_value=10, allow_nan=False)
positive = st.floats(min_value=1.0, max_value=5000.0)
unit_quaternions = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1).map(lambda q: list(np.asarray(q) / np.linalg.norm(q)))


@st.composite
def orientations(draw):
    """(key, value, R_body_cam) for one of the four orientation forms."""
    form = draw(st.sampled_from(["look", "axes", "axes_vectors", "rotation", "quaternion"]))
    if form == "look":
        look = draw(st.sampled_from(sorted(geo.LOOK_AXES)))
        return "look", look, geo.R_from_look(look)
    if form == "axes":
        look = draw(st.sampled_from(sorted(geo.LOOK_AXES)))
        return "axes", list(geo.LOOK_AXES[look]), geo.R_from_look(look)
    R = geo.R_from_quat(draw(unit_quaternions))
    if form == "axes_vectors":  # columns given with arbitrary positive lengths
        scale = draw(st.lists(st.floats(0.1, 10), min_size=3, max_size=3))
        return "axes", [[float(x) for x in R[:, i] * scale[i]] for i in range(3)], R
    if form == "rotation":
        noise = draw(st.floats(0, 2e-7))  # within the 1e-6 orthonormality tolerance
        Rn = R + noise * np.ones((3, 3))
        return "rotation", Rn.tolist(), Rn
    q = geo.quat_from_R(R)
    return "quaternion", [float(x) for x in q], R


@st.composite
def valid_rigs(draw):
    names = draw(st.lists(st.from_regex(r"[a-z0-9_]{1,8}", fullmatch=True), min_size=1, max_size=4, unique=True))
    cams, Rs = {}, {}
    for name in names:
        model = draw(st.sampled_from(["pinhole", "fisheye"]))
        w, h = draw(st.integers(1, 4000)), draw(st.integers(1, 4000))
        cam = {"model": model, "resolution": [w, h]}
        if draw(st.booleans()):
            cam["intrinsics"] = {"focal": draw(positive)}
        else:
            cam["intrinsics"] = {"fx": draw(positive), "fy": draw(positive), "cx": draw(finite) + w / 2,
                                 "cy": draw(finite) + h / 2}
        n_dist = 4 if model == "fisheye" else draw(st.sampled_from([2, 4, 5, 8, 12]))
        if draw(st.booleans()):
            cam["distortion"] = draw(st.lists(st.floats(-0.5, 0.5), min_size=n_dist, max_size=n_dist))
        if draw(st.integers(0, 4)):  # most cameras have a pose
            cam["position"] = draw(st.lists(finite, min_size=3, max_size=3))
            key, value, R = draw(orientations())
            cam[key] = value
            Rs[name] = R
        if draw(st.booleans()):
            cam["calibration"] = {"reprojection_rms_px": draw(st.floats(0, 5)), "frames": draw(st.integers(0, 99)),
                                  "sigma": {"position_mm": draw(st.lists(st.floats(0, 9), min_size=3, max_size=3))}}
        cams[name] = cam
    doc = {"rig": draw(st.text(max_size=10)), "cameras": cams}
    if len(names) >= 2 and draw(st.booleans()):
        a, b = names[:2]
        if cams[a].get("position") != cams[b].get("position"):
            doc["stereo_pairs"] = [[a, b] if draw(st.booleans()) else {"left": a, "right": b, "baseline_m": 0.1}]
    return doc, Rs


@SETTINGS_RIGS
@given(valid_rigs())
def test_generated_valid_rigs_load_and_round_trip(doc_and_R):
    doc, Rs = doc_and_R
    rig = rig_from_dict(doc, "generated.yaml")
    assert rig.names == tuple(doc["cameras"])
    for name, R in Rs.items():
        np.testing.assert_allclose(rig.camera(name).T_body_cam[:3, :3], R, atol=1e-12)
        np.testing.assert_allclose(rig.camera(name).T_body_cam[:3, 3], doc["cameras"][name]["position"])
    text = dump_rig(rig)
    again = parse_rig(text, "written.yaml")
    assert again == rig
    assert dump_rig(again) == text
