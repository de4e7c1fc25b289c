#!/usr/bin/python3
"""Crash trial: raillomer-server killed (kill -9) again and again while a client streams a
run into it, on loopback.

Each trial starts a fresh store. A client sends 16 submaps of a straight corridor with a batch
of 10 poses before each (paced over about 1.5 s), and resends every message until the server acknowledges it (as the
estimator's outbox does; a duplicate counts as acknowledged). Meanwhile the server is killed
--kills-per-trial times at random moments and started again on the same ports 0.2 s later.
After the client is done the run must hold every submap and pose exactly once, its tiles the
corridor's points exactly (submaps overlap by half: a union of 0.1 m voxels), and the index
must pass SQLite's integrity check. Defaults: 24 trials, 53 kills.

Usage: /usr/bin/python3 tests/tools/server_crash_trial.py [--build build] [--trials 24]
           [--kills 53] [--seed 1] [--check]
With --check the exit status is 1 when a trial lost or duplicated anything."""
import argparse
import http.client
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                "server"))
import harness  # noqa: E402

SUBMAPS = 16
POSES_PER_BATCH = 10


class Client(threading.Thread):
    """Streams the run; every message is resent until a 2xx answers it."""

    def __init__(self, port_of, token, run):
        super().__init__()
        self.port_of, self.token, self.run_id = port_of, token, run
        self.rejected = []
        self.attempts = 0

    def send(self, path, body, content_type):
        while True:
            self.attempts += 1
            try:
                conn = http.client.HTTPConnection("127.0.0.1", self.port_of(), timeout=10)
                conn.request("POST", path, body=body,
                             headers={"Authorization": "Bearer " + self.token,
                                      "Content-Type": content_type})
                r = conn.getresponse()
                data = r.read()
                conn.close()
            except (OSError, http.client.HTTPException):  # the server is down: again shortly
                time.sleep(0.05)
                continue
            if 200 <= r.status < 300:
                return
            if r.status >= 500:
                time.sleep(0.05)
                continue
            self.rejected.append((path, r.status, data[:200]))
            return

    def run(self):
        base = "/api/v1/runs/%d" % self.run_id
        for i in range(SUBMAPS):
            poses = [harness.pose(i * POSES_PER_BATCH + k) for k in range(POSES_PER_BATCH)]
            self.send(base + "/poses", json.dumps({"poses": poses}), "application/json")
            time.sleep(0.03)  # paced, so the kills fall while it streams
            self.send(base + "/submaps", harness.submap_pcd(i), "application/octet-stream")
            time.sleep(0.03)


def trial(k, kills, rng, work):
    data = os.path.join(work, "trial%02d" % k, "data")
    os.makedirs(os.path.dirname(data))
    server = harness.Server(data=data)
    ports = (server.port, server.ws_port)
    run = server.create_run(line="Trial %d" % k)
    client = Client(lambda: ports[0], server.token, run)
    client.start()
    for _ in range(kills):
        time.sleep(rng.uniform(0.05, 0.5))
        server.stop(signal.SIGKILL)
        time.sleep(0.2)
        server = harness.Server(data=data, port=ports[0], ws_port=ports[1])
    client.join(timeout=300)
    problems = []
    if client.is_alive():
        problems.append("the client did not finish")
    if client.rejected:
        problems.append("rejected: %s" % client.rejected)
    info = server.json("GET", "/api/v1/runs/%d" % run)[1]
    if (info["submaps"], info["poses"], info["submaps_lost"]) != (SUBMAPS,
                                                                 SUBMAPS * POSES_PER_BATCH, 0):
        problems.append("run holds %d submaps (%d lost), %d poses" %
                        (info["submaps"], info["submaps_lost"], info["poses"]))
    server.write("POST", "/api/v1/runs/%d/finish" % run, {})
    _, tiles = server.json("GET", "/api/v1/runs/%d/tiles?level=0" % run)
    points = sum(t["points"] for t in tiles["tiles"])
    expected = 400 * 80 // 2 * (SUBMAPS + 1)  # submap i covers 20 i .. 20 i + 40 m
    if points != expected:
        problems.append("tiles hold %d points, not %d" % (points, expected))
    server.stop()
    check = subprocess.run(["sqlite3", os.path.join(data, "index.sqlite"), "PRAGMA integrity_check;"],
                           capture_output=True, text=True)
    if check.stdout.strip() != "ok":
        problems.append("integrity: " + check.stdout + check.stderr)
    return problems, client.attempts


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(harness.ROOT, "build"))
    ap.add_argument("--trials", type=int, default=24)
    ap.add_argument("--kills", type=int, default=53)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--check", action="store_true")
    a = ap.parse_args()
    os.environ.setdefault("RAILLOMER_BIN", os.path.join(a.build, "bin"))
    rng = random.Random(a.seed)
    work = tempfile.mkdtemp(prefix="raillomer_crash_trial_")
    # The kills spread over the trials as evenly as they go.
    per_trial = [a.kills // a.trials + (1 if k < a.kills % a.trials else 0) for k in range(a.trials)]
    failed = 0
    try:
        for k in range(a.trials):
            problems, attempts = trial(k, per_trial[k], rng, work)
            failed += bool(problems)
            print("trial %2d: %d kills, %d requests: %s" %
                  (k, per_trial[k], attempts, "; ".join(problems) if problems else "ok"), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print("server_crash_trial: %d trials, %d kills: %d lost or duplicated anything" %
          (a.trials, a.kills, failed))
    if a.check and failed:
        sys.exit(1)


if __name__ == "__main__":
    main()
