#!/usr/bin/env bash
# The main job end to end on the embedded default: simulate the 30 s demo run (two LiDARs, IMU,
# odometer, GNSS) into runs/demo, run the estimator on the recorded bag, then score the estimate
# and the GNSS receiver's fixes against the ground truth (the estimate in UTM, as it comes, and
# its map's sharpness).
# Usage: bash deploy/demo.sh [scenario] [out_dir]   (as root on Debian 12)
set -euo pipefail
cd "$(dirname "$0")/.."
scenario="${1:-demo}"
out="${2:-runs/$scenario}"
bash deploy/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j2 --target raillomer-sim raillomer-eval raillomer-estimator
./build/bin/raillomer-sim --scenario "$scenario" --out "$out"
./build/bin/raillomer-estimator --bag "$out/run.bag" --config "$out/rig.yaml" --out "$out/estimate"
# A georeferenced estimate (GNSS aligned: the trajectory starts with "# utm_zone") is scored in
# UTM as it is; one left in the local odometry frame is first aligned in SE(3).
align=se3
if head -n 1 "$out/estimate/trajectory.tum" | grep -q '^# utm_zone'; then align=none; fi
# The map is scored as well: its sharpness against the simulated corridor's planes and rails.
./build/bin/raillomer-eval --estimate "$out/estimate/trajectory.tum" --truth "$out/truth.tum" \
  --align "$align" --json "$out/estimate_eval.json" --plot "$out/estimate_eval.svg" \
  --scenario "$scenario" --submaps "$out/estimate/submaps"
./build/bin/raillomer-eval --estimate "$out/gnss.tum" --truth "$out/truth.tum" --align none \
  --json "$out/gnss_eval.json" --plot "$out/gnss_eval.svg"
echo "demo: outputs in $out (run.bag, truth.tum, gnss.tum, rig.yaml, estimate/, estimate_eval.json,"
echo "      estimate_eval.svg, gnss_eval.json, gnss_eval.svg)"
