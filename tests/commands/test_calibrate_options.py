"""`rigcal calibrate`'s options reach the library as one frozen CalibrateOptions whose
fields are named as the flags, and `--help` groups them in panels."""

from __future__ import annotations

import dataclasses
import inspect

import pytest
import typer.main

from rigcal.cli import app, calibrate
from rigcal.commands.calibrate import CalibrateOptions
from rigcal.errors import InputError


def test_every_flag_is_a_field_of_the_same_name():
    flags = {n for n in inspect.signature(calibrate).parameters if n not in ("dataset", "out_yaml")}
    fields = {f.name for f in dataclasses.fields(CalibrateOptions)}
    assert flags == fields, flags ^ fields
    assert dataclasses.is_dataclass(CalibrateOptions) and CalibrateOptions.__dataclass_params__.frozen


def test_every_option_sits_in_a_help_panel():
    command = typer.main.get_command(app).commands["calibrate"]
    panels = {p.name: getattr(p, "rich_help_panel", None) for p in command.params if p.name != "dataset"}
    assert all(panels.values()), [n for n, v in panels.items() if not v]
    assert len(set(panels.values())) == 4


def test_the_imu_step_options_follow_the_flags():
    o = CalibrateOptions(offset_window=0.5, knot_spacing=0.02, rolling_shutter=True, imu_intrinsics="joint")
    step = o.imu_step("imu0")
    assert (step.imu, step.offset_window, step.knot_spacing, step.rolling_shutter, step.imu_intrinsics) == (
        "imu0", 0.5, 0.02, True, "joint")
    assert CalibrateOptions().imu_step("imu0").rolling_shutter is None  # only where the rig declares a line delay
    assert CalibrateOptions(fix_intrinsics=True, imu_intrinsics="joint").imu_step("imu0").imu_intrinsics == "held"
    with pytest.raises(InputError, match="--knot-spacing"):
        CalibrateOptions(knot_spacing=2.0).imu_step("imu0")
