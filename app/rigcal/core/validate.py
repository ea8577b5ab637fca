"""Field validators shared by the file loaders (rig, target): each takes the key path and
an `err(key, message)` factory, so every refusal is one line naming file, key, expected
and got. Numbers must be finite (integers beyond float range included)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

def describe(v: Any, limit: int = 60) -> str:
    """A value, described briefly for an error line."""
    if v is None:
        return "nothing"
    if isinstance(v, dict):
        return "a mapping" if v else "an empty mapping"
    if isinstance(v, str):
        return "text " + shorten(repr(v), limit)
    return shorten(repr(v), limit)


def shorten(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def refuse_unknown_keys(d: dict, allowed: Sequence[str], key: str, err) -> None:
    for k in d:
        if k not in allowed:
            hint = _closest(str(k), allowed)
            # a key with a line break (or other control characters) is shown quoted: the error is one line
            name = shorten(str(k) if str(k).isprintable() else repr(str(k)), 60)
            at = f"{key}.{name}" if key else name
            raise err(at, "unknown key" + (f" (did you mean `{hint}`?)" if hint else "")
                      + f"; expected one of {', '.join(allowed)}")


def _closest(word: str, options: Sequence[str]) -> str | None:
    import difflib

    m = difflib.get_close_matches(word, options, n=1, cutoff=0.6)
    return m[0] if m else None


def finite_number(v: Any, key: str, err) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise err(key, f"expected a number, got {describe(v)}")
    try:
        x = float(v)
    except OverflowError:  # an integer beyond float range
        x = math.inf
    if not math.isfinite(x):
        raise err(key, f"expected a finite number, got {describe(v)}")
    return x


def positive_number(v: Any, key: str, err) -> float:
    x = finite_number(v, key, err)
    if x <= 0:
        raise err(key, f"expected a positive number, got {v!r}")
    return x


def number_vector(v: Any, n: int, key: str, err) -> np.ndarray:
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise err(key, f"expected {n} numbers, got {describe(v)}")
    return np.array([finite_number(x, f"{key}[{i}]", err) for i, x in enumerate(v)])


def check_finite_tree(v: Any, key: str, err) -> None:
    """Free-form stats blocks (calibration, depth_check) hold mappings with text keys, lists,
    text, booleans and finite numbers, which is what the writer can round-trip."""
    if isinstance(v, dict):
        for k, x in v.items():
            if not isinstance(k, str):
                raise err(key, f"expected text keys, got {describe(k)}")
            check_finite_tree(x, f"{key}.{k}", err)
    elif isinstance(v, list):
        for i, x in enumerate(v):
            check_finite_tree(x, f"{key}[{i}]", err)
    elif isinstance(v, (int, float)):  # bool is an int
        finite_number(float(v) if isinstance(v, bool) else v, key, err)
    elif v is not None and not isinstance(v, str):
        raise err(key, f"expected numbers, text, lists or mappings, got {describe(v)}")


def parses_as_float(text: str) -> bool:
    """Whether float() reads `text` (a CSV cell): finds the cell to name in an error."""
    try:
        float(text)
        return True
    except ValueError:
        return False


def read_text(path: str | Path, error: type[Exception]) -> str:
    """An input file's text, or one line `file: file not found` / `file: cannot read (...)`."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder; expected a YAML file") from None
    except OSError as e:
        raise error(f"{path}: cannot read ({e.__class__.__name__}: {e})") from None
    # YAML allows UTF-16 with a byte order mark (what Windows PowerShell's `>` writes)
    encoding = "utf-16" if data[:2] in (b"\xff\xfe", b"\xfe\xff") else "utf-8"
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as e:
        raise error(f"{path}: not {encoding.upper()} text (byte 0x{data[e.start]:02x} at offset {e.start}); "
                    f"expected a YAML file saved as UTF-8") from None
