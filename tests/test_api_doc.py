"""The README's "Python API" example (docs/python-api.md) runs as a doctest."""

from __future__ import annotations

import doctest
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "python-api.md"


def test_python_api_example_runs_as_written(monkeypatch):
    monkeypatch.chdir(ROOT)  # the example loads rigs by paths relative to the repository root
    result = doctest.testfile(str(DOC), module_relative=False, optionflags=doctest.NORMALIZE_WHITESPACE,
                              verbose=False, report=True)
    assert result.attempted >= 20, "the example lost its code"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {DOC.name} failed (see output)"
