"""`corners/<camera>.csv`: corners detected elsewhere, instead of images (docs/formats.md#dataset).

    #frame,board,corner_id,x_px,y_px
    1404733405732800000,grid,0,175.9867,336.8252

`frame` is the stem the image would have had, `board` a board name of target.yaml,
`corner_id` a row of that board's Board.corners, pixels in the raw (distorted) image with
the origin at the centre of the top-left pixel (rigcal's and OpenCV's convention). Bad
rows raise DatasetError naming the file and the row (1-based line number).
"""

from __future__ import annotations

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


def _numbers(col: np.ndarray, line_no: np.ndarray, path: Path, name: str, integer: bool = False) -> np.ndarray:
    try:
        x = col.astype(float)
    except ValueError:
        bad = next(k for k, c in enumerate(col) if not parses_as_float(c))
        raise DatasetError(f"{path}: row {line_no[bad]}: {name}: expected a number, got {col[bad]!r}") from None
    bad = ~np.isfinite(x) | ((x != np.round(x)) | (x < 0) if integer else np.zeros(len(x), bool))
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


def _group(frames, boards, ids, uv) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """Rows -> one view per (frame, board), ids ascending."""
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
