#!/usr/bin/env bash
# Builds the browser viewer (web/ -> web/dist, which raillomer-server serves by default) and,
# with --tests, installs the browser tests' Node packages (tests/web). npm ci installs exactly
# what the lockfiles name; no browser is downloaded (the tests drive Debian's chromium).
# Usage: bash deploy/build-web.sh [--tests]
set -euo pipefail
cd "$(dirname "$0")/.."
export PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1
if ! command -v npm >/dev/null 2>&1; then
  echo "build-web.sh: npm is missing: run deploy/install-deps.sh first (as root)" >&2
  exit 1
fi
# Reinstall only when the lockfile changed since the last install.
install() {
  local dir="$1"
  if [ ! -f "$dir/node_modules/.package-lock.json" ] ||
      [ "$dir/package-lock.json" -nt "$dir/node_modules/.package-lock.json" ]; then
    echo "build-web.sh: npm ci in $dir"
    npm ci --prefix "$dir" --no-audit --no-fund --loglevel=error
  fi
}
install web
npm run --prefix web build --silent
if [ "${1:-}" = "--tests" ]; then
  install tests/web
fi
