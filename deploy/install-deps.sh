#!/usr/bin/env bash
# Installs every Debian package that building and testing RailLoMer need.
# Idempotent and non-interactive; run as root on Debian 12.
set -euo pipefail

packages=(
  # toolchain
  build-essential cmake pkg-config git clang-format ccache
  # core libraries
  libeigen3-dev libyaml-cpp-dev libcli11-dev libspdlog-dev nlohmann-json3-dev
  libgeographiclib-dev geographiclib-tools
  # estimator: nonlinear least squares; submap registration (ICP, NDT)
  libceres-dev libpcl-dev
  # simulator ray casting
  libembree-dev
  # map store: Draco tiles (and Debian's draco_decoder, an independent check), the SQLite index,
  # OctoMap for change detection's occupancy
  libdraco-dev draco libsqlite3-dev sqlite3 liboctomap-dev zlib1g-dev
  # server: HTTP, WebSocket (Boost.Beast); tests with clients that are not ours; load tests
  libcpp-httplib-dev libboost-dev python3-websockets curl wrk
  # ROS1 bags without ROS
  librosbag-storage-dev libsensor-msgs-dev librcpputils-dev libament-index-cpp-dev
  # tests, benchmarks and the independent bag check
  libgtest-dev libgmock-dev libbenchmark-dev python3 python3-rosbag python3-yaml
  # the slow tier's fuzz target (libFuzzer with clang)
  clang
  # the browser viewer's tests: Debian's chromium, driven by Playwright
  chromium
)
# Node.js and npm build the viewer; a machine that has them (from NodeSource, say, whose nodejs
# carries npm and conflicts with Debian's npm package) keeps its own.
if ! command -v npm >/dev/null 2>&1; then
  packages+=(nodejs npm)
fi

if [ "$(id -u)" -ne 0 ]; then
  echo "install-deps.sh: must run as root (apt-get install)" >&2
  exit 1
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps.sh: all ${#packages[@]} packages already installed"
  exit 0
fi

echo "install-deps.sh: installing ${#missing[@]} packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -q
apt-get install -y -q --no-install-recommends "${missing[@]}"
