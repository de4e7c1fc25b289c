#!/usr/bin/python3
"""Splits an estimator run's error against truth into along-track, lateral, vertical and heading
components over distance, to tell which direction drifts.

Usage:
  /usr/bin/python3 tests/tools/drift_split.py <run dir> [--every M] [--csv FILE]

<run dir> holds trajectory.tum and truth.tum (a --sim run). Both are put in one frame by the
yaw and position of the first estimated pose (no fitting; roll and pitch are absolute, since the
estimator levels on gravity), so the figures are the drift accumulated since the start.
Rows are printed every M metres of travelled distance (default 50).

--biases adds the error of the estimator's IMU bias states (timing.csv) against the simulator's
true biases (imu_bias.csv, written beside truth.tum by --sim runs): dbg_x/y/z, the gyroscope's
in urad/s, and dba_x/y/z, the accelerometer's in mm/s^2, body axes. A yaw gyro bias error of e urad/s turns the heading by e urad
every second wherever the LiDARs do not hold it.
"""
import argparse
import bisect
import math
import os
import sys


def read_tum(path):
    rows = []
    if not os.path.exists(path):
        sys.exit(f"drift_split: {path} does not exist")
    with open(path) as f:
        for line in f:
            if not line.strip() or line.startswith("#"):
                continue
            v = [float(x) for x in line.split()[:8]]
            rows.append((v[0], v[1:4], v[4:8]))
    if not rows:
        sys.exit(f"drift_split: {path} holds no poses")
    return rows


def qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def qconj(q):
    return (-q[0], -q[1], -q[2], q[3])


def qrot(q, v):
    p = qmul(qmul(q, (v[0], v[1], v[2], 0.0)), qconj(q))
    return p[:3]


def yaw_of(q):
    x, y, z, w = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def rpy_of(q):
    x, y, z, w = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    return roll, pitch, yaw_of(q)


def read_csv_columns(path, names):
    """Rows of (stamp_s, [values of `names`]) from a CSV with a header, stamp_s first."""
    rows = []
    if not os.path.exists(path):
        sys.exit(f"drift_split: {path} does not exist" +
                 (" (imu_bias.csv comes with --sim runs of this version)" if path.endswith("imu_bias.csv") else ""))
    with open(path) as f:
        header = f.readline().strip().split(",")
        try:
            idx = [header.index(n) for n in names]
        except ValueError as e:
            sys.exit(f"drift_split: {path}: {e}")
        for line in f:
            v = line.strip().split(",")
            if len(v) < len(header):
                continue
            rows.append((float(v[0]), [float(v[i]) for i in idx]))
    return rows


BIAS_NAMES = ["gyro_bias_x", "gyro_bias_y", "gyro_bias_z", "accel_bias_x", "accel_bias_y", "accel_bias_z"]


def bias_errors(run):
    """A function t -> the six bias errors (estimate minus truth; gyro urad/s, accel mm/s^2)."""
    est = read_csv_columns(f"{run}/timing.csv", BIAS_NAMES)
    truth = read_csv_columns(f"{run}/imu_bias.csv", BIAS_NAMES)
    if not est or not truth:
        sys.exit(f"drift_split: {run}: no bias rows in timing.csv or imu_bias.csv")
    est_t = [t for t, _ in est]
    truth_t = [t for t, _ in truth]

    def nearest(stamps, rows, t):
        k = bisect.bisect_left(stamps, t)
        if k > 0 and (k == len(stamps) or abs(stamps[k - 1] - t) < abs(stamps[k] - t)):
            k -= 1
        return rows[k][1]

    def at(t):
        e, tr = nearest(est_t, est, t), nearest(truth_t, truth, t)
        return [(a - b) * (1e6 if i < 3 else 1e3) for i, (a, b) in enumerate(zip(e, tr))]

    return at


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def parse_args():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("--every", type=float, default=50.0, help="metres between printed rows")
    ap.add_argument("--csv", help="write every matched pose's split to this CSV")
    ap.add_argument("--biases", action="store_true",
                    help="add the IMU bias states' errors against the truth (needs imu_bias.csv)")
    return ap.parse_args()


def truth_lookup(truth):
    """t -> the truth row stamped within 5 ms of t, or None."""
    tstamps = [t for t, _, _ in truth]

    def truth_at(t):
        k = bisect.bisect_left(tstamps, t - 1e-6)
        if k >= len(truth) or abs(tstamps[k] - t) > 5e-3:
            return None
        return truth[k]

    return truth_at


def frame_tie(est, truth_at):
    """(yaw quaternion, translation) taking the estimate's frame onto the truth's. The
    estimator's world is levelled on gravity: only yaw and position are free, so the frames are
    tied by the yaw and position of the first matched pose (roll and pitch stay absolute)."""
    for t, p, q in est:
        tr = truth_at(t)
        if tr is not None:
            dyaw = wrap(yaw_of(tr[2]) - yaw_of(q))
            q_te = (0.0, 0.0, math.sin(0.5 * dyaw), math.cos(0.5 * dyaw))
            return q_te, [a - b for a, b in zip(tr[1], qrot(q_te, p))]
    sys.exit("drift_split: no estimated pose matches a truth stamp")


def splits(est, truth_at):
    """Per matched pose: (t, distance travelled, along, lateral, vertical error in the truth's
    body frame, roll, pitch, yaw error)."""
    q_te, t_te = frame_tie(est, truth_at)
    out = []
    dist = 0.0
    last_tp = None
    for t, p, q in est:
        tr = truth_at(t)
        if tr is None:
            continue
        _, tp, tq = tr
        if last_tp is not None:
            dist += math.dist(tp, last_tp)
        last_tp = tp
        pw = [a + b for a, b in zip(qrot(q_te, p), t_te)]
        qw = qmul(q_te, q)
        err_world = [a - b for a, b in zip(pw, tp)]
        e_body = qrot(qconj(tq), err_world)  # along (x), lateral (y), vertical (z) in the truth body
        r_e, p_e, y_e = rpy_of(qw)
        r_t, p_t, y_t = rpy_of(tq)
        out.append((t, dist, e_body[0], e_body[1], e_body[2], wrap(r_e - r_t), wrap(p_e - p_t), wrap(y_e - y_t)))
    return out


def print_table(out, every, bias_at):
    """A row every `every` metres and the last, with the bias errors when asked for."""
    header = (f"{'t_s':>8} {'dist_m':>8} {'along_m':>8} {'lat_m':>8} {'vert_m':>8} {'roll_deg':>8} "
              f"{'pitch_deg':>9} {'yaw_deg':>8}")
    if bias_at:
        # Bias errors: gyroscope dbg (urad/s), accelerometer dba (mm/s^2), body x y z.
        header += "".join(f"{n:>8}" for n in ("dbg_x", "dbg_y", "dbg_z", "dba_x", "dba_y", "dba_z"))
    print(header)
    next_d = 0.0
    t0 = out[0][0]
    for i, r in enumerate(out):
        if r[1] >= next_d or i == len(out) - 1:
            line = (f"{r[0] - t0:8.1f} {r[1]:8.1f} {r[2]:8.3f} {r[3]:8.3f} {r[4]:8.3f} "
                    f"{math.degrees(r[5]):8.3f} {math.degrees(r[6]):9.3f} {math.degrees(r[7]):8.3f}")
            if bias_at:
                b = bias_at(r[0])
                line += "".join(f"{x:8.1f}" for x in b[:3]) + "".join(f"{x:8.2f}" for x in b[3:])
            print(line)
            next_d += every


def main():
    args = parse_args()
    bias_at = bias_errors(args.run) if args.biases else None
    est = read_tum(f"{args.run}/trajectory.tum")
    out = splits(est, truth_lookup(read_tum(f"{args.run}/truth.tum")))
    print_table(out, args.every, bias_at)
    if args.csv:
        with open(args.csv, "w") as f:
            f.write("t_s,dist_m,along_m,lateral_m,vertical_m,roll_rad,pitch_rad,yaw_rad\n")
            for r in out:
                f.write(",".join(f"{x:.6f}" for x in r) + "\n")


if __name__ == "__main__":
    main()
