#!/usr/bin/env bash
# Builds the submap decoder's libFuzzer target with clang (address and undefined-behaviour
# sanitizers) and runs it for a bounded time from a seed corpus of valid submaps. Exit status 1
# if it finds a crash (the input is kept in the work folder; a work folder the script made
# itself is removed when nothing crashed).
# Usage: bash tests/tools/fuzz_submap_decoder.sh [seconds (default 60)] [work dir]
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds="${1:-60}"
work="${2:-}"
own_work=false
if [ -z "$work" ]; then
  work="$(mktemp -d /tmp/raillomer_fuzz_XXXXXX)"
  own_work=true
fi
mkdir -p "$work/corpus"
clang++ -std=c++17 -O1 -g -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
  -I. -I/usr/include/eigen3 tests/api/submap_decoder_fuzz.cc api/stream.cc api/trajectory.cc \
  api/atomic_file.cc \
  -o "$work/fuzz_submap_decoder"
# Seeds: valid submaps (with and without keyframes, georeferenced and local).
/usr/bin/python3 - "$work/corpus" <<'PY'
import os, struct, sys
out = sys.argv[1]
def submap(points, zone, keyframes):
    h = "# .PCD v0.7 - RailLoMer submap\n# raillomer sequence 7 index 3 keyframes %d\n" % keyframes
    h += "# raillomer stamps 1600000000.000000000 1600000001.500000000\n# raillomer zone %s\n" % zone
    h += "# raillomer origin 432100.0000 3585200.0000 30.0000\n"
    for k in range(keyframes):
        h += "# raillomer keyframe 1600000000.%09d 432100.5 3585200.25 31.0 0 0 0 1\n" % (k * 100000000)
    h += ("VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH %d\n"
          "HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS %d\nDATA binary\n") % (points, points)
    body = b"".join(struct.pack("<4f", 0.1 * i, -0.2 * i, 0.05 * i, float(i % 256)) for i in range(points))
    return h.encode() + body
for i, (n, zone, k) in enumerate([(0, "50N", 0), (3, "50N", 1), (17, "local", 2), (64, "33S", 10)]):
    open(os.path.join(out, "seed%d.pcd" % i), "wb").write(submap(n, zone, k))
PY
echo "fuzz_submap_decoder: fuzzing for ${seconds} s in $work"
cd "$work"
if ./fuzz_submap_decoder -max_total_time="$seconds" -max_len=65536 -timeout=5 -rss_limit_mb=2048 \
    -print_final_stats=1 corpus > fuzz.log 2>&1; then
  tail -n 12 fuzz.log
  echo "fuzz_submap_decoder: no crash in ${seconds} s"
  # A work folder of its own is kept only when it holds a crash.
  if $own_work; then rm -rf "$work"; fi
else
  tail -n 40 fuzz.log
  echo "fuzz_submap_decoder: a crash; the input is in $work" >&2
  exit 1
fi
