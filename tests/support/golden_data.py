"""Golden files compared as data, never as text.

The last digit of a float differs between machines (CPU, BLAS kernels, libm), so the
exports under tests/golden/exports are parsed, and the fresh and stored trees compared:
structure, keys, strings and comment lines exactly; numbers within

    |fresh - stored| <= RTOL * max(|fresh|, |stored|) + ATOL

RTOL = 1e-12 is ~4,500 ulp: room for a different summation order or libm rounding
carried through a chain of products (quaternion from a matrix, cv2.stereoRectify),
while a real change (a different formula, a rounded or truncated value, a changed
model) moves a number by far more. ATOL = 1e-14 covers entries that are zero in
exact arithmetic but carry rounding noise of a few ulp of the unit-size numbers around
them (a rotation matrix's off-diagonal, 2.2e-16 per operation); nothing exported is
both meaningful and that small.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import yaml

RTOL = 1e-12
ATOL = 1e-14


class _GoldenLoader(yaml.SafeLoader):
    """SafeLoader that also reads OpenCV FileStorage YAML (`%YAML 1.2`, `!!opencv-matrix`)."""


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> dict:
    return {"!!opencv-matrix": loader.construct_mapping(node, deep=True)}


_GoldenLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)


def load(path: Path) -> tuple[Any, list[str]]:
    """(parsed document, comment lines) of one exported file."""
    text = path.read_text()
    comments = [line.strip() for line in text.splitlines() if line.lstrip().startswith("#")]
    if path.suffix == ".json":
        return json.loads(text), comments
    if text.startswith("%YAML"):  # OpenCV's directive; PyYAML reads 1.2 documents as 1.1 ones
        text = text.split("\n", 1)[1]
    return yaml.load(text, Loader=_GoldenLoader), comments


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def differences(fresh: Any, stored: Any, path: str = "") -> list[str]:
    """Every place where two parsed documents differ beyond the stated tolerance."""
    where = path or "<root>"
    if _is_number(fresh) and _is_number(stored):
        if isinstance(fresh, int) != isinstance(stored, int):
            return [f"{where}: {stored!r} became {fresh!r} (integer vs float)"]
        if math.isnan(fresh) and math.isnan(stored):
            return []
        if abs(fresh - stored) <= RTOL * max(abs(fresh), abs(stored)) + ATOL:
            return []
        return [f"{where}: {stored!r} became {fresh!r}"]
    if type(fresh) is not type(stored):
        return [f"{where}: {type(stored).__name__} {stored!r} became {type(fresh).__name__} {fresh!r}"]
    if isinstance(fresh, dict):
        if list(fresh) != list(stored):
            return [f"{where}: keys {list(stored)} became {list(fresh)}"]
        return [d for k in fresh for d in differences(fresh[k], stored[k], f"{path}.{k}" if path else str(k))]
    if isinstance(fresh, list):
        if len(fresh) != len(stored):
            return [f"{where}: {len(stored)} items became {len(fresh)}"]
        return [d for i, (a, b) in enumerate(zip(fresh, stored)) for d in differences(a, b, f"{path}[{i}]")]
    return [] if fresh == stored else [f"{where}: {stored!r} became {fresh!r}"]


def file_differences(fresh: Path, stored: Path) -> list[str]:
    """differences() of two exported files, comment lines included (compared as text)."""
    (a, ca), (b, cb) = load(fresh), load(stored)
    out = differences(a, b)
    if ca != cb:
        out.append(f"comment lines changed: {cb} became {ca}")
    return out
