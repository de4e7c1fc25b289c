#!/usr/bin/env bash
# The main job end to end on the embedded default: simulate the 30 s demo run (two LiDARs, IMU,
# odometer, GNSS) into runs/demo, build the browser viewer, start raillomer-server (runs/server,
# http://127.0.0.1:8470, serving the viewer at /),
# run the estimator on the recorded bag streaming its poses and submaps to the server, score the
# estimate and the GNSS receiver's fixes against the ground truth (the estimate in UTM, as it
# comes, and its map's sharpness), and leave the server up with the run on its API.
# Usage: bash deploy/demo.sh [scenario] [out_dir]   (as root on Debian 12)
# Environment: RAILLOMER_PORT (default 8470), RAILLOMER_SERVER_DATA (default runs/server).
set -euo pipefail
cd "$(dirname "$0")/.."
scenario="${1:-demo}"
out="${2:-runs/$scenario}"
port="${RAILLOMER_PORT:-8470}"
data="${RAILLOMER_SERVER_DATA:-runs/server}"
bash deploy/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j2 --target raillomer-sim raillomer-eval raillomer-estimator raillomer-server
# The browser viewer (web/dist), which the server serves at /.
bash deploy/build-web.sh
./build/bin/raillomer-sim --scenario "$scenario" --out "$out"

# The server: reuse one this script started before, else start it in the background.
mkdir -p "$data"
if [ -f "$data/server.pid" ] && kill -0 "$(cat "$data/server.pid")" 2>/dev/null &&
    curl -sf "http://127.0.0.1:$port/health" >/dev/null; then
  echo "demo: raillomer-server already up on port $port (pid $(cat "$data/server.pid"))"
else
  nohup ./build/bin/raillomer-server --data "$data" --port "$port" >"$data/server.log" 2>&1 &
  echo $! >"$data/server.pid"
  for _ in $(seq 100); do
    curl -sf "http://127.0.0.1:$port/health" >/dev/null && break
    if ! kill -0 "$(cat "$data/server.pid")" 2>/dev/null; then
      cat "$data/server.log" >&2
      echo "demo: raillomer-server did not start (port $port in use? set RAILLOMER_PORT)" >&2
      exit 1
    fi
    sleep 0.1
  done
fi

./build/bin/raillomer-estimator --bag "$out/run.bag" --config "$out/rig.yaml" --out "$out/estimate" \
  --server "http://127.0.0.1:$port" --token-file "$data/ingest.token" \
  --line "Demo line" --vehicle "RLM-1"
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
run=$(curl -sf "http://127.0.0.1:$port/api/v1/runs" | /usr/bin/python3 -c \
  'import json,sys; print(json.load(sys.stdin)["runs"][-1]["id"])')
echo "demo: outputs in $out (run.bag, truth.tum, gnss.tum, rig.yaml, estimate/, estimate_eval.json,"
echo "      estimate_eval.svg, gnss_eval.json, gnss_eval.svg)"
echo "demo: raillomer-server is up (data in $data, log $data/server.log):"
echo "      curl http://127.0.0.1:$port/api/v1/runs/$run"
echo "      curl 'http://127.0.0.1:$port/api/v1/runs/$run/tiles?level=0'"
echo "      curl 'http://127.0.0.1:$port/api/v1/runs/$run/trajectory?format=geojson'"
echo "      stop it with: kill \$(cat $data/server.pid)"
echo "demo: the viewer, with the demo run open: http://127.0.0.1:$port/?run=$run"
