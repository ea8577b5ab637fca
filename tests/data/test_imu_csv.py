"""rigcal.data.imu_csv.read_imu_csv: numpy's one-pass reader and the row-by-row one give the same
arrays, and every bad row is still refused with one line naming the file and row."""

import numpy as np
import pytest

from rigcal.data import imu_csv as mod
from rigcal.data.imu_csv import IMU_HEADER, imu_csv, read_imu_csv
from rigcal.errors import DatasetError

T0 = 1_600_000_000_000_000_000


def samples(n: int = 50, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = T0 + np.arange(n, dtype=np.int64) * 2_500_000
    return t, rng.normal(0, 0.01, (n, 3)), rng.normal([0, 0, 9.8], 0.05, (n, 3))


def test_fast_reader_takes_a_plain_file_and_matches_the_row_reader(tmp_path, monkeypatch):
    t, g, a = samples()
    p = tmp_path / "imu0.csv"
    # a BOM, CRLF line ends, a comment line and a blank line: all plain
    text = "\ufeff" + imu_csv(t, g, a).replace("\n", "\r\n", 3).replace(IMU_HEADER, IMU_HEADER + "\n# still\n")
    p.write_text(text, encoding="utf-8")
    slow = mod._read_rows(p)
    monkeypatch.setattr(mod, "_read_rows", lambda path: pytest.fail("the plain file went the slow way"))
    fast = read_imu_csv(p)
    assert fast.t_ns.dtype == np.int64
    np.testing.assert_array_equal(fast.t_ns, t)
    np.testing.assert_array_equal(fast.t_ns, slow.t_ns)
    np.testing.assert_array_equal(fast.gyro, slow.gyro)  # both correctly rounded: bit for bit
    np.testing.assert_array_equal(fast.accel, slow.accel)
    np.testing.assert_array_equal(fast.gyro, g)  # imu_csv writes the shortest text that reads back exactly


BAD_ROWS = {  # (row 4 of the file, the 3rd sample, replaced by) -> the message's tail
    "signed_stamp": ("+1600000000005000000,0,0,0,0,0,9.8", "row 4: timestamp '+1600000000005000000' is not an integer"),
    "negative_stamp": ("-1600000000005000000,0,0,0,0,0,9.8", "row 4: timestamp '-1600000000005000000' is not an integer"),
    "comment_in_row": ("1600000000005000000,0,0,0,0,0 # x,9.8", "row 4: column 6: '0 # x' is not a number"),
    "cut_by_comment": ("1600000000005000000,0,0,0,0,0,9.8 # note", "row 4: column 7: '9.8 # note' is not a number"),
    "text": ("1600000000005000000,0,abc,0,0,0,9.8", "row 4: column 3: 'abc' is not a number"),
    "nan": ("1600000000005000000,0,0,nan,0,0,9.8", "row 4: column 4: expected a finite number, got 'nan'"),
    "columns": ("1600000000005000000,0,0,0,0,9.8", "row 4: expected 7 comma-separated columns"),
    "float_stamp": ("1.6e18,0,0,0,0,0,9.8", "row 4: timestamp '1.6e18' is not an integer"),
    "repeat": ("1600000000002500000,0,0,0,0,0,9.8", "row 4: timestamp 1600000000002500000 repeats the previous row's"),
    "backwards": ("1600000000001000000,0,0,0,0,0,9.8", "row 4: timestamp 1600000000001000000 is before the previous"),
    "too_big": ("99999999999999999999,0,0,0,0,0,9.8", "row 4: timestamp 99999999999999999999 does not fit in 64 bits"),
}


@pytest.mark.parametrize("case", sorted(BAD_ROWS))
def test_bad_row_is_named(tmp_path, case):
    line, message = BAD_ROWS[case]
    t, g, a = samples(5)
    rows = imu_csv(t, g, a).splitlines()
    rows[3] = line
    p = tmp_path / "imu0.csv"
    p.write_text("\n".join(rows) + "\n", encoding="utf-8")
    with pytest.raises(DatasetError) as e:
        read_imu_csv(p)
    assert str(e.value).startswith(f"{p}: {message}")
    assert "\n" not in str(e.value)


def test_indented_blank_line_goes_the_slow_way_and_is_skipped(tmp_path):
    t, g, a = samples(5)
    p = tmp_path / "imu0.csv"
    p.write_text(imu_csv(t, g, a).replace("\n", "\n   \n", 2), encoding="utf-8")
    assert not mod._plain(p)
    np.testing.assert_array_equal(read_imu_csv(p).t_ns, t)


def test_scan_sees_a_comment_split_across_its_blocks(tmp_path, monkeypatch):
    t, g, a = samples(200)
    p = tmp_path / "imu0.csv"
    p.write_text(imu_csv(t, g, a), encoding="utf-8")
    monkeypatch.setattr(mod, "_SCAN_BYTES", 7)  # many block edges, one of them before the header's '#'
    assert mod._plain(p)
    text = p.read_text().splitlines()
    text[150] = text[150] + "#x"
    p.write_text("\n".join(text) + "\n", encoding="utf-8")
    assert not mod._plain(p)
