#!/usr/bin/python3
"""Runs raillomer-estimator with GNSS on simulated scenarios and scores each run in UTM against
the truth with no post-alignment (raillomer-eval --align none): ATE RMSE and MAX, the largest
error inside GNSS outages, the largest step of the trajectory between two poses (what the truth
does not move), and beside them the GNSS bound of the run. It also scores each run's
map (raillomer-eval --scenario --submaps): the spread normal to the corridor's known planes
(every patch by submap in <run>/planes.csv) and the rail-head height difference between
submaps (every segment by submap in <run>/rails.csv).

The GNSS bound is what an estimator with perfect odometry would reach: the truth moved by the
4-DoF transform (yaw and offset) that best fits the receiver's fixes, multipath excluded, scored
like the estimate. With a single-point receiver whose error wanders by a metre over minutes,
this is the floor for any estimator that has no other absolute reference; the estimate can only
come near it.

Usage:
  /usr/bin/python3 tests/tools/gnss_suite.py [--build build] [--out runs/gnss]
      [--scenarios all|extra|NAME[,NAME...]] [--seed N] [--duration S] [--markdown FILE]
      [--check] [--replay DIR [--options FILE] [--exact-fixes]]

With --replay DIR the estimator does not run: each run's GNSS-off odometry (DIR/<run>/, as
estimator_suite.py writes it to runs/estimator/full) is georeferenced again with the run's fixes
by raillomer-gnss-replay, the estimator's own GNSS fusion (--options: an estimator: section to
try, e.g. gnss: settings). The trajectory is the one the estimator would publish, so ATE, MAX, the
outage and the steps are scored as for a full run, in seconds; the map columns stay empty and
RTF and peak memory are the GNSS-off run's. --exact-fixes replaces the fixes by the true antenna
position at the same epochs (gaps and outages kept): what is left is the estimator's own error.

With --check the exit status is 1 when a run misses a target of issue 4 (ATE RMSE 0.25 m,
MAX 1.0 m, MAX 1.5 m inside an outage, planes 3 cm RMS, rail heads within 3 cm) or is not
georeferenced.
"""
import argparse
import bisect
import functools
import json
import math
import os
import shutil
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from estimator_suite import (add_run_arguments, failure, report, run_estimator, run_label,  # noqa: E402
                             select_runs)

ATE_TARGET_M, MAX_TARGET_M, OUTAGE_MAX_TARGET_M = 0.25, 1.0, 1.5
PLANE_TARGET_M, RAIL_TARGET_M = 0.03, 0.03
OUTAGE_GAP_S = 5.0  # no fix for this long: the receiver is out


def read_tum(path):
    poses = []
    with open(path) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            v = line.split()
            poses.append((float(v[0]), (float(v[1]), float(v[2]), float(v[3]))))
    return poses


class Interpolator:
    def __init__(self, poses):
        self.poses = poses
        self.stamps = [t for t, _ in poses]

    def at(self, t):
        """Position at t, or None outside the span."""
        if not self.poses or t < self.stamps[0] or t > self.stamps[-1]:
            return None
        i = min(max(bisect.bisect_left(self.stamps, t), 1), len(self.stamps) - 1)
        (t0, a), (t1, b) = self.poses[i - 1], self.poses[i]
        f = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
        return tuple(a[k] + f * (b[k] - a[k]) for k in range(3))


def fit_four_dof(src, dst):
    """Yaw and offset taking src onto dst (least squares; horizontal rotation only)."""
    n = len(src)
    ms = [sum(p[k] for p in src) / n for k in range(3)]
    md = [sum(p[k] for p in dst) / n for k in range(3)]
    sxx = sxy = syx = syy = 0.0
    for s, d in zip(src, dst):
        ax, ay, bx, by = s[0] - ms[0], s[1] - ms[1], d[0] - md[0], d[1] - md[1]
        sxx += ax * bx
        sxy += ax * by
        syx += ay * bx
        syy += ay * by
    yaw = math.atan2(sxy - syx, sxx + syy)
    c, s_ = math.cos(yaw), math.sin(yaw)
    t = (md[0] - (c * ms[0] - s_ * ms[1]), md[1] - (s_ * ms[0] + c * ms[1]), md[2] - ms[2])
    return yaw, t


def apply(yaw, t, p):
    c, s = math.cos(yaw), math.sin(yaw)
    return (c * p[0] - s * p[1] + t[0], s * p[0] + c * p[1] + t[1], p[2] + t[2])


def gnss_bound(truth, fixes, antenna_up_m):
    """ATE RMSE and MAX (m) of the truth moved by its best 4-DoF fit to the fixes."""
    ti = Interpolator(truth)
    src, dst = [], []
    for t, p in fixes:
        q = ti.at(t)
        if q is not None:
            src.append((q[0], q[1], q[2] + antenna_up_m))
            dst.append(p)
    if len(src) < 3:
        return None
    keep = list(range(len(src)))
    for _ in range(4):  # drop multipath (5-30 m) and refit
        yaw, t = fit_four_dof([src[i] for i in keep], [dst[i] for i in keep])
        r = [math.dist(apply(yaw, t, src[i])[:2], dst[i][:2]) for i in range(len(src))]
        keep = [i for i in range(len(src)) if r[i] < 4.0] or keep
    errors = [math.dist(apply(yaw, t, p), p) for _, p in truth[::10]]
    return math.sqrt(sum(e * e for e in errors) / len(errors)), max(errors)


def outage_max(estimate, truth, fixes):
    """Largest 3D error of the estimate while the receiver had no fix for OUTAGE_GAP_S, or None."""
    stamps = [t for t, _ in fixes]
    gaps = [(a, b) for a, b in zip(stamps, stamps[1:]) if b - a > OUTAGE_GAP_S]
    if stamps and estimate and estimate[-1][0] - stamps[-1] > OUTAGE_GAP_S:
        gaps.append((stamps[-1], estimate[-1][0] + 1.0))
    if not gaps:
        return None
    ti = Interpolator(truth)
    worst = 0.0
    for t, p in estimate:
        if any(a < t < b for a, b in gaps):
            q = ti.at(t)
            if q is not None:
                worst = max(worst, math.dist(p, q))
    return worst


def largest_step(estimate, truth):
    """Largest change between consecutive poses (at most 0.5 s apart) of the estimate that the
    truth does not have (m, 3D): a step in the published trajectory."""
    ti = Interpolator(truth)
    worst = 0.0
    for (t0, a), (t1, b) in zip(estimate, estimate[1:]):
        qa, qb = ti.at(t0), ti.at(t1)
        if t1 - t0 > 0.5 or qa is None or qb is None:
            continue
        worst = max(worst, math.dist([b[k] - a[k] for k in range(3)], [qb[k] - qa[k] for k in range(3)]))
    return worst


def antenna_up(scenario_yaml_text):
    """The simulator's antenna height above the body origin (gnss.antenna_m: [0, 0, h]; default 0.3)."""
    for line in scenario_yaml_text.splitlines():
        if "antenna_m:" in line:
            return float(line.split("[")[1].split("]")[0].split(",")[2])
    return 0.3


@functools.lru_cache(maxsize=None)
def scenario_yaml(build, scenario):
    """A built-in scenario's YAML (raillomer-sim --print-scenario) or a scenario file's."""
    if scenario.endswith(".yaml"):
        with open(scenario) as f:
            return f.read()
    return subprocess.run([os.path.join(build, "bin", "raillomer-sim"), "--scenario", scenario, "--print-scenario"],
                          capture_output=True, text=True).stdout


def write_exact_fixes(source, out, antenna_up_m):
    """out/gnss.tum: the run's fix epochs (gaps and outages kept) at the true antenna position."""
    truth = Interpolator(read_tum(os.path.join(source, "truth.tum")))
    lines = []
    with open(os.path.join(source, "gnss.tum")) as f:
        for line in f:
            if line.startswith("#"):
                lines.append(line)
                continue
            v = line.split()
            q = truth.at(float(v[0])) if v else None
            if q is not None:
                lines.append(f"{v[0]} {q[0]:.6f} {q[1]:.6f} {q[2] + antenna_up_m:.6f} 0 0 0 1\n")
    with open(os.path.join(out, "gnss.tum"), "w") as f:
        f.writelines(lines)


def replay(build, out, scenario, source, options, exact_fixes=False):
    """raillomer-gnss-replay on the GNSS-off run in source: out gets the trajectory the estimator
    would publish, the run's truth and fixes (with exact_fixes, error-free ones at the same
    epochs), and a summary.json with what scoring needs."""
    os.makedirs(out, exist_ok=True)
    shutil.copyfile(os.path.join(source, "truth.tum"), os.path.join(out, "truth.tum"))
    if exact_fixes:
        write_exact_fixes(source, out, antenna_up(scenario_yaml(build, scenario)))
    else:
        shutil.copyfile(os.path.join(source, "gnss.tum"), os.path.join(out, "gnss.tum"))
    counts = os.path.join(out, "replay.json")
    if os.path.exists(counts):
        os.remove(counts)
    cmd = [os.path.join(build, "bin", "raillomer-gnss-replay"), "--odometry", os.path.join(source, "trajectory.tum"),
           "--fixes", os.path.join(out, "gnss.tum"), "--sim", scenario, "--out", os.path.join(out, "trajectory.tum"),
           "--json", counts]
    if options:
        cmd += ["--options", options]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    with open(os.path.join(source, "summary.json")) as f:
        s = json.load(f)
    stats = {"factors": 0, "outliers": 0}
    if proc.returncode == 0:
        with open(counts) as f:
            stats = json.load(f)
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump({"georeferenced": proc.returncode == 0, "gnss": stats, "real_time_factor": s["real_time_factor"],
                   "peak_rss_mb": s["peak_rss_mb"]}, f)
    return proc


def run_one(build, out_root, scenario, seed, duration, source=None, options=None, exact_fixes=False):
    label = run_label(scenario, seed)
    out = os.path.join(out_root, label)
    if source:
        run = os.path.join(source, label)
        missing = [n for n in ("trajectory.tum", "gnss.tum", "truth.tum", "summary.json")
                   if not os.path.isfile(os.path.join(run, n))]
        if missing:
            return {"scenario": label, "wall_s": 0.0,
                    "error": [f"no GNSS-off run to replay in {run} (missing {', '.join(missing)}; make it with "
                              f"estimator_suite.py --scenarios {scenario}"
                              f"{'' if seed is None else f' --seed {seed}'} --out D, then replay D/full)"]}
        proc, wall = replay(build, out, scenario, run, options, exact_fixes), 0.0
    else:
        proc, wall = run_estimator(build, scenario, seed, duration, out, [])
    row = {"scenario": label, "wall_s": wall}
    if proc.returncode != 0 and not (source and proc.returncode == 3):
        row["error"] = failure(proc)
        return row
    with open(os.path.join(out, "summary.json")) as f:
        s = json.load(f)
    row.update(georeferenced=s.get("georeferenced", False), gnss=s.get("gnss", {}), rtf=s["real_time_factor"],
               peak_rss_mb=s["peak_rss_mb"])
    if not row["georeferenced"]:
        row["error"] = ["not georeferenced"]
        return row
    map_args = [] if source else ["--scenario", scenario, "--submaps", os.path.join(out, "submaps"),
                                  "--rail-csv", os.path.join(out, "rails.csv"),
                                  "--plane-csv", os.path.join(out, "planes.csv")]
    ev = subprocess.run([os.path.join(build, "bin", "raillomer-eval"), "--estimate", os.path.join(out, "trajectory.tum"),
                         "--truth", os.path.join(out, "truth.tum"), "--align", "none",
                         "--json", os.path.join(out, "eval.json"), "--plot", os.path.join(out, "eval.svg")] + map_args,
                        capture_output=True, text=True)
    if ev.returncode != 0:
        row["error"] = [ev.stderr.strip()]
        return row
    with open(os.path.join(out, "eval.json")) as f:
        e = json.load(f)
    truth = read_tum(os.path.join(out, "truth.tum"))
    fixes = read_tum(os.path.join(out, "gnss.tum"))
    estimate = read_tum(os.path.join(out, "trajectory.tum"))
    bound = gnss_bound(truth, fixes, antenna_up(scenario_yaml(build, scenario)))
    row.update(distance_m=e["distance_m"], ate_m=e["ate_rmse_m"], max_m=e["ate_max_m"],
               outage_max_m=outage_max(estimate, truth, fixes), step_m=largest_step(estimate, truth),
               bound_ate_m=bound[0] if bound else None, bound_max_m=bound[1] if bound else None,
               plane_rms_m=e["map"]["plane_rms_m"] if "map" in e and e["map"]["plane_patches"] else None,
               rail_p95_m=e["map"]["rail_spread_p95_m"] if "map" in e else None,
               rail_max_m=e["map"]["rail_spread_max_m"] if "map" in e else None)
    return row


def fmt(v, digits=2):
    return "-" if v is None else f"{v:.{digits}f}"


def cm(v):
    """Metres as centimetres, or - where there was nothing to measure."""
    return "-" if v is None else f"{100 * v:.1f}"


def markdown(rows):
    lines = ["| scenario | distance (km) | ATE RMSE (m) | MAX (m) | MAX in outage (m) | largest step (cm) "
             "| GNSS bound RMSE / MAX (m) | map planes RMS (cm) | rail heads p95 / max (cm) | GNSS factors "
             "| multipath rejected | RTF | peak RSS (MB) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['scenario']} | failed: {' '.join(r['error'])} | | | | | | | | | | | |")
            continue
        lines.append(f"| {r['scenario']} | {r['distance_m'] / 1000:.2f} | {r['ate_m']:.2f} | {r['max_m']:.2f} | "
                     f"{fmt(r['outage_max_m'])} | {cm(r['step_m'])} | "
                     f"{fmt(r['bound_ate_m'])} / {fmt(r['bound_max_m'])} | "
                     f"{cm(r['plane_rms_m'])} | {cm(r['rail_p95_m'])} / {cm(r['rail_max_m'])} | "
                     f"{r['gnss'].get('factors', 0)} | {r['gnss'].get('outliers', 0)} | {r['rtf']:.2f} | "
                     f"{r['peak_rss_mb']:.0f} |")
    return "\n".join(lines)


def misses(row):
    if "error" in row:
        return True
    return (row["ate_m"] > ATE_TARGET_M or row["max_m"] > MAX_TARGET_M or
            (row["plane_rms_m"] or 0.0) > PLANE_TARGET_M or (row["rail_max_m"] or 0.0) > RAIL_TARGET_M or
            (row["outage_max_m"] is not None and row["outage_max_m"] > OUTAGE_MAX_TARGET_M))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_arguments(ap, "gnss")
    ap.add_argument("--replay", metavar="DIR", help="georeference DIR/<run>'s GNSS-off odometry again instead of "
                    "running the estimator (estimator_suite.py's runs/estimator/full)")
    ap.add_argument("--options", metavar="FILE", help="with --replay: an estimator: section to try")
    ap.add_argument("--exact-fixes", action="store_true",
                    help="with --replay: error-free fixes at the run's fix epochs (the estimator's own share)")
    a = ap.parse_args()
    if (a.options or a.exact_fixes) and not a.replay:
        ap.error("--options and --exact-fixes go with --replay")
    runs = select_runs(a)
    rows = []
    for scenario, seed in runs:
        row = run_one(a.build, a.out, scenario, seed, a.duration, a.replay, a.options, a.exact_fixes)
        rows.append(row)
        if "error" in row:
            print(f"{row['scenario']:34s} FAILED {' '.join(row['error'])}", flush=True)
        else:
            print(f"{row['scenario']:34s} {row['distance_m'] / 1000:6.2f} km  ATE {row['ate_m']:.2f} m  "
                  f"MAX {row['max_m']:.2f} m  outage MAX {fmt(row['outage_max_m'])} m  "
                  f"step {cm(row['step_m'])} cm  "
                  f"bound {fmt(row['bound_ate_m'])} / {fmt(row['bound_max_m'])} m  "
                  f"planes {cm(row['plane_rms_m'])} cm  rails {cm(row['rail_max_m'])} cm  "
                  f"RTF {row['rtf']:.2f}", flush=True)
    report(markdown(rows), a, any(misses(r) for r in rows))


if __name__ == "__main__":
    main()
