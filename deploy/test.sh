#!/usr/bin/env bash
# Installs the dependencies, builds everything and runs the default test tier (no slow tests).
# Usage: bash deploy/test.sh   (as root on Debian 12; BUILD_DIR overrides ./build)
set -euo pipefail
cd "$(dirname "$0")/.."
bash deploy/install-deps.sh
build="${BUILD_DIR:-build}"
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release
cmake --build "$build" -j2
bash deploy/build-web.sh --tests
cd "$build"
ctest -LE slow -j2 --output-on-failure
