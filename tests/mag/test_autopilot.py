"""px4_mag_params / ardupilot_mag_params: each autopilot's published correction, written out
here from its source (PX4 calibration::Magnetometer::Correct, ArduPilot
AP_Compass_Backend::rotate_field then correct_field), applied to raw readings with the exported
parameters, gives rigcal's calibrated field in FRD and the autopilot's units."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.core import geometry as geo
from rigcal.core.rig import parse_rig
from rigcal.mag import model
from rigcal.mag.autopilot import (R_FRD_FLU, R_from_euler_deg, ardupilot_mag_params, nearest_enum,
                                  px4_mag_params, px4_rotation_residual_deg)

H = np.array([12.0, -25.0, 7.5])
A = model.normalise(model.sym_from_vec(np.array([1.08, 0.93, 1.01, 0.04, -0.02, 0.03])), 1.0)[0]


def _rig(R_body_mag: np.ndarray, h=H, A_=A) -> object:
    cal = {"hard_iron_uT": h.tolist(), "soft_iron": A_.tolist()}
    q = geo.quat_from_R(R_body_mag).tolist()
    text = f"""rig: t
imus:
  imu0: {{position: [0, 0, 0], axes: [F, L, U], update_rate: 200.0, gyroscope_noise_density: 1.0e-4,
         gyroscope_random_walk: 1.0e-5, accelerometer_noise_density: 1.0e-3, accelerometer_random_walk: 1.0e-3}}
magnetometers:
  mag0: {{quaternion: {q}, update_rate: 100.0, noise_density: 0.05, calibration: {cal}}}
cameras:
  cam0: {{resolution: [640, 480], intrinsics: {{focal: 300.0}}}}
"""
    return parse_rig(text)


def _raw(R_body_mag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raw readings (uT) of fields from every direction, and the true field in FRD (uT)."""
    rng = np.random.default_rng(0)
    b_body = rng.normal(size=(50, 3)) * 30.0
    return model.readings(b_body, H, A, R_body_mag), b_body @ R_FRD_FLU.T


def test_enum_table_known_answers():
    np.testing.assert_allclose(R_from_euler_deg(0, 0, 90) @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # YAW_90
    assert nearest_enum(np.diag([1.0, -1.0, -1.0])) == (8, pytest.approx(0.0, abs=1e-9))  # ROLL_180
    assert nearest_enum(R_from_euler_deg(90, 0, 270))[0] == 37
    # an FRD chip on an FLU rig is the autopilot's ROTATION_NONE
    assert nearest_enum(R_FRD_FLU @ np.diag([1.0, -1.0, -1.0]))[0] == 0


def test_offset_signs_and_units_follow_each_autopilot():
    rig = _rig(np.diag([1.0, -1.0, -1.0]), h=np.array([10.0, 0.0, 0.0]), A_=np.eye(3))
    px4, ap = px4_mag_params(rig), ardupilot_mag_params(rig)
    assert px4["CAL_MAG0_XOFF"] == pytest.approx(0.10)  # gauss, subtracted
    assert ap["COMPASS_OFS_X"] == pytest.approx(-100.0)  # milligauss, added
    assert px4["CAL_MAG0_ROT"] == 0 and ap["COMPASS_ORIENT"] == 0 and "CUST_ROT_ENABLE" not in ap


def test_px4_correction_gives_the_calibrated_field_for_an_enum_mount():
    R = R_FRD_FLU.T @ R_from_euler_deg(180, 0, 90)  # chip at ROTATION_ROLL_180_YAW_90 in FRD terms
    rig = _rig(R)
    p = px4_mag_params(rig)
    assert p["CAL_MAG0_ROT"] == 10 and px4_rotation_residual_deg(rig)["mag0"] < 1e-6
    m, b_frd = _raw(R)
    off = np.array([p["CAL_MAG0_XOFF"], p["CAL_MAG0_YOFF"], p["CAL_MAG0_ZOFF"]])
    S = np.diag([p["CAL_MAG0_XSCALE"], p["CAL_MAG0_YSCALE"], p["CAL_MAG0_ZSCALE"]])
    S[0, 1] = S[1, 0] = p["CAL_MAG0_XODIAG"]
    S[0, 2] = S[2, 0] = p["CAL_MAG0_YODIAG"]
    S[1, 2] = S[2, 1] = p["CAL_MAG0_ZODIAG"]
    corrected = ((m / 100.0 - off) @ S.T) @ R_from_euler_deg(180, 0, 90).T
    np.testing.assert_allclose(corrected, b_frd / 100.0, atol=1e-12)


@pytest.mark.parametrize("off_deg", [0.0, 2.0])
def test_ardupilot_correction_gives_the_calibrated_field(off_deg):
    R = geo.R_from_rotvec(np.radians(off_deg) * np.array([0.6, -0.48, 0.64])) @ np.diag([1.0, -1.0, -1.0])
    rig = _rig(R)
    p = ardupilot_mag_params(rig)
    m, b_frd = _raw(R)
    if off_deg == 0.0:
        assert p["COMPASS_ORIENT"] == 0 and "CUST_ROT_ENABLE" not in p
        R_orient = np.eye(3)
    else:
        assert p["COMPASS_ORIENT"] == 101 and p["CUST_ROT_ENABLE"] == 1
        R_orient = R_from_euler_deg(p["CUST_ROT1_ROLL"], p["CUST_ROT1_PITCH"], p["CUST_ROT1_YAW"])
    ofs = np.array([p["COMPASS_OFS_X"], p["COMPASS_OFS_Y"], p["COMPASS_OFS_Z"]])
    M = np.diag([p["COMPASS_DIA_X"], p["COMPASS_DIA_Y"], p["COMPASS_DIA_Z"]])
    M[0, 1] = M[1, 0] = p["COMPASS_ODI_X"]
    M[0, 2] = M[2, 0] = p["COMPASS_ODI_Y"]
    M[1, 2] = M[2, 1] = p["COMPASS_ODI_Z"]
    corrected = ((m * 10.0) @ R_orient.T + ofs) @ M.T * p["COMPASS_SCALE"]
    np.testing.assert_allclose(corrected, b_frd * 10.0, atol=1e-9)
    if off_deg:  # PX4 has only the enum: the 2 degrees remain
        assert px4_rotation_residual_deg(rig)["mag0"] == pytest.approx(2.0, abs=1e-6)


def _rig_text(calibrated: bool) -> str:
    cal = f", calibration: {{hard_iron_uT: {H.tolist()}, soft_iron: {A.tolist()}}}" if calibrated else ""
    return f"""rig: t
imus:
  imu0: {{position: [0, 0, 0], axes: [F, L, U], update_rate: 200.0, gyroscope_noise_density: 1.0e-4,
         gyroscope_random_walk: 1.0e-5, accelerometer_noise_density: 1.0e-3, accelerometer_random_walk: 1.0e-3}}
magnetometers:
  mag0: {{axes: [F, -L, -U], update_rate: 100.0, noise_density: 0.05{cal}}}
cameras:
  cam0: {{resolution: [640, 480], intrinsics: {{focal: 300.0}}, position: [0.1, 0.0, 0.0], look: forward}}
"""


@pytest.mark.parametrize("fmt, name, key", [("px4", "rigcal.params", "CAL_MAG0_XOFF"),
                                            ("ardupilot", "rigcal.param", "COMPASS_OFS_X")])
def test_autopilot_exports_carry_the_compass_parameters(tmp_path, fmt, name, key):
    """`rigcal export --format px4|ardupilot` writes the calibrated compass's parameters beside
    the vision sensor's (the values of px4_mag_params / ardupilot_mag_params); a declared
    magnetometer without a calibration is refused: one line, exit 2, nothing written."""
    from typer.testing import CliRunner

    from rigcal.cli import app

    (tmp_path / "cal.yaml").write_text(_rig_text(True))
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["export", str(tmp_path / "cal.yaml"), "--format", fmt, "--out", str(out)])
    assert r.exit_code == 0, r.output
    text = out.read_text()
    expected = (px4_mag_params if fmt == "px4" else ardupilot_mag_params)(parse_rig(_rig_text(True)))
    sep = "\t" if fmt == "px4" else ","
    got = {f[-3 if fmt == "px4" else 0]: f[-2 if fmt == "px4" else 1]
           for f in (ln.split(sep) for ln in text.splitlines() if ln and not ln.startswith("#"))}
    assert float(got[key]) == pytest.approx(expected[key], rel=1e-9)
    assert set(expected) <= set(got)

    (tmp_path / "decl.yaml").write_text(_rig_text(False))
    out2 = tmp_path / "out2"
    r = CliRunner().invoke(app, ["export", str(tmp_path / "decl.yaml"), "--format", fmt, "--out", str(out2)])
    assert r.exit_code == 2 and "magnetometers.mag0: no calibration" in r.output
    assert len(r.output.strip().splitlines()) == 1 and not out2.exists()
