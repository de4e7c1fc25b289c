#!/usr/bin/python3
"""Benchmarks raillomer-estimator: speed on a recorded bag and memory against run length.

Speed: records --seconds of a scenario (default rich_high_town_a, 30 s at 100 km/h) to a bag,
then runs the whole estimator on it (GNSS fusion and the two-stage submap mapping included,
submaps written) and reports the median and 95th-percentile frontend + backend time per frame
(both LiDARs) and the real-time factor (data seconds / wall seconds, bag reading included).
Targets: median <= 50 ms, real-time factor >= 2.

Memory: runs the simulator's long_20km line in-process for 96 s (2.0 km: 67 s accelerating to
120 km/h, then cruising) and 337 s (10.0 km) and
compares the peak resident memory of the two runs. Target: the 10 km run peaks less than 10 %
above the 2 km one.

Usage: /usr/bin/python3 tests/tools/estimator_benchmark.py [--build build] [--work DIR]
           [--scenario NAME] [--seconds S] [--skip-memory] [--check]
With --check the exit status is 1 when a target is missed.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def run(cmd):
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit("estimator_benchmark: failed: %s\n%s" % (" ".join(cmd), proc.stderr[-2000:]))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--work")
    ap.add_argument("--scenario", default="rich_high_town_a")
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--skip-memory", action="store_true")
    ap.add_argument("--check", action="store_true")
    a = ap.parse_args()
    work = a.work or tempfile.mkdtemp(prefix="raillomer_bench_")
    sim = os.path.join(a.build, "bin", "raillomer-sim")
    est = os.path.join(a.build, "bin", "raillomer-estimator")
    ok = True
    try:
        bag_dir = os.path.join(work, "bag")
        print(f"recording {a.seconds:.0f} s of {a.scenario} ...", flush=True)
        run([sim, "--scenario", a.scenario, "--duration", str(a.seconds), "--out", bag_dir])
        out = os.path.join(work, "speed")
        run([est, "--bag", os.path.join(bag_dir, "run.bag"), "--config", os.path.join(bag_dir, "rig.yaml"),
             "--out", out, "--quiet", "--no-keyframes"])
        with open(os.path.join(out, "summary.json")) as f:
            s = json.load(f)
        median, p95, rtf = s["frame_ms"]["median"], s["frame_ms"]["p95"], s["real_time_factor"]
        print(f"speed: {s['frames']} frames, median {median:.1f} ms/frame (target <= 50), p95 {p95:.1f} ms, "
              f"frontend median {s['frontend_ms']['median']:.1f} ms, backend median {s['backend_ms']['median']:.1f} ms, "
              f"real-time factor {rtf:.2f} (target >= 2); georeferenced {s['georeferenced']}, "
              f"{s['submaps']['count']} submaps ({s['submaps']['ndt_applied']} registered by NDT)", flush=True)
        ok = ok and median <= 50.0 and rtf >= 2.0
        if not a.skip_memory:
            peaks = {}
            for label, seconds in (("2km", 96), ("10km", 337)):
                out = os.path.join(work, "memory_" + label)
                print(f"memory: long_20km for {seconds} s ...", flush=True)
                run([est, "--sim", "long_20km", "--duration", str(seconds), "--out", out, "--quiet", "--no-keyframes"])
                with open(os.path.join(out, "summary.json")) as f:
                    m = json.load(f)
                peaks[label] = m["peak_rss_mb"]
                print(f"memory: {label}: {m['distance_m'] / 1000:.2f} km, peak {m['peak_rss_mb']:.0f} MB", flush=True)
            growth = peaks["10km"] / peaks["2km"] - 1.0
            print(f"memory: 10 km peaks {100 * growth:+.1f} % against 2 km (target < +10 %)")
            ok = ok and growth < 0.10
    finally:
        if not a.work:
            shutil.rmtree(work, ignore_errors=True)
    if a.check and not ok:
        sys.exit(1)


if __name__ == "__main__":
    main()
