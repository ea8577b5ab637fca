"""`corners/<camera>.csv`: corners detected elsewhere, instead of images (docs/formats.md#dataset).

    #frame,board,corner_id,x_px,y_px
    1404733405732800000,grid,0,175.9867,336.8252

`frame` is the stem the image would have had, `board` a board name of target.yaml,
`corner_id` a row of that board's Board.corners, pixels in the raw (distorted) image with
the origin at the centre of the top-left pixel (rigcal's and OpenCV's convention). Bad
rows raise DatasetError naming the file and the row (1-based line number).
"""

from __future__ import annotations

import operator
import re
from pathlib import Path

import numpy as np

from rigcal.errors import DatasetError
from rigcal.core.target import Target
from rigcal.core.validate import parses_as_float

COLUMNS = ("frame", "board", "corner_id", "x_px", "y_px")
HEADER = "#" + ",".join(COLUMNS)


def read_corners(path: str | Path, target: Target) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """Views (frame, board, ids (N,) ascending, uv (N, 2)) of one camera's corners file, in
    file order of first appearance."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    fast = _parse_clean(text, target)
    if fast is not None:
        return _group(*fast)
    # the row-by-row reading below finds and names the first bad row
    rows, lines = [], []
    for n, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        cells = [c.strip() for c in s.split(",")]
        if len(cells) != len(COLUMNS):
            raise DatasetError(f"{path}: row {n}: expected {len(COLUMNS)} columns ({','.join(COLUMNS)}), "
                               f"got {len(cells)}")
        rows.append(cells)
        lines.append(n)
    if not rows:
        raise DatasetError(f"{path}: no corners (expected rows {HEADER[1:]})")
    cells = np.array(rows, dtype=object)
    line_no = np.array(lines)
    frames, boards = cells[:, 0].astype(str), cells[:, 1].astype(str)
    ids = _numbers(cells[:, 2], line_no, path, "corner_id", integer=True)
    uv = np.column_stack([_numbers(cells[:, k], line_no, path, COLUMNS[k]) for k in (3, 4)])
    _check_rows(frames, boards, ids, line_no, path, target)
    return _group(frames, boards, ids, uv)


_SPACE = re.compile(r"\s")


def _parse_clean(text: str, target: Target) -> tuple | None:
    """(frames, boards, ids, uv) of a file that read_corners would accept as it is, read a
    column at a time (a row-by-row read of EuRoC's 180,000 rows took seconds); None when any
    row is other than clean (blank or indented lines, spaces in cells, a wrong column count,
    a bad number, board or id, a repeated corner), for read_corners' row-by-row reading to
    name the row."""
    if "\x00" in text:  # numpy's fixed-width strings drop trailing NULs
        return None
    body = [s for s in text.splitlines() if s and s[0] != "#"]
    if not body or set(map(operator.methodcaller("count", ","), body)) != {len(COLUMNS) - 1}:
        return None
    joined = ",".join(body)
    if _SPACE.search(joined):
        return None
    cells = joined.split(",")
    try:  # float() as the row-by-row reading's object arrays use it
        ids_f, x, y = (np.fromiter(map(float, cells[k::len(COLUMNS)]), float, count=len(body)) for k in (2, 3, 4))
    except ValueError:
        return None
    if not (np.isfinite(ids_f).all() and np.isfinite(x).all() and np.isfinite(y).all()
            and (ids_f == np.round(ids_f)).all() and (ids_f >= 0).all()):
        return None
    frame_list, board_list = cells[0::len(COLUMNS)], cells[1::len(COLUMNS)]
    frame_k, board_k = _codes(frame_list), _codes(board_list)
    names = list(dict.fromkeys(board_list))
    sizes = {b.name: b.n_corners for b in target.boards}
    if any(b not in sizes for b in names):
        return None
    if (ids_f >= np.array([sizes[b] for b in names])[board_k]).any():
        return None
    ids = ids_f.astype(np.int64)
    pair = frame_k * len(names) + board_k
    key = np.sort(pair * (int(ids.max()) + 1) + ids)
    if (key[1:] == key[:-1]).any():
        return None
    return np.array(frame_list, dtype=str), np.array(board_list, dtype=str), ids, np.column_stack([x, y]), pair


def _codes(cells: list[str]) -> np.ndarray:
    """Each cell's index among the distinct cells (in order of first appearance)."""
    index = {c: k for k, c in enumerate(dict.fromkeys(cells))}
    return np.fromiter(map(index.__getitem__, cells), np.int64, count=len(cells))


def _numbers(col: np.ndarray, line_no: np.ndarray, path: Path, name: str, integer: bool = False) -> np.ndarray:
    try:
        x = col.astype(float)
    except ValueError:
        bad = next(k for k, c in enumerate(col) if not parses_as_float(c))
        raise DatasetError(f"{path}: row {line_no[bad]}: {name}: expected a number, got {col[bad]!r}") from None
    # an integer past int64 (1e300) would cast to an arbitrary id
    bad = ~np.isfinite(x) | ((x != np.round(x)) | (x < 0) | (x >= 2.0 ** 62) if integer else np.zeros(len(x), bool))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        what = "a non-negative integer" if integer else "a finite number"
        raise DatasetError(f"{path}: row {line_no[k]}: {name}: expected {what}, got {col[k]!r}")
    return x.astype(np.int64) if integer else x


def _check_rows(frames, boards, ids, line_no, path: Path, target: Target) -> None:
    sizes = {b.name: b.n_corners for b in target.boards}
    unknown = ~np.isin(boards, list(sizes))
    if unknown.any():
        k = int(np.flatnonzero(unknown)[0])
        raise DatasetError(f"{path}: row {line_no[k]}: board {str(boards[k])!r} is not in the target "
                           f"(boards: {', '.join(sizes)})")
    limit = np.array([sizes[b] for b in boards])
    out = ids >= limit
    if out.any():
        k = int(np.flatnonzero(out)[0])
        raise DatasetError(f"{path}: row {line_no[k]}: corner_id {ids[k]} is outside board {str(boards[k])!r} "
                           f"(ids 0..{limit[k] - 1})")
    key = np.char.add(np.char.add(frames.astype(str), "\x00" + np.char.add(boards.astype(str), "\x00")),
                      ids.astype(str))
    _, first, counts = np.unique(key, return_index=True, return_counts=True)
    if (counts > 1).any():
        dup = key == key[first[counts > 1][0]]
        a, b = line_no[np.flatnonzero(dup)[:2]]
        raise DatasetError(f"{path}: row {b}: frame {frames[dup][0]}, board {boards[dup][0]}, corner_id "
                           f"{ids[dup][0]} already given in row {a}")


def _group(frames, boards, ids, uv, pair=None) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """Rows -> one view per (frame, board), ids ascending. pair: any one value per distinct
    (frame, board), e.g. integer codes (computed from the strings when not given)."""
    if pair is None:
        pair = np.char.add(np.char.add(frames.astype(str), "\x00"), boards.astype(str))
    _, first, inverse = np.unique(pair, return_index=True, return_inverse=True)
    order = np.lexsort((ids, inverse))
    cuts = np.flatnonzero(np.diff(inverse[order])) + 1
    views = []
    for grp in np.split(order, cuts):
        k = grp[0]
        views.append((int(first[inverse[k]]), str(frames[k]), str(boards[k]), ids[grp], uv[grp]))
    views.sort(key=lambda v: v[0])
    return [v[1:] for v in views]
