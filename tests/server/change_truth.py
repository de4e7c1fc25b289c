"""The simulator's edits of a changed run (changes.json) against the changes a server reports:
simulated runs streamed into a server by raillomer-estimator, the truth placed in the reference
run's map, and recall, precision and position errors as the issue measures them."""
import asyncio
import json
import math
import os
import subprocess
import threading
import time

import harness

# The simulator's edit kinds as the API names them.
KIND = {"object_added": "added", "fallen_tree": "added", "object_removed": "removed",
        "object_moved": "moved", "vegetation_growth": "vegetation"}
# What counts: changes of 0.3 m or more within 15 m of the track.
MIN_SIZE_M, MAX_OFFSET_M = 0.3, 15.0


def stream_run(server, scenario, out, line, seed=None, extra=()):
    """raillomer-estimator --sim `scenario` streamed into `server` as a run of `line`; the
    run's output folder (truth.tum, submaps/)."""
    args = [os.path.join(harness.bin_dir(), "raillomer-estimator"), "--sim", scenario, "--quiet",
            "--no-keyframes", "--out", out, "--server", "http://127.0.0.1:%d" % server.port,
            "--token", server.token, "--line", line] + list(extra)
    if seed is not None:
        args += ["--seed", str(seed)]
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return out


def truth_changes(scenario, out):
    """The edits of a changed scenario (raillomer-sim writes changes.json with the first
    second of its run)."""
    subprocess.run([os.path.join(harness.bin_dir(), "raillomer-sim"), "--scenario", scenario,
                    "--out", out, "--duration", "1"], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.PIPE)
    with open(os.path.join(out, "changes.json")) as f:
        return json.load(f)["changes"]


def read_tum(path):
    """{stamp (10 ms): ((x, y, z), (qx, qy, qz, qw))} of a TUM file."""
    rows = {}
    with open(path) as f:
        for line in f:
            if line.strip() and not line.startswith("#"):
                v = [float(x) for x in line.split()[:8]]
                rows[round(v[0], 2)] = (v[1:4], v[4:8])
    return rows


def submap_keyframes(run_dir):
    """[(stamp (10 ms), (x, y, z), (qx, qy, qz, qw))]: the keyframe poses the run's submaps
    carry in their headers, the poses its map's points were placed by."""
    keyframes = []
    for name in sorted(os.listdir(os.path.join(run_dir, "submaps"))):
        with open(os.path.join(run_dir, "submaps", name), "rb") as f:
            for raw in f:
                if raw.startswith(b"DATA"):
                    break
                if raw.startswith(b"# raillomer keyframe "):
                    v = [float(x) for x in raw.split()[3:11]]
                    keyframes.append((round(v[0], 2), v[1:4], v[4:8]))
    return keyframes


def rotate(q, v):
    """v rotated by the unit quaternion q = (x, y, z, w)."""
    x, y, z, w = q
    t = (2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0]))
    return (v[0] + w * t[0] + y * t[2] - z * t[1], v[1] + w * t[1] + z * t[0] - x * t[2],
            v[2] + w * t[2] + x * t[1] - y * t[0])


def map_position(run_dir, at_utm, radius_m=40.0):
    """Where the run's map puts a true UTM point: each submap keyframe within radius_m of it
    places the point as its scans did (into the keyframe's true body frame, out by its
    estimated pose); the mean of those places. The map sits where the run's GNSS placed it."""
    truth = read_tum(os.path.join(run_dir, "truth.tum"))
    places = []
    for stamp, position, orientation in submap_keyframes(run_dir):
        if stamp not in truth:
            continue
        true_position, true_orientation = truth[stamp]
        if math.hypot(true_position[0] - at_utm[0], true_position[1] - at_utm[1]) > radius_m:
            continue
        inverse = (-true_orientation[0], -true_orientation[1], -true_orientation[2],
                   true_orientation[3])
        body = rotate(inverse, [at_utm[k] - true_position[k] for k in range(3)])
        moved = rotate(orientation, body)
        places.append([position[k] + moved[k] for k in range(3)])
    if not places:
        raise RuntimeError("no keyframe of %s within %.0f m of %s" % (run_dir, radius_m, at_utm))
    return [sum(p[k] for p in places) / len(places) for k in range(3)]


def in_scope(truth):
    return max(truth["extent_m"]) >= MIN_SIZE_M and abs(truth["lateral_m"]) <= MAX_OFFSET_M


def expected_centre(truth, reference_dir):
    """A true change's centre in the reference run's map."""
    return map_position(reference_dir, truth["centre_utm"])


def footprint_distance(truth, centre, at):
    """Horizontal distance from a reported centre to the true change's footprint (its extent
    about `at`, the expected centre); 0 inside."""
    dx = max(0.0, abs(centre[0] - at[0]) - truth["extent_m"][0] / 2)
    dy = max(0.0, abs(centre[1] - at[1]) - truth["extent_m"][1] / 2)
    return math.hypot(dx, dy)


def match(truths, reported, reference_dir, slack_m=1.0):
    """Pairs each in-scope true change with the reported change of its kind whose centre lies
    in its footprint (grown by slack_m), nearest first. Returns (rows, unmatched reports in
    scope): a row per true change with the report (or None) and the centre error."""
    rows, used = [], set()
    for t in truths:
        if not in_scope(t):
            continue
        at = expected_centre(t, reference_dir)
        best, best_d = None, slack_m
        for c in reported:
            p = c["properties"]
            if p["id"] in used or p["kind"] != KIND[t["kind"]]:
                continue
            d = footprint_distance(t, p["utm"], at)
            if d <= best_d:
                best, best_d = c, d
        if best:
            used.add(best["properties"]["id"])
        error = math.hypot(best["properties"]["utm"][0] - at[0],
                           best["properties"]["utm"][1] - at[1]) if best else None
        rows.append({"truth": t, "expected_utm": at, "report": best, "centre_error_m": error})
    extra = [c for c in reported if c["properties"]["id"] not in used
             and abs(c["properties"]["offset_m"]) <= MAX_OFFSET_M
             and max(c["properties"]["size_m"]) >= MIN_SIZE_M]
    return rows, extra


def wait_for_detection(server, run, timeout_s=300.0):
    """The run's changes once its detection is done; (collection, seconds waited)."""
    start = time.time()
    while True:
        status, body = server.json("GET", "/api/v1/runs/%d/changes" % run)
        if status != 200:
            raise RuntimeError("GET changes: %d %s" % (status, body))
        if body["detection"]["status"] in ("done", "failed"):
            return body, time.time() - start
        if time.time() - start > timeout_s:
            raise RuntimeError("detection of run %d not done after %.0f s: %s" %
                               (run, timeout_s, body["detection"]))
        time.sleep(0.2)


class Live:
    """The live hub's pose and change messages of every run, with the time each arrived."""

    def __init__(self, port):
        self.messages = []
        self.ready = threading.Event()
        self.stop = False
        self.thread = threading.Thread(target=lambda: asyncio.run(self._run(port)), daemon=True)
        self.thread.start()
        self.ready.wait(10)

    async def _run(self, port):
        import websockets
        async with websockets.connect("ws://127.0.0.1:%d/live" % port, max_queue=None) as ws:
            await ws.send(json.dumps({"subscribe": "all"}))
            await ws.recv()
            self.ready.set()
            while not self.stop:
                try:
                    text = await asyncio.wait_for(ws.recv(), 0.5)
                except asyncio.TimeoutError:
                    continue
                except websockets.ConnectionClosed:  # the server stopped
                    return
                m = json.loads(text)
                if m.get("type") in ("pose", "change"):
                    self.messages.append((time.time(), m))
