#!/usr/bin/env bash
# The main job end to end on the embedded default: simulate the 30 s demo run (two LiDARs, IMU,
# odometer, GNSS) into runs/demo, then score the GNSS receiver's fixes against the ground truth.
# Usage: bash deploy/demo.sh [scenario] [out_dir]   (as root on Debian 12)
set -euo pipefail
cd "$(dirname "$0")/.."
scenario="${1:-demo}"
out="${2:-runs/$scenario}"
bash deploy/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j2 --target raillomer-sim raillomer-eval
./build/bin/raillomer-sim --scenario "$scenario" --out "$out"
./build/bin/raillomer-eval --estimate "$out/gnss.tum" --truth "$out/truth.tum" --align none \
  --json "$out/gnss_eval.json" --plot "$out/gnss_eval.svg"
echo "demo: outputs in $out (run.bag, truth.tum, gnss.tum, rig.yaml, gnss_eval.json, gnss_eval.svg)"
