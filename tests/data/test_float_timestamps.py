"""Timestamps written as floats ("1.6000000000025e+18") in rigcal's three sample readers: the
motion dataset's IMU and magnetometer files and `rigcal imu-noise`'s recording. numpy 2.2 and
older read such a field of an integer column through a float, rounded to 256 ns, with only a
DeprecationWarning; in order, nothing else would refuse it. Each reader refuses the row in
one line instead (the 3.10 test environment has such a numpy)."""

from __future__ import annotations

import pytest

from rigcal.data.imu_csv import read_imu_csv
from rigcal.data.mag_csv import read_mag_csv
from rigcal.errors import DatasetError, InputError
from rigcal.imunoise.recording import read_imu_file


def _stamps(n: int) -> list[str]:
    return [f"{1.6e18 + k * 2.5e6:.13e}" for k in range(n)]


@pytest.mark.parametrize("reader, values, error", [
    (read_imu_csv, "0,0,0,0,0,9.8", DatasetError),
    (read_imu_file, "0,0,0,0,0,9.8", InputError),
    (read_mag_csv, "20,0,40", DatasetError),
])
def test_timestamps_written_as_floats_are_refused_even_in_order(tmp_path, reader, values, error):
    p = tmp_path / "samples.csv"
    p.write_text("#timestamp [ns],...\n" + "".join(f"{t},{values}\n" for t in _stamps(20)))
    with pytest.raises(error, match=r"row 2: timestamp '1\.6000000000000e\+18' is not an integer"):
        reader(p)
