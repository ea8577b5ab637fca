"""Property tests for the target loader: whatever target.yaml holds, parse_target /
target_from_dict either return a Target that round-trips through the writer or raise
TargetFileError (one line), never anything else; generated valid targets load to what
they say and round-trip."""

from __future__ import annotations


import cv2
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rigcal.errors import TargetFileError
from rigcal.core.target import dump_target, parse_target, target_from_dict, target_to_dict

VALID_TEXTS = [
    # the spec's example (dataset.md)
    """boards:
  - name: front_wall
    type: charuco                # charuco | chessboard
    dictionary: DICT_5X5_1000    # a cv2.aruco predefined dictionary name
    squares: [10, 7]             # squares along the board's x, along its y
    square_length: 0.08          # metres
    marker_length: 0.06          # metres
    first_marker_id: 0           # markers are ids first_marker_id .. first_marker_id + n - 1
    legacy_pattern: false        # OpenCV's pre-4.6 ChArUco layout
  - name: back_wall
    type: charuco
    dictionary: DICT_5X5_1000
    squares: [10, 7]
    square_length: 0.08
    marker_length: 0.06
    first_marker_id: 35
""",
    # a calib.io board (even rows: legacy layout) and an inverted-print board, flow style
    """boards:
  - {name: calibio, type: charuco, dictionary: DICT_4X4_250, squares: [31, 16], square_length: 0.04933,
     marker_length: 0.03846, legacy_pattern: true}
""",
    "boards:\n  - {type: chessboard, inner_corners: [9, 6], square_length: 0.025}\n",
    "boards:\n- name: ecocheck\n  type: chessboard\n  inner_corners: [13, 9]\n  square_length: 0.03\n",
    # Kalibr's AprilGrid (dataset.md) beside a ChArUco board, and a Kalibr target file as it is
    """boards:
  - name: grid
    type: aprilgrid
    tags: [6, 6]
    tag_size: 0.088
    tag_spacing: 0.3
    first_tag_id: 0
  - {name: wall, type: charuco, dictionary: DICT_5X5_1000, squares: [5, 4], square_length: 0.05, marker_length: 0.035}
""",
    "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n",
]
VALID_DOCS = [yaml.safe_load(t) for t in VALID_TEXTS]

SETTINGS = settings(max_examples=150, derandomize=True, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
SETTINGS_FILES = settings(SETTINGS, max_examples=80)
FAST_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # test inputs only

KEYWORDS = ["boards", "name", "type", "charuco", "chessboard", "dictionary", "squares", "square_length",
            "marker_length", "first_marker_id", "legacy_pattern", "inner_corners", "DICT_5X5_1000", "DICT_4X4_50",
            "DICT_APRILTAG_36h11", "front_wall", "true", "false", "aprilgrid", "tags", "tag_size", "tag_spacing",
            "first_tag_id", "target_type", "tagCols", "tagRows", "tagSize", "tagSpacing", "checkerboard"]
scalars = st.one_of(
    st.none(), st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30), st.integers(min_value=10**300, max_value=10**400),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0, 1, 2, 3, -1, 0.5, 0.08, 0.06, 1e-300, 10**6]),
    st.text(max_size=12), st.sampled_from(KEYWORDS))
keys = st.one_of(st.sampled_from(KEYWORDS), st.text(max_size=8), st.integers(-3, 3), st.booleans(), st.none())
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                       st.dictionaries(keys, inner, max_size=5)), max_leaves=25)


def to_yaml(doc) -> str:
    return yaml.dump(doc, Dumper=FAST_DUMPER, allow_unicode=True)


def only_target_file_errors(load, *args):
    """Call the loader; a one-line TargetFileError is fine; a Target must round-trip."""
    try:
        target = load(*args)
    except TargetFileError as e:
        assert "\n" not in str(e) and str(e).startswith(args[-1]), str(e)
        return None
    text = dump_target(target)
    again = parse_target(text, "written.yaml")
    assert again == target
    assert dump_target(again) == text
    return target


# ----------------------------------------------------------------------------- arbitrary input


@SETTINGS
@given(values)
def test_arbitrary_documents_only_raise_target_file_errors(doc):
    only_target_file_errors(target_from_dict, doc, "any.yaml")


@SETTINGS
@given(st.lists(values, max_size=4))
def test_arbitrary_board_lists_only_raise_target_file_errors(boards):
    only_target_file_errors(target_from_dict, {"boards": boards}, "any.yaml")


@SETTINGS
@given(values)
def test_arbitrary_yaml_text_only_raises_target_file_errors(doc):
    try:
        text = to_yaml(doc)
    except yaml.YAMLError:
        return  # not representable in YAML; nothing to load
    only_target_file_errors(parse_target, text, "any.yaml")


@SETTINGS
@given(st.text(alphabet=st.sampled_from(list("abcDICT_X5:[]{},&*!|>'\"#%@ -\n\t.0123456789")) | st.characters(),
               max_size=200))
def test_arbitrary_text_only_raises_target_file_errors(text):
    only_target_file_errors(parse_target, text, "any.yaml")


TAGGED = ["!!float abc", "!!int x", "!!bool maybe", "!!timestamp x", "!!binary ===", "!!set {a: 1}",
          "!!omap [a: 1]", "!!pairs [a: 1]", "!!python/object:os.system x", "&a [*a]", "2001-13-01",
          "*undefined", "!!str 1", "!!null x", "{<<: 1}", "[" * 300, ".nan", "-.inf", "1e999", "0x10", "1_000"]


@SETTINGS
@given(st.sampled_from(range(len(VALID_TEXTS))), st.data())
def test_valid_files_with_a_line_replaced_only_raise_target_file_errors(i, data):
    lines = VALID_TEXTS[i].splitlines()
    n = data.draw(st.integers(0, len(lines) - 1))
    indent = len(lines[n]) - len(lines[n].lstrip())
    key = lines[n].strip().lstrip("- ").split(":")[0]
    new = data.draw(st.one_of(st.sampled_from(TAGGED), st.text(max_size=20)))
    lines[n] = " " * indent + f"{key}: {new}"
    only_target_file_errors(parse_target, "\n".join(lines), "mutated.yaml")


# ----------------------------------------------------------------------------- mutations of valid targets


from tests.support.doc_paths import mutated_docs as shared_mutated_docs  # noqa: E402 (shared with the other loader's properties)


NUMBER_EDITS = [0, -1, 1, 2, 3, 10**9, -0.0, 1e-320, 1e308, float("nan"), float("inf"), 10**400, True, "1", None,
                [], {}, [3, 3], [0, 5], [10**9, 10**9], "DICT_4X4_50", "DICT_5X5_1001"]


def mutated_docs():
    return shared_mutated_docs(VALID_DOCS, NUMBER_EDITS, keys, values)




def test_integer_beyond_float_range_is_a_target_file_error():
    with pytest.raises(TargetFileError, match="square_length"):
        parse_target("boards:\n  - {type: chessboard, inner_corners: [9, 6], square_length: 1" + "0" * 400 + "}\n",
                     "big.yaml")


@SETTINGS
@given(mutated_docs())
def test_mutated_targets_only_raise_target_file_errors(doc):
    only_target_file_errors(target_from_dict, doc, "mutated.yaml")


@SETTINGS_FILES
@given(mutated_docs())
def test_mutated_targets_through_yaml_only_raise_target_file_errors(doc):
    try:
        text = to_yaml(doc)
    except yaml.YAMLError:
        return
    only_target_file_errors(parse_target, text, "mutated.yaml")


# ----------------------------------------------------------------------------- valid targets


DICTIONARY_SIZES = {name: cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0]
                    for name in ("DICT_4X4_50", "DICT_4X4_1000", "DICT_5X5_250", "DICT_5X5_1000", "DICT_6X6_250",
                                 "DICT_7X7_1000", "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_36h11")}
lengths = st.floats(min_value=1e-4, max_value=2.0, allow_nan=False)


@st.composite
def valid_targets(draw):
    """(document, boards as (name, type, squares, square, dictionary, marker, first id, legacy))."""
    if draw(st.integers(0, 4)) == 0:  # a chessboard, alone
        inner = [draw(st.integers(3, 40)), draw(st.integers(3, 40))]
        square = draw(lengths)
        d = {"type": "chessboard", "inner_corners": inner, "square_length": square}
        name = "chessboard"
        if draw(st.booleans()):
            name = d["name"] = draw(st.from_regex(r"[A-Za-z0-9_.-]{1,10}", fullmatch=True))
        return {"boards": [d]}, [(name, "chessboard", (inner[0] + 1, inner[1] + 1), square, None, None, 0, False)]
    dictionary = draw(st.sampled_from(sorted(DICTIONARY_SIZES)))
    size = DICTIONARY_SIZES[dictionary]
    names = draw(st.lists(st.from_regex(r"[A-Za-z0-9_.-]{1,10}", fullmatch=True), min_size=1, max_size=4,
                          unique=True))
    boards, expected, next_id = [], [], 0
    for name in names:
        sx, sy = draw(st.integers(2, 12)), draw(st.integers(2, 12))
        n = sx * sy // 2
        first = next_id + draw(st.integers(0, 5))
        if first + n > size:
            break
        next_id = first + n
        square = draw(lengths)
        marker = square * draw(st.floats(0.1, 0.95))
        legacy = draw(st.booleans())
        d = {"name": name, "type": "charuco", "dictionary": dictionary, "squares": [sx, sy],
             "square_length": square, "marker_length": marker}
        if first or draw(st.booleans()):
            d["first_marker_id"] = first
        if legacy or draw(st.booleans()):
            d["legacy_pattern"] = legacy
        boards.append(d)
        expected.append((name, "charuco", (sx, sy), square, dictionary, marker, first, legacy))
    if not boards:  # the first board alone did not fit the dictionary: a small one that does
        boards = [{"name": "a", "type": "charuco", "dictionary": dictionary, "squares": [3, 3],
                   "square_length": 0.1, "marker_length": 0.05}]
        expected = [("a", "charuco", (3, 3), 0.1, dictionary, 0.05, 0, False)]
    return {"boards": boards}, expected


@SETTINGS_FILES
@given(valid_targets())
def test_generated_valid_targets_load_and_round_trip(doc_and_expected):
    doc, expected = doc_and_expected
    target = parse_target(to_yaml(doc), "generated.yaml")
    got = [(b.name, b.type, b.squares, b.square_length, b.dictionary, b.marker_length, b.first_marker_id,
            b.legacy_pattern) for b in target.boards]
    assert got == expected
    text = dump_target(target)
    again = parse_target(text, "written.yaml")
    assert again == target
    assert dump_target(again) == text
    assert target_from_dict(target_to_dict(target), "dict") == target


def test_the_valid_examples_load():
    for text in VALID_TEXTS:
        assert only_target_file_errors(parse_target, text, "example.yaml") is not None
