#!/bin/bash
# Checks that two builds give the same outputs, byte for byte: for a change meant to leave
# behaviour alone (a function split into steps, a rename). Both builds simulate each scenario
# (the bags and the simulator's truth must match), then estimate the baseline's bag (trajectory,
# keyframes, submaps and a .ply map must match), score the estimates (raillomer-eval's JSON must
# match) and run the demo's ablations. Times (timing.csv, summary.json) are not compared.
#
#   tests/tools/same_outputs.sh OLD_BIN NEW_BIN [WORK_DIR]
#
# OLD_BIN and NEW_BIN are build/bin folders (copy the old one aside before rebuilding:
# `cp -r build/bin /tmp/old_bin`). Exit code 0 when every output matches, 1 otherwise. The work
# takes about 7 GB (the bags); a folder of its own making is removed when every output matches.
set -euo pipefail

if [ $# -lt 2 ]; then
  sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
old=$(realpath "$1")
new=$(realpath "$2")
work=${3:-}
own_work=false
if [ -z "$work" ]; then
  work=$(mktemp -d /tmp/same_outputs.XXXXXX)
  own_work=true
fi
mkdir -p "$work"
for bin in "$old" "$new"; do
  for tool in raillomer-sim raillomer-estimator raillomer-eval; do
    [ -x "$bin/$tool" ] || { echo "same_outputs: $bin/$tool is missing" >&2; exit 2; }
  done
done
scenarios=(demo lidar_blackout imu_loss winter_wheel_slip)
changed=tests/tools/change_scenarios/mixed_changed.yaml
failures=0

# The bin folder of side old or new.
bin_of() { if [ "$1" = new ]; then echo "$new"; else echo "$old"; fi; }

# Compares a file or folder of the two runs; counts a difference.
same() {
  local what=$1 a=$2 b=$3
  if diff -rq "$a" "$b" >/dev/null 2>&1; then
    echo "  same       $what"
  else
    echo "  DIFFERENT  $what ($a vs $b)"
    failures=$((failures + 1))
  fi
}

simulate() {
  local name=$1 scenario=$2
  echo "$name: simulating with both builds"
  for side in old new; do
    "$(bin_of $side)/raillomer-sim" --scenario "$scenario" --out "$work/$side/sim/$name" >/dev/null 2>&1
  done
  for file in run.bag truth.tum gnss.tum changes.json; do
    [ -f "$work/old/sim/$name/$file" ] && same "$name $file" "$work/old/sim/$name/$file" \
      "$work/new/sim/$name/$file"
  done
  return 0
}

# Estimates the baseline's bag with both builds (extra estimator arguments after the name;
# @SIDE@ in them becomes old or new). The trajectory and submaps must exist; keyframes may not.
estimate() {
  local name=$1 out=$2
  shift 2
  local sim=$work/old/sim/$name
  for side in old new; do
    "$(bin_of $side)/raillomer-estimator" --bag "$sim/run.bag" --config "$sim/rig.yaml" --quiet \
      --out "$work/$side/est/$out" "${@//@SIDE@/$side}" >/dev/null 2>&1 || true
  done
  for item in trajectory.tum submaps; do
    same "$out $item" "$work/old/est/$out/$item" "$work/new/est/$out/$item"
  done
  for item in keyframes.tum keyframes; do
    [ -e "$work/old/est/$out/$item" ] && same "$out $item" "$work/old/est/$out/$item" \
      "$work/new/est/$out/$item"
  done
  return 0
}

# Scores the old build's estimate with both builds' raillomer-eval.
score() {
  local name=$1
  local sim=$work/old/sim/$name est=$work/old/est/$name
  for side in old new; do
    mkdir -p "$work/$side/eval"
    "$(bin_of $side)/raillomer-eval" --estimate "$est/trajectory.tum" --truth "$sim/truth.tum" --align none \
      --json "$work/$side/eval/$name.json" --plot "$work/$side/eval/$name.svg" \
      --scenario "$name" --submaps "$est/submaps" >/dev/null 2>&1 || true
  done
  same "$name eval JSON" "$work/old/eval/$name.json" "$work/new/eval/$name.json"
  same "$name eval plot" "$work/old/eval/$name.svg" "$work/new/eval/$name.svg"
}

for s in "${scenarios[@]}"; do
  simulate "$s" "$s"
  echo "$s: estimating and scoring with both builds"
  estimate "$s" "$s"
  score "$s"
done
simulate mixed_changed "$changed"
echo "demo: ablations and the map"
estimate demo demo_lidar_only --lidar-only
estimate demo demo_no_gnss --no-gnss
estimate demo demo_no_odometer --no-odometer
estimate demo demo_map --map "$work/@SIDE@/map.ply" --map-voxel 0.2
same "demo map.ply" "$work/old/map.ply" "$work/new/map.ply"

if [ $failures -eq 0 ]; then
  if $own_work; then
    rm -rf "$work"
    echo "same_outputs: every output matches"
  else
    echo "same_outputs: every output matches (work in $work)"
  fi
  exit 0
fi
echo "same_outputs: $failures output(s) differ (work in $work)"
exit 1
