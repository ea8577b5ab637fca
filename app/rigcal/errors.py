"""One exception tree. The CLI turns RigcalError into one stderr line and exit 2
(bad input) or exit 1 (the work itself failed)."""

from __future__ import annotations


class RigcalError(Exception):
    """Base of every error rigcal raises on purpose. `exit_code` is what the CLI returns."""

    exit_code = 2


class InputError(RigcalError):
    """Bad input: a file, key or value that breaks a contract. Exit 2."""


class RigFileError(InputError):
    """A rig YAML file breaks docs/formats.md#rig-yaml. Message: `file: key.path: what was expected`."""


class TargetFileError(InputError):
    """A target YAML file breaks docs/formats.md#dataset."""


class DatasetError(InputError):
    """A dataset folder breaks the layout of docs/formats.md#dataset."""


class OutputError(InputError):
    """An output path that cannot be written (exists, unwritable, disk full)."""


class CalibrationError(RigcalError):
    """The work itself failed (e.g. a camera never linked to the rest). Exit 1."""

    exit_code = 1
