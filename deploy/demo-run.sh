#!/usr/bin/env bash
# The demo's runs, on programs already built (deploy/demo.sh builds them first):
#  1. start raillomer-server (or reuse the one this script started before);
#  2. simulate the scenario (default `demo`: 30 s, two LiDARs, IMU, odometer, GNSS) into out_dir;
#  3. run the estimator on the recorded bag, streaming poses and submaps to the server;
#  4. score the estimate (in UTM, with its map's sharpness) and the GNSS fixes against the truth;
#  5. when the simulator has the scenario a week later (`<scenario>_changed`), simulate and stream
#     that as a second run of the line, wait for the server's change detection and list what
#     changed;
#  6. leave the server up and print the URLs to open.
# Usage: bash deploy/demo-run.sh [scenario] [out_dir]   (default runs/<scenario>; the changed
# run's simulation goes beside it, to <out_dir>_changed)
# Environment: RAILLOMER_PORT (default 8470; 0 lets the OS pick), RAILLOMER_SERVER_DATA (default
# runs/server), RAILLOMER_BIN (default build/bin).
set -euo pipefail
shopt -s inherit_errexit  # a failure inside $(...) stops the script too
cd "$(dirname "$0")/.."
scenario="${1:-demo}"
out="${2:-runs/$scenario}"
port="${RAILLOMER_PORT:-8470}"
data="${RAILLOMER_SERVER_DATA:-runs/server}"
bin="${RAILLOMER_BIN:-build/bin}"
line="$scenario"

# Starts raillomer-server on $data in the background unless the one started before still serves;
# sets $port to the port it serves on. A server of this data folder that does not answer is an
# error: two servers must not share one store.
start_server() {
  mkdir -p "$data"
  local known pid
  known="$(cat "$data/server.port" 2>/dev/null || echo "$port")"
  pid="$(cat "$data/server.pid" 2>/dev/null || true)"
  if [ -n "$pid" ] && [[ "$(cat "/proc/$pid/comm" 2>/dev/null || true)" == raillomer-serv* ]]; then
    if curl -sf "http://127.0.0.1:$known/health" >/dev/null; then
      port="$known"
      echo "demo: raillomer-server already up on port $port (pid $pid)"
      return
    fi
    echo "demo: a raillomer-server (pid $pid) holds $data but does not answer on port $known;" \
      "stop it (kill $pid) or set RAILLOMER_SERVER_DATA to another folder" >&2
    exit 1
  fi
  local ws_flag=()
  [ "$port" = 0 ] && ws_flag=(--ws-port 0)
  : >"$data/server.log"
  nohup "$bin/raillomer-server" --data "$data" --port "$port" "${ws_flag[@]}" >"$data/server.log" 2>&1 &
  echo $! >"$data/server.pid"
  wait_for_server
}

# Waits (20 s at most) for the server just started to log the port it serves on and answer there.
wait_for_server() {
  for _ in $(seq 200); do
    local served
    served="$(sed -n 's|.*serving http://127\.0\.0\.1:\([0-9]*\)/.*|\1|p' "$data/server.log" | head -n 1)"
    if [ -n "$served" ] && curl -sf "http://127.0.0.1:$served/health" >/dev/null; then
      port="$served"
      echo "$port" >"$data/server.port"
      return
    fi
    if ! kill -0 "$(cat "$data/server.pid")" 2>/dev/null; then
      cat "$data/server.log" >&2
      local hint=""
      [ "$port" != 0 ] && hint=" (port $port in use? set RAILLOMER_PORT)"
      echo "demo: raillomer-server did not start$hint" >&2
      exit 1
    fi
    sleep 0.1
  done
  echo "demo: raillomer-server did not answer within 20 s (log: $data/server.log)" >&2
  exit 1
}

# Runs the estimator on $1/run.bag, streaming it to the server as a run of $line (its output also
# in $1/estimator.log); prints the run's id, as the estimator reports it.
stream_run() {
  "$bin/raillomer-estimator" --bag "$1/run.bag" --config "$1/rig.yaml" --out "$1/estimate" \
    --server "http://127.0.0.1:$port" --token-file "$data/ingest.token" \
    --line "$line" --vehicle "RLM-1" 2>&1 | tee "$1/estimator.log" >&2
  local id
  id="$(sed -n 's/^  server: run \([0-9]*\),.*/\1/p' "$1/estimator.log" | tail -n 1)"
  if [ -z "$id" ]; then
    echo "demo: the estimator names no server run (log: $1/estimator.log)" >&2
    exit 1
  fi
  echo "$id"
}

# Scores the estimate of $1 and the receiver's fixes against the simulator's truth.
evaluate() {
  # A georeferenced estimate (GNSS aligned: the trajectory starts with "# utm_zone") is scored in
  # UTM as it is; one left in the local odometry frame is first aligned in SE(3).
  local align=se3
  if head -n 1 "$1/estimate/trajectory.tum" | grep -q '^# utm_zone'; then align=none; fi
  # The map is scored as well: its sharpness against the simulated corridor's planes and rails.
  "$bin/raillomer-eval" --estimate "$1/estimate/trajectory.tum" --truth "$1/truth.tum" \
    --align "$align" --json "$1/estimate_eval.json" --plot "$1/estimate_eval.svg" \
    --scenario "$scenario" --submaps "$1/estimate/submaps"
  "$bin/raillomer-eval" --estimate "$1/gnss.tum" --truth "$1/truth.tum" --align none \
    --json "$1/gnss_eval.json" --plot "$1/gnss_eval.svg"
}

# The changes of a run (the URL $1) as the server has them; a clear error if it does not answer.
changes_json() {
  curl -sf "$1" || {
    echo "demo: no answer from $1 (log: $data/server.log)" >&2
    exit 1
  }
}

# Waits until the server's detection of run $1 is done (3 min at most), showing its progress,
# then lists the changes it found.
report_changes() {
  local url="http://127.0.0.1:$port/api/v1/runs/$1/changes" status=""
  for _ in $(seq 180); do
    status="$(changes_json "$url" | /usr/bin/python3 -c 'import json,sys
d = json.load(sys.stdin)["detection"]
reason = " (%s)" % d["reason"] if d.get("reason") else ""
print("%s %.2f km compared%s" % (d["status"], d.get("km_compared") or 0, reason))')"
    echo "demo: change detection of run $1: $status"
    # Done, failed, or a reason why it will not run.
    case "$status" in done* | failed* | *"("*) break ;; esac
    sleep 1
  done
  changes_json "$url" | /usr/bin/python3 -c 'import json,sys
c = json.load(sys.stdin)
d = c["detection"]
if d["status"] != "done":
    sys.exit("demo: change detection did not finish: %s %s" % (
        d["status"], d.get("error") or d.get("reason") or "(no reason given)"))
print("demo: %d change(s) in run %s against run %s (%.2f km compared, registration RMS %.3f m):" % (
    len(c["features"]), sys.argv[1], d["reference_run"], d["km_compared"], d["registration_rms_m"] or 0))
for f in c["features"]:
    p = f["properties"]
    if p["intrudes_envelope"]:
        envelope = "INTRUDES the structure gauge by %.2f m" % -p["margin_m"]
    elif p["margin_m"] < 0:  # a removed object no longer intrudes
        envelope = "gone: it stood %.2f m inside the structure gauge" % -p["margin_m"]
    else:
        envelope = "%.2f m clear of the structure gauge" % p["margin_m"]
    if p.get("earlier_change"):
        envelope += "; found before, first in run %d (%s)" % (p["first_seen_run"], p["status"])
    side = lambda o: "%.1f m %s" % (abs(o), "left" if o >= 0 else "right")
    if p["side"] == "across":
        place = "across the track (%s to %s)" % tuple(side(o) for o in p["offset_range_m"])
    else:
        place = "%s of the track" % side(p["offset_m"])
    print("  km %.3f  %-10s %-45s %.1f x %.1f x %.1f m  %s" % (
        p["chainage_m"] / 1000, p["kind"], place, *p["size_m"], envelope))' "$1"
}

start_server
"$bin/raillomer-sim" --scenario "$scenario" --out "$out"
run="$(stream_run "$out")"
evaluate "$out"
echo "demo: outputs in $out (run.bag, truth.tum, gnss.tum, rig.yaml, estimate/, estimate_eval.json,"
echo "      estimate_eval.svg, gnss_eval.json, gnss_eval.svg)"

view="?run=$run"
scenarios="$("$bin/raillomer-sim" --list)"
if grep -q "^${scenario}_changed " <<<"$scenarios"; then
  echo "demo: the same line a week later (${scenario}_changed), streamed as a second run"
  "$bin/raillomer-sim" --scenario "${scenario}_changed" --out "${out}_changed"
  changed="$(stream_run "${out}_changed")"
  report_changes "$changed"
  # The viewer compares the changed run with its reference, in whose map the changes lie.
  reference="$(changes_json "http://127.0.0.1:$port/api/v1/runs/$changed/changes" |
    /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)["detection"]["reference_run"])')"
  view="?run=$changed&compare=$reference&color=change"
  echo "demo: the change report: http://127.0.0.1:$port/api/v1/runs/$changed/changes/report"
fi

echo "demo: raillomer-server is up (data in $data, log $data/server.log):"
echo "      curl http://127.0.0.1:$port/api/v1/runs/$run"
echo "      curl 'http://127.0.0.1:$port/api/v1/runs/$run/tiles?level=0'"
echo "      curl 'http://127.0.0.1:$port/api/v1/runs/$run/trajectory?format=geojson'"
echo "      stop it with: kill \$(cat $data/server.pid)"
echo "demo: the viewer: http://127.0.0.1:$port/$view"
