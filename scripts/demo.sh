#!/usr/bin/env bash
# `make demo`: the main job on the embedded example rig. Args: VENV_BIN OUT_DIR
#   simulate the golden rig (front stereo pair + a back camera that never shares a view),
#   calibrate it from the images alone, compare with the simulator's truth,
#   then use the calibrated rig downstream (projection, view);
#   part 2: the golden rig with an IMU, moved by hand in front of static boards (imu.md),
#   calibrated end to end (T_body_cam relative to the IMU, clock offsets, biases).
set -euo pipefail
BIN=${1:-.venv/bin}; OUT=${2:-demo-out}
mkdir -p "$OUT"
echo "== 1. simulate rigs/drone-stereo-back.yaml (room scene) -> $OUT/sim"
"$BIN/rigcal" simulate rigs/drone-stereo-back.yaml --out "$OUT/sim" --seed 7 --force
echo
echo "== 2. calibrate $OUT/sim -> $OUT/calibrated.yaml (+ report.html)"
"$BIN/rigcal" calibrate "$OUT/sim" --out "$OUT/calibrated.yaml" --report "$OUT/report.html"
echo
echo "== 3. compare the calibration with the simulator's truth"
"$BIN/rigcal" compare "$OUT/calibrated.yaml" "$OUT/sim/truth.yaml"
echo
echo "== 4. golden projection (cli.md) through the declared rig, then the calibrated one"
"$BIN/rigcal" project rigs/drone-stereo-back.yaml --position 100 300 10 --axes N -E U --point 103 310 12
"$BIN/rigcal" project "$OUT/calibrated.yaml" --position 100 300 10 --axes N -E U --point 103 310 12
echo
echo "== 5. rig view -> $OUT/rig.html; exports -> $OUT/export/"
"$BIN/rigcal" view "$OUT/calibrated.yaml" --out "$OUT/rig.html"
rm -rf "$OUT/export"; mkdir -p "$OUT/export"
"$BIN/rigcal" export "$OUT/calibrated.yaml" --format kalibr --out "$OUT/export/camchain.yaml"
"$BIN/rigcal" export "$OUT/calibrated.yaml" --format opencv --out "$OUT/export/opencv"
echo
echo "== 6. part 2: simulate rigs/drone-stereo-back-imu.yaml moving (--scene imu, 5 s) -> $OUT/imu-sim"
"$BIN/rigcal" simulate rigs/drone-stereo-back-imu.yaml --out "$OUT/imu-sim" --scene imu --duration 5 \
    --camera-rate 10 --seed 7 --force
echo
echo "== 7. calibrate it against the IMU -> $OUT/imu-calibrated.yaml"
"$BIN/rigcal" calibrate "$OUT/imu-sim" --out "$OUT/imu-calibrated.yaml"
echo
echo "== 8. compare with the truth (T_imu_cam, clock offsets, biases); Kalibr and EuRoC exports"
"$BIN/rigcal" compare "$OUT/imu-calibrated.yaml" "$OUT/imu-sim/truth.yaml"
rm -rf "$OUT/export/kalibr-imu" "$OUT/export/euroc"
"$BIN/rigcal" export "$OUT/imu-calibrated.yaml" --format kalibr-imu --out "$OUT/export/kalibr-imu"
"$BIN/rigcal" export "$OUT/imu-calibrated.yaml" --format euroc --out "$OUT/export/euroc"
echo
echo "demo done: open $OUT/report.html and $OUT/rig.html in a browser"
