"""Regenerate the golden export files under tests/golden/exports/.

Run from the repository root:   make golden   (= python -m tests.golden.regenerate)

Then review `git diff tests/golden/exports`: every changed value is a change in what
users' tools will read. tests/exports/test_export.py checks that the current exports equal
these files as data (tests/support/golden_data.py: structure, keys, strings and comments
exactly, numbers to a relative 1e-12), never as text: the last digit of a float
differs between machines, so a regeneration elsewhere may rewrite digits that the
comparison rightly ignores; commit such a rewrite only with a real change.
"""

from __future__ import annotations

from pathlib import Path

from rigcal.commands import export as export_command
from rigcal.core.io import atomic_dir
from rigcal.core.rig import load_rig

GOLDEN = Path(__file__).resolve().parent
ROOT = GOLDEN.parent.parent
EXPORTS = GOLDEN / "exports"

# The spec's golden rig as declared (clean textbook numbers), and the same rig as a
# calibrated file would hold it (small distortion, slightly turned cameras, statistics).
INPUTS = {
    "drone-stereo-back": ROOT / "rigs" / "drone-stereo-back.yaml",
    "drone-stereo-back-calibrated": GOLDEN / "drone-stereo-back-calibrated.yaml",
}
# Output name of each format inside one rig's folder.
OUTPUTS = {"kalibr": "camchain.yaml", "json": "rig.json", "opencv": "opencv", "ros": "ros"}
# The camera-IMU formats (rigcal.exports.imu_formats), of a calibrated rig with an IMU.
IMU_INPUTS = {"drone-stereo-back-imu-calibrated": GOLDEN / "drone-stereo-back-imu-calibrated.yaml"}
IMU_OUTPUTS = {"kalibr-imu": "kalibr-imu", "euroc": "euroc"}


def write_goldens(dest: Path) -> list[Path]:
    """Write every export of every golden input under dest/<input>/<output>; returns the files."""
    for stem, rig_path, outputs in ([(s, p, OUTPUTS) for s, p in INPUTS.items()]
                                    + [(s, p, IMU_OUTPUTS) for s, p in IMU_INPUTS.items()]):
        rig = load_rig(rig_path)
        for fmt, name in outputs.items():
            # A label without the machine's path keeps messages identical everywhere.
            result = export_command.build(rig, fmt, f"{stem}.yaml")
            export_command.write_export(result, fmt, dest / stem / name)
    return sorted(p for p in dest.rglob("*") if p.is_file())


def main() -> None:
    with atomic_dir(EXPORTS, force=True) as tmp:
        files = write_goldens(tmp)
    for f in files:
        print(EXPORTS / f.relative_to(tmp))


if __name__ == "__main__":
    main()
