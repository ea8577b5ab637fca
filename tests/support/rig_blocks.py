"""Rig-file text for an IMU, and the check of a rig file refused in one line, shared by the
rig-loader and IMU-simulation tests."""

IMU_BLOCK = """\
imus:
  imu0:
    position: [0.01, 0.02, -0.03]
    axes: [F, -L, -U]
    update_rate: 200.0
    gyroscope_noise_density: 1.7e-4
    gyroscope_random_walk: 1.9e-5
    accelerometer_noise_density: 2.0e-3
    accelerometer_random_walk: 3.0e-3
"""


def assert_one_line_refusal(r, path, key: str, expected: str, out) -> None:
    """A CliRunner result refusing the rig file `path`: exit 2, one stderr line naming the
    file and `key` and saying `expected`, no traceback, nothing written at `out`."""
    assert r.exit_code == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert f"{path}: {key}: " in lines[0], lines[0]
    assert expected in lines[0]
    assert "Traceback" not in r.stderr and not out.exists()
