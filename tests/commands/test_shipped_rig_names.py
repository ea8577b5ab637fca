"""Every command that takes a rig accepts a shipped rig's name (`drone-stereo-back`, as the
README shows for simulate), wherever the command runs; a name that is neither a file nor a
shipped rig is one line listing the shipped ones, exit 2. (simulate --scene imu by name:
tests/sim/test_simulate_free_running.py.)"""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from rigcal.cli import app

runner = CliRunner()
SHIPPED = Path(__file__).resolve().parents[2] / "rigs"


def _ok(*args):
    r = runner.invoke(app, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r.output


def test_compare_view_export_and_project_take_a_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no rig files here
    text = _ok("compare", "drone-stereo-back-imu", "drone-stereo-back-imu")
    assert "front_left" in text
    _ok("view", "drone-stereo-back", "--out", tmp_path / "v.html")
    assert (tmp_path / "v.html").is_file()
    _ok("export", "drone-stereo-back", "--format", "json", "--out", tmp_path / "r.json")
    assert (tmp_path / "r.json").is_file()
    _ok("project", "drone-stereo-back", "--position", 100, 300, 10, "--heading", 0, "--point", 103, 310, 12)


def test_an_unknown_name_lists_the_shipped_rigs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = runner.invoke(app, ["view", "no-such-rig", "--out", str(tmp_path / "v.html")])
    assert r.exit_code == 2 and "drone-stereo-back-imu" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1 and not (tmp_path / "v.html").exists()
