#!/usr/bin/env bash
# The main job end to end on the embedded default: install what it needs, build the tools and the
# browser viewer, then run deploy/demo-run.sh: simulate the demo line, stream it to
# raillomer-server, score it against the truth, stream the same line a week later with changes
# and report them.
# Usage: bash deploy/demo.sh [scenario] [out_dir]   (as root on Debian 12)
# Environment: RAILLOMER_PORT (default 8470; 0 lets the OS pick), RAILLOMER_SERVER_DATA (default
# runs/server).
set -euo pipefail
cd "$(dirname "$0")/.."
bash deploy/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j2 --target raillomer-sim raillomer-eval raillomer-estimator raillomer-server
# The browser viewer (web/dist), which the server serves at /.
bash deploy/build-web.sh
RAILLOMER_BIN=build/bin exec bash deploy/demo-run.sh "$@"
