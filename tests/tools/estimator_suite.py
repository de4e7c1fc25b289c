#!/usr/bin/python3
"""Runs raillomer-estimator (GNSS off) on simulated scenarios and scores each run with
raillomer-eval: end-point drift, ATE, per-frame time, real-time factor and peak memory.

Usage:
  /usr/bin/python3 tests/tools/estimator_suite.py [--build build] [--out runs/suite]
      [--scenarios all|extra|NAME[,NAME...]] [--ablations full,no-odometer,lidar-inertial,lidar-only]
      [--seed N] [--duration S] [--markdown FILE] [--check]

"all" is every built-in scenario except the changed run plus the extra scenarios under
tests/estimator/scenarios (other seeds, speeds and feature densities). With --check the exit
status is 1 when a run misses its drift target (0.2 % on feature-rich, 0.5 % elsewhere).
"""
import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
EXTRA_DIR = os.path.join(ROOT, "tests", "estimator", "scenarios")
ABLATION_FLAGS = {
    "full": [],
    "no-odometer": ["--no-odometer"],
    "no-rail-plane": ["--no-rail-plane"],
    "no-height-descriptor": ["--no-height-descriptor"],
    "no-favour-factors": ["--no-favour-factors"],
    "lidar-inertial": ["--lidar-inertial"],
    "lidar-only": ["--lidar-only"],
}
# Extra runs of built-in scenarios with another noise seed.
EXTRA_SEEDS = [("rich_high_town_a", 7), ("poor_high_catenary_b", 9)]


def builtin_scenarios(build):
    out = subprocess.run([os.path.join(build, "bin", "raillomer-sim"), "--list"],
                         check=True, capture_output=True, text=True).stdout
    names = [line.split()[0] for line in out.splitlines() if line.strip()]
    return [n for n in names if not n.endswith("_changed")]


def extra_scenarios():
    runs = [(os.path.join(EXTRA_DIR, f), None) for f in sorted(os.listdir(EXTRA_DIR)) if f.endswith(".yaml")]
    return runs + EXTRA_SEEDS


def target_pct(name):
    return 0.2 if "rich" in os.path.basename(name) else 0.5


def run_label(scenario, seed):
    return os.path.splitext(os.path.basename(scenario))[0] + (f"@seed{seed}" if seed is not None else "")


def run_estimator(build, scenario, seed, duration, out, flags):
    """Runs raillomer-estimator --sim on a scenario (a shorter one whole when --duration exceeds
    it). Returns the finished process and the wall time."""
    cmd = [os.path.join(build, "bin", "raillomer-estimator"), "--sim", scenario, "--out", out,
           "--quiet", "--no-keyframes"] + flags
    if seed is not None:
        cmd += ["--seed", str(seed)]
    if duration:
        cmd += ["--duration", str(duration)]
    t0 = time.time()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0 and duration and "exceeds the scenario's motion profile" in proc.stderr:
        cmd = cmd[:cmd.index("--duration")] + cmd[cmd.index("--duration") + 2:]
        proc = subprocess.run(cmd, capture_output=True, text=True)
    return proc, time.time() - t0


def failure(proc):
    return proc.stderr.strip().splitlines()[-2:] if proc.stderr else ["exit %d" % proc.returncode]


def report(table, a, missed):
    """Prints the Markdown table, writes it to --markdown, and with --check exits 1 if a target
    was missed."""
    print(table)
    if a.markdown:
        with open(a.markdown, "w") as f:
            f.write(table + "\n")
    if a.check:
        sys.exit(1 if missed else 0)


def add_run_arguments(ap, out_default):
    """The options both suites share: where the tools are, where runs go, which runs."""
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", default=os.path.join(ROOT, "runs", out_default))
    ap.add_argument("--scenarios", default="all")
    ap.add_argument("--seed", type=int)
    ap.add_argument("--duration", type=float)
    ap.add_argument("--markdown")
    ap.add_argument("--check", action="store_true")


def select_runs(a):
    """(scenario, seed) pairs for --scenarios all | extra | NAME[,NAME...]."""
    if a.scenarios == "all":
        return [(n, None) for n in builtin_scenarios(a.build)] + extra_scenarios()
    if a.scenarios == "extra":
        return extra_scenarios()
    return [(n, a.seed) for n in a.scenarios.split(",")]


def run_one(build, out_root, scenario, seed, ablation, duration):
    label = run_label(scenario, seed)
    out = os.path.join(out_root, ablation, label)
    proc, wall = run_estimator(build, scenario, seed, duration, out, ["--no-gnss", "--no-submaps"] + ABLATION_FLAGS[ablation])
    row = {"scenario": label, "ablation": ablation, "target_pct": target_pct(label), "wall_s": wall}
    if proc.returncode != 0:
        row["error"] = failure(proc)
        return row
    ev = subprocess.run([os.path.join(build, "bin", "raillomer-eval"), "--estimate", os.path.join(out, "trajectory.tum"),
                         "--truth", os.path.join(out, "truth.tum"), "--align", "se3",
                         "--json", os.path.join(out, "eval.json"), "--plot", os.path.join(out, "eval.svg")],
                        capture_output=True, text=True)
    if ev.returncode != 0:
        row["error"] = [ev.stderr.strip()]
        return row
    with open(os.path.join(out, "eval.json")) as f:
        e = json.load(f)
    with open(os.path.join(out, "summary.json")) as f:
        s = json.load(f)
    row.update(distance_m=e["distance_m"], drift_pct=e["end_drift_pct"], ate_m=e["ate_rmse_m"],
               rpe_pct=e.get("rpe_trans_mean_pct"), median_ms=s["frame_ms"]["median"], p95_ms=s["frame_ms"]["p95"],
               rtf=s["real_time_factor"], warnings=s["warnings"], peak_rss_mb=s["peak_rss_mb"])
    return row


def markdown(rows):
    lines = ["| scenario | ablation | distance (km) | end drift (%) | target (%) | ATE RMSE (m) | median ms/frame | RTF | peak RSS (MB) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['scenario']} | {r['ablation']} | failed: {' '.join(r['error'])} | | | | | | |")
            continue
        ok = "" if r["drift_pct"] <= r["target_pct"] else " (miss)"
        lines.append(f"| {r['scenario']} | {r['ablation']} | {r['distance_m'] / 1000:.2f} | {r['drift_pct']:.3f}{ok} | "
                     f"{r['target_pct']} | {r['ate_m']:.2f} | {r['median_ms']:.1f} | {r['rtf']:.2f} | {r['peak_rss_mb']:.0f} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_arguments(ap, "suite")
    ap.add_argument("--ablations", default="full")
    a = ap.parse_args()
    runs = select_runs(a)
    rows = []
    for ablation in a.ablations.split(","):
        if ablation not in ABLATION_FLAGS:
            sys.exit(f"estimator_suite: unknown ablation '{ablation}' (one of {', '.join(ABLATION_FLAGS)})")
        for scenario, seed in runs:
            row = run_one(a.build, a.out, scenario, seed, ablation, a.duration)
            rows.append(row)
            if "error" in row:
                print(f"{row['scenario']:34s} {ablation:16s} FAILED {' '.join(row['error'])}", flush=True)
            else:
                print(f"{row['scenario']:34s} {ablation:16s} {row['distance_m'] / 1000:6.2f} km  drift {row['drift_pct']:.3f} % "
                      f"(target {row['target_pct']})  ATE {row['ate_m']:.2f} m  {row['median_ms']:.1f} ms/frame  "
                      f"RTF {row['rtf']:.2f}  {row['peak_rss_mb']:.0f} MB", flush=True)
    report(markdown(rows), a, any(r["ablation"] == "full" and ("error" in r or r["drift_pct"] > r["target_pct"])
                                  for r in rows))


if __name__ == "__main__":
    main()
