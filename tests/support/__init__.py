"""Helpers the tests (and benchmarks) share: synthetic observations, golden-file comparison, an independent renderer, recordings in other tools' formats."""
