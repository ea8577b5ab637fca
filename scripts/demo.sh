#!/usr/bin/env bash
# `make demo`: the main job on the embedded example. Args: VENV_BIN OUT_DIR
set -euo pipefail
BIN=${1:-.venv/bin}; OUT=${2:-demo-out}
mkdir -p "$OUT"
echo "== golden projection (cli.md)"
"$BIN/rigcal" project rigs/drone-stereo-back.yaml --position 100 300 10 --axes N -E U --point 103 310 12
echo "== rig view -> $OUT/rig.html"
"$BIN/rigcal" view rigs/drone-stereo-back.yaml --out "$OUT/rig.html"
