#!/usr/bin/python3
"""raillomer-server against hostile and careless clients, each test on a fresh server on
loopback with plain sockets and http.client: bodies that would inflate or never end, slow
clients, header floods, range amplification, the web root's edges, a pose in another UTM zone,
numbers at their limits, lost submap payloads after a crash, and the store's file modes.

Memory is the server's peak resident size (VmHWM) before and after the attack. Run one test
with: python3 tests/server/hardening_test.py Hardening.test_gzip_body_is_refused_unread"""
import http.client
import json
import os
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time
import unittest
import zlib

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import (Server, bin_dir, body_of, pose, raw_exchange, status_of,  # noqa: E402
                     submap_pcd)

#: No request without a token may grow the server's peak memory by more than this (MB).
UNAUTHENTICATED_GROWTH_MB = 64.0


def gzip_bomb(inflated_mb):
    """A gzip body of `inflated_mb` MB of zeros (about 1 KB per MB)."""
    z = zlib.compressobj(9, zlib.DEFLATED, 31)
    zeros = bytes(1 << 20)
    return b"".join(z.compress(zeros) for _ in range(inflated_mb)) + z.flush()


def request_head(method, path, headers):
    return (("%s %s HTTP/1.1\r\nHost: 127.0.0.1\r\n" % (method, path)) +
            "".join("%s: %s\r\n" % kv for kv in headers) + "\r\n").encode()


def wait_for_tiles(server, run, level=0, timeout=20.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        status, body = server.json("GET", "/api/v1/runs/%d/tiles?level=%d" % (run, level))
        if status == 200 and body["tiles"]:
            return body["tiles"]
        time.sleep(0.1)
    raise AssertionError("no tiles were written")


class Hardening(unittest.TestCase):
    config = None

    def setUp(self):
        self.server = Server(config=self.config)
        # A first request, so the baseline holds what serving at all costs.
        self.server.request("GET", "/health")
        self.baseline_mb = self.server.status("VmHWM")

    def tearDown(self):
        self.assertTrue(self.server.alive(), "the server died:\n" + self.server.log_text())
        self.server.cleanup()

    def assertPeakGrowthBelow(self, limit_mb, baseline_mb=None):
        growth = self.server.status("VmHWM") - (baseline_mb or self.baseline_mb)
        sys.stderr.write("%s: peak memory +%.1f MB\n" % (self.id().split(".")[-1], growth))
        self.assertLess(growth, limit_mb, "peak memory grew by %.0f MB" % growth)

    # 1. A compressed body is never inflated: refused (401 without a token, 415 with one)
    # before it is read.
    def test_gzip_body_is_refused_unread(self):
        bomb = gzip_bomb(1024)
        for token, expected in ((None, 401), (self.server.token, 415)):
            headers = [("Content-Type", "application/json"), ("Content-Encoding", "gzip"),
                       ("Content-Length", str(len(bomb)))]
            if token:
                headers.append(("Authorization", "Bearer " + token))
            answer, _ = raw_exchange(self.server.port,
                                     request_head("POST", "/api/v1/runs", headers) + bomb)
            self.assertEqual(status_of(answer), expected, answer[:300])
        self.assertPeakGrowthBelow(UNAUTHENTICATED_GROWTH_MB)
        self.assertEqual(self.server.json("GET", "/api/v1/runs")[1]["runs"], [])

    # 2. A chunked body is held to the route's limit as it arrives, and a write without a
    # token is refused before its body is read.
    def test_chunked_body_is_held_to_the_limit(self):
        run = self.server.create_run()

        def chunked(token, total_mb):
            headers = [("Content-Type", "application/octet-stream"),
                       ("Transfer-Encoding", "chunked")]
            if token:
                headers.append(("Authorization", "Bearer " + token))
            yield request_head("POST", "/api/v1/runs/%d/submaps" % run, headers)
            piece = b"100000\r\n" + b"x" * 0x100000 + b"\r\n"
            for _ in range(total_mb):
                yield piece
            yield b"0\r\n\r\n"

        answer, sent = raw_exchange(self.server.port, chunked(None, 512))
        self.assertEqual(status_of(answer), 401, answer[:300])
        self.assertLess(sent, 64 << 20, "the server read %d MB before refusing" % (sent >> 20))
        answer, sent = raw_exchange(self.server.port, chunked(self.server.token, 512))
        self.assertEqual(status_of(answer), 413, answer[:300])
        self.assertIn(b"max_body_bytes", body_of(answer))
        self.assertLess(sent, 160 << 20)  # the 64 MiB limit, and what the socket buffers hold
        self.assertPeakGrowthBelow(UNAUTHENTICATED_GROWTH_MB + 64 + 16)
        self.assertEqual(self.server.json("GET", "/api/v1/runs/%d" % run)[1]["submaps"], 0)

    # 3. 300 clients that send a header line every 2 s hold no thread: /health answers within
    # 1 s throughout, and the header deadline closes them.
    def test_slow_clients_do_not_hold_up_others(self):
        slow = []
        for _ in range(300):
            s = socket.create_connection(("127.0.0.1", self.server.port))
            s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            slow.append(s)
        stop = threading.Event()

        def trickle():
            n = 0
            while not stop.wait(2.0):
                n += 1
                for s in slow:
                    try:
                        s.sendall(b"X-Slow-%d: 1\r\n" % n)
                    except OSError:
                        pass

        sender = threading.Thread(target=trickle)
        sender.start()
        worst = 0.0
        try:
            start = time.time()
            while time.time() - start < 12.0:
                t = time.time()
                status, _, _ = self.server.request("GET", "/health", timeout=5)
                worst = max(worst, time.time() - t)
                self.assertEqual(status, 200)
                time.sleep(0.2)
        finally:
            stop.set()
            sender.join()
        self.assertLess(worst, 1.0, "/health took %.2f s" % worst)
        # The header deadline (10 s) closed every slow client.
        closed = 0
        for s in slow:
            s.settimeout(0.5)
            try:
                closed += s.recv(1) == b""
            except ConnectionResetError:
                closed += 1
            except socket.timeout:
                pass
            s.close()
        self.assertEqual(closed, 300)
        self.assertGreaterEqual(self.server.metric("raillomer_http_header_timeouts_total"), 300)

    # 3. The live hub bounds its connections too, upgraded or not.
    def test_the_live_hub_bounds_its_connections(self):
        self.server.cleanup()
        self.server = Server(config="ws_max_clients: 8\nheader_timeout_s: 2\n")
        held = [socket.create_connection(("127.0.0.1", self.server.ws_port)) for _ in range(8)]
        time.sleep(0.2)
        answer, _ = raw_exchange(self.server.ws_port, b"GET /live HTTP/1.1\r\nHost: x\r\n\r\n")
        self.assertEqual(status_of(answer), 503, answer)
        self.assertIn(b"ws_max_clients", answer)
        # The held ones never sent an upgrade: the header deadline closes them, and room returns.
        time.sleep(2.5)
        for s in held:
            s.close()
        answer, _ = raw_exchange(self.server.ws_port, b"GET /nowhere HTTP/1.1\r\nHost: x\r\n\r\n")
        self.assertEqual(status_of(answer), 404, answer)
        self.assertIn(b'"code":"not_found"', answer)
        upgrade = ("GET /live?run=1abc HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n"
                   "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                   "Sec-WebSocket-Version: 13\r\n\r\n").encode()
        answer, _ = raw_exchange(self.server.ws_port, upgrade)
        self.assertEqual(status_of(answer), 400, answer)
        self.assertIn(b"run must be a run id (got '1abc')", answer)
        # A run that is not UTF-8 is named in the refusal, not a reason to fall over.
        answer, _ = raw_exchange(self.server.ws_port, upgrade.replace(b"run=1abc", b"run=\xff"))
        self.assertEqual(status_of(answer), 400, answer)
        self.assertTrue(self.server.alive())
        # Each refusal is JSON that says why: no key, a header flood, no HTTP at all.
        for request, status, says in (
                (upgrade.replace(b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n", b""), 400,
                 b"needs Sec-WebSocket-Key"),
                (upgrade.replace(b"Host: x", b"Host: x\r\nX-Pad: " + b"a" * 20000), 431,
                 b"over 16 KiB"),
                (b"GARBAGE\r\n\r\n", 400, b"does not parse")):
            answer, _ = raw_exchange(self.server.ws_port, request)
            self.assertEqual(status_of(answer), status, answer)
            self.assertIn(says, answer)

    # 3b. A live client's commands are bounded: a subscription to more runs than a client can
    # follow, or a command longer than any real one, is refused, not held.
    def test_the_live_hub_bounds_each_clients_commands(self):
        import asyncio
        import websockets

        async def exchange():
            uri = "ws://127.0.0.1:%d/live" % self.server.ws_port
            async with websockets.connect(uri) as ws:
                replies = []
                for command in ({"subscribe": list(range(1, 300))}, {"subscribe": [-5]},
                                {"subscribe": [18446744073709551615]}, {"subscribe": "ALL"},
                                {"subscribe": [1], "extra": 1}, {"subscribe": [3]}):
                    await ws.send(json.dumps(command))
                    replies.append(json.loads(await ws.recv()))
                await ws.send(json.dumps({"subscribe": list(range(1, 5000))}))
                try:
                    await asyncio.wait_for(ws.recv(), 5)
                    return replies, None
                except websockets.ConnectionClosed as e:
                    return replies, e.rcvd.code if e.rcvd else None

        replies, closed = asyncio.run(exchange())
        messages = [r.get("message", "") for r in replies]
        self.assertIn("at most 256 runs", messages[0])
        self.assertIn("not -5", messages[1])
        self.assertIn("not 18446744073709551615", messages[2])
        self.assertIn('not "ALL"', messages[3])
        self.assertIn('unknown member "extra"', messages[4])
        self.assertEqual(replies[5], {"type": "subscribed", "runs": [3]})
        self.assertEqual(closed, 1009)  # message too big
        self.assertPeakGrowthBelow(UNAUTHENTICATED_GROWTH_MB)

    # 4. Headers are bounded in size: a flood is refused (431) before it is held.
    def test_header_flood_is_refused(self):
        def flood():
            yield b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            lines = (b"X-Filler: " + b"0123456789" * 10 + b"\r\n") * 100
            for _ in range(6200):  # 62 MB of header lines
                yield lines
        answer, sent = raw_exchange(self.server.port, flood())
        self.assertEqual(status_of(answer), 431, answer[:300])
        self.assertLess(sent, 16 << 20)
        many = request_head("GET", "/health", [("X-%d" % i, "1") for i in range(5000)])
        answer, _ = raw_exchange(self.server.port, many)
        self.assertEqual(status_of(answer), 431, answer[:300])
        self.assertPeakGrowthBelow(UNAUTHENTICATED_GROWTH_MB)

    # 5. One range is served (206), several are answered with the whole tile (200), never
    # with more bytes than the tile has; a range beyond it is a 416 naming the size.
    def test_ranges_are_bounded(self):
        run = self.server.create_run()
        status, _, _ = self.server.request("POST", "/api/v1/runs/%d/submaps" % run, submap_pcd(0),
                                           self.server.token)
        self.assertEqual(status, 201)
        url = wait_for_tiles(self.server, run)[0]["url"]
        status, headers, whole = self.server.request("GET", url)
        self.assertEqual(status, 200)
        size = len(whole)
        many = "bytes=" + ",".join("%d-%d" % (i, i) for i in range(0, 1200, 2))
        status, headers, body = self.server.request("GET", url, headers={"Range": many})
        self.assertEqual(status, 200)
        self.assertEqual(body, whole)
        status, headers, body = self.server.request("GET", url, headers={"Range": "bytes=10-19"})
        self.assertEqual(status, 206)
        self.assertEqual(headers["content-range"], "bytes 10-19/%d" % size)
        self.assertEqual(body, whole[10:20])
        status, headers, body = self.server.request("GET", url, headers={"Range": "bytes=-5"})
        self.assertEqual((status, body), (206, whole[-5:]))
        status, headers, body = self.server.request("GET", url,
                                                    headers={"Range": "bytes=%d-" % size})
        self.assertEqual(status, 416)
        self.assertEqual(headers["content-range"], "bytes */%d" % size)
        # The error replaces the tile: its length is the error's, not the tile's.
        self.assertEqual(int(headers["content-length"]), len(body))
        self.assertEqual(json.loads(body)["error"]["code"], "range_not_satisfiable")
        self.assertPeakGrowthBelow(UNAUTHENTICATED_GROWTH_MB)

    # 7. A run lies in one UTM zone: a pose in another is refused, with its whole batch.
    def test_a_pose_in_another_zone_is_refused(self):
        run = self.server.create_run()
        path = "/api/v1/runs/%d/poses" % run
        self.assertEqual(self.server.write("POST", path, {"poses": [pose(i) for i in range(3)]})[0],
                         200)
        status, body = self.server.write("POST", path, {"poses": [pose(3, zone="1N")]})
        self.assertEqual(status, 400)
        self.assertIn("zone 1N", body["error"]["message"])
        status, body = self.server.write("POST", path, {"poses": [pose(4), pose(5, zone="51N")]})
        self.assertEqual(status, 400)
        _, _, tum = self.server.request("GET", "/api/v1/runs/%d/trajectory?format=tum" % run)
        self.assertEqual(tum.decode().count("\n"), 4, tum)  # the zone line and 3 poses
        self.assertEqual(self.server.json("GET", "/api/v1/runs/%d" % run)[1]["poses"], 3)

    # 10. Numbers at their limits and names with slashes.
    def test_numbers_at_their_limits_are_refused(self):
        run = self.server.create_run()
        submaps = "/api/v1/runs/%d/submaps" % run
        for bad in (submap_pcd(0, sequence="-5"), submap_pcd(0, sequence_line=False),
                    submap_pcd(0, sequence=str(1 << 63))):
            status, _, body = self.server.request("POST", submaps, bad, self.server.token)
            self.assertEqual(status, 400, body)
        poses = "/api/v1/runs/%d/poses" % run
        for sequence in (1 << 63, -1, 1 << 64):
            p = pose(0)
            p["sequence"] = sequence
            self.assertEqual(self.server.write("POST", poses, {"poses": [p]})[0], 400, sequence)
        for query in ("level=1e3", "level=1.0", "level=99", "level=", "bbox=0,0,1,1x"):
            status, _, body = self.server.request("GET",
                                                  "/api/v1/runs/%d/tiles?%s" % (run, query))
            self.assertEqual(status, 400, query)
        status, _, _ = self.server.request(
            "GET", "/api/v1/runs/%d/export?level=1e3&bbox=0,0,1,1" % run)
        self.assertEqual(status, 400)
        info = self.server.json("GET", "/api/v1/runs/%d" % run)[1]
        self.assertEqual((info["submaps"], info["poses"]), (0, 0))

    def test_a_large_export_is_sent_without_holding_it(self):
        # 50 submaps 40 m apart, 64 000 points each: 3.2 million points in the tiles.
        run = self.server.create_run()
        points = [(0.1 * x + 0.05, 0.1 * y + 0.05, 0.05) for x in range(400) for y in range(-80, 80)]
        for i in range(0, 100, 2):
            status, _, body = self.server.request("POST", "/api/v1/runs/%d/submaps" % run,
                                                  submap_pcd(i, points=points), self.server.token)
            self.assertEqual(status, 201, body)
        self.assertEqual(self.server.write("POST", "/api/v1/runs/%d/finish" % run, {})[0], 200)
        # A fresh process: the tiles on disk, nothing of the ingest in memory.
        self.server = self.server.restarted()
        self.server.request("GET", "/health")
        baseline = self.server.status("VmHWM")
        conn = http.client.HTTPConnection("127.0.0.1", self.server.port, timeout=60)
        conn.request("GET", "/api/v1/runs/%d/export?format=las&bbox=0,0,1000000,10000000" % run)
        r = conn.getresponse()
        self.assertEqual(r.status, 200)
        self.assertEqual(int(r.getheader("X-Points")), 50 * 64000)
        received = 0
        while True:
            piece = r.read(1 << 20)
            if not piece:
                break
            received += len(piece)
        conn.close()
        self.assertEqual(received, 227 + 102 + 20 * 50 * 64000)  # header, zone key, records
        self.assertPeakGrowthBelow(UNAUTHENTICATED_GROWTH_MB, baseline)

    def test_pose_batches_are_bounded(self):
        run = self.server.create_run()
        poses = "/api/v1/runs/%d/poses" % run
        status, body = self.server.write("POST", poses, {"poses": [pose(i) for i in range(10001)]})
        self.assertEqual(status, 413)
        self.assertIn("max_poses_per_batch", body["error"]["message"])
        t = time.time()
        status, body = self.server.write("POST", poses, {"poses": [pose(i) for i in range(200000)]})
        self.assertEqual(status, 413)
        self.assertLess(time.time() - t, 10.0)
        self.assertEqual(self.server.write("POST", poses, {"poses": [pose(i) for i in range(10000)]}),
                         (200, {"stored": 10000, "received": 10000}))

    def test_a_line_name_with_slashes_can_be_fetched(self):
        self.server.create_run(line="../x/y")
        status, body = self.server.json("GET", "/api/v1/lines/..%2Fx%2Fy")
        self.assertEqual(status, 200)
        self.assertEqual(body["name"], "../x/y")

    def test_a_submap_spread_over_kilometres_is_refused(self):
        run = self.server.create_run()
        import random
        rng = random.Random(5)
        points = [(rng.uniform(-9000, 9000), rng.uniform(-9000, 9000), 0.5) for _ in range(100000)]
        status, _, body = self.server.request("POST", "/api/v1/runs/%d/submaps" % run,
                                              submap_pcd(0, points=points), self.server.token)
        self.assertEqual(status, 400, body)
        self.assertIn(b"max_submap_extent_m", body)
        self.assertPeakGrowthBelow(64)

    def test_the_fronts_refusals_say_what_is_wrong(self):
        status, headers, body = self.server.request("PATCH", "/api/v1/runs", b"{}",
                                                    self.server.token)
        self.assertEqual(status, 405)
        self.assertIn("POST", headers["allow"])
        self.assertIn(b"PATCH is not allowed", body)
        status, _, body = self.server.request("GET", "/api/v1/runs/%zz")
        self.assertEqual(status, 400)
        self.assertIn(b"%-escape", body)
        answer, _ = raw_exchange(self.server.port, b"GARBAGE\r\n\r\n")
        self.assertEqual(status_of(answer), 400)
        self.assertIn(b"malformed HTTP request", body_of(answer))
        status, _, body = self.server.request("GET", "/nowhere")
        self.assertEqual(status, 404)
        self.assertIn(b"no resource at /nowhere", body)

    # A JSON body is read strictly: a member named twice (which a plain parse resolves by
    # keeping the last) or one the route does not know (a typo that would go unsaid) is
    # refused by name. A point of interest sent back as it was read (id, timestamps) is taken.
    # Two Authorization headers are refused rather than one of them chosen.
    def test_json_bodies_are_read_strictly(self):
        def post(path, body, method="POST"):
            status, _, answer = self.server.request(method, path, body, self.server.token,
                                                    headers={"Content-Type": "application/json"})
            return status, json.loads(answer).get("error", {}).get("message", "")

        self.assertEqual(post("/api/v1/runs", b'{"line": "l", "vehicle": "v", "line": "m"}'),
                         (400, 'the body is not JSON: member "line" appears twice in one object'))
        self.assertEqual(post("/api/v1/runs", b'{"line": "l", "vehicel": "v"}'),
                         (400, 'unknown member "vehicel" (line, vehicle, start_ns)'))
        self.assertEqual(self.server.json("GET", "/api/v1/runs")[1]["runs"], [])
        poi = {"kind": "mast", "utm_zone": "50N", "position": [432100.0, 3585200.0, 30.0],
               "properties": {"a": {"b": 1}}}
        status, created = self.server.write("POST", "/api/v1/pois", poi)
        self.assertEqual(status, 201)
        path = "/api/v1/pois/%d" % created["id"]
        created["name"] = "M12"
        status, updated = self.server.write("PUT", path, created)
        self.assertEqual((status, updated["name"], updated["id"]), (200, "M12", created["id"]))
        nested = b'{"kind": "mast", "utm_zone": "50N", "position": [1, 2, 3], ' \
                 b'"properties": {"a": {"b": 1, "b": 2}}}'
        self.assertEqual(post(path, nested, "PUT"),
                         (400, 'the body is not JSON: member "b" appears twice in one object'))
        many = ", ".join('"k%d": %d' % (i, i) for i in range(40)) + ', "k7": 0'
        self.assertEqual(post(path, nested.replace(b'"b": 1, "b": 2', many.encode()), "PUT"),
                         (400, 'the body is not JSON: member "k7" appears twice in one object'))
        status, said = post(path, json.dumps(dict(poi, colour="red")).encode(), "PUT")
        self.assertEqual(status, 400)
        self.assertIn('unknown member "colour"', said)
        self.assertEqual(self.server.json("GET", path)[1], updated)
        run = self.server.create_run()
        status, said = post("/api/v1/runs/%d/poses" % run,
                            json.dumps({"poses": [dict(pose(0), stamp=5)]}).encode())
        self.assertEqual(status, 400)
        self.assertIn('pose 0: unknown member "stamp"', said)
        answer, _ = raw_exchange(self.server.port, request_head(
            "POST", "/api/v1/runs/%d/finish" % run,
            [("Authorization", "Bearer " + self.server.token), ("Authorization", "Bearer x"),
             ("Content-Length", "0")]))
        self.assertEqual(status_of(answer), 400)
        self.assertIn(b"send one Authorization header, not 2", body_of(answer))
        self.assertEqual(self.server.json("GET", "/api/v1/runs/%d" % run)[1]["status"], "live")

    # 11. The store's files are the server's user's alone.
    def test_the_store_is_private(self):
        data = self.server.data
        mode = lambda p: stat.S_IMODE(os.stat(os.path.join(data, p)).st_mode)
        self.assertEqual(mode(""), 0o700)
        self.assertEqual(mode("incoming"), 0o700)
        self.assertEqual(mode("index.sqlite"), 0o600)
        self.assertEqual(mode("ingest.token"), 0o600)

    # 12. A write takes the token from the Authorization header alone: a cookie is what a
    # browser sends along with a form that another page on this host posts. A ?token= on a
    # read that needs none is not echoed into a cookie.
    def test_writes_take_the_token_from_the_header_alone(self):
        body = json.dumps({"line": "L", "vehicle": "V"})
        cookie = {"Cookie": "raillomer_token=" + self.server.token, "Content-Type": "text/plain"}
        status, _, answer = self.server.request("POST", "/api/v1/runs", body, headers=cookie)
        self.assertEqual(status, 401, answer)
        self.assertEqual(self.server.json("GET", "/api/v1/runs")[1]["runs"], [])
        self.assertEqual(self.server.request("POST", "/api/v1/runs", body, self.server.token)[0],
                         201)
        status, headers, _ = self.server.request("GET", "/health?token=a;%20Domain=evil.example")
        self.assertEqual(status, 200)
        self.assertNotIn("set-cookie", headers)


class Requests:
    """Raw HTTP/1.1 requests as bytes, with the ingest token unless told otherwise."""

    def __init__(self, token):
        self.auth = "Authorization: Bearer %s\r\n" % token
        self.cases = []

    def add(self, method, path, body=b"", headers="", with_auth=True, length=True):
        head = "%s %s HTTP/1.1\r\nHost: 127.0.0.1\r\n%s%s" % (
            method, path, self.auth if with_auth else "", headers)
        if length:
            head += "Content-Length: %d\r\n" % len(body)
        self.cases.append((head + "\r\n").encode() + body)

    def json(self, method, path, body):
        self.add(method, path, body, "Content-Type: application/json\r\n")


JSON_BODIES = [b"", b"null", b"[]", b"{", b"\xff\xfe{}", b'{"a":' * 5000 + b"1" + b"}" * 5000,
               b'{"line": 3, "vehicle": "v"}', b'{"line": "", "vehicle": "v"}',
               b'{"line": "x\u0001", "vehicle": "v"}', b'{"line": "l", "vehicle": "v", '
               b'"start_ns": -1}', b'{"line": "l", "vehicle": "v", "start_ns": 1.5}',
               b'{"line": "l", "vehicle": "v", "start_ns": 9223372036854775808}',
               b'{"line": "a\xe2\x80\xaeb", "vehicle": "v"}', b'{"line": "l", "vehicle": "\xc2\x85"}',
               b'{"line": "%s", "vehicle": "v"}' % (b"x" * 300), b"NaN", b"1e999",
               b'{"line": "l", "vehicle": "v", "line": "m"}', b'{"line": "l", "vehicel": "v"}']


def unauthorised_writes(r, run, token):
    """Every write without a token, with a wrong one, with one in the query, or gzipped."""
    runs = "/api/v1/runs/%d" % run
    writes = [("POST", "/api/v1/runs"), ("POST", runs + "/finish"), ("POST", runs + "/submaps"),
              ("POST", runs + "/poses"), ("POST", "/api/v1/lines/L/kmposts"),
              ("POST", "/api/v1/pois"), ("PUT", "/api/v1/pois/1"), ("DELETE", "/api/v1/pois/1")]
    for method, path in writes:
        r.add(method, path, b"{}", with_auth=False)
        r.add(method, path, b"{}", "Authorization: Bearer wrong-token-wrong-token\r\n", False)
        r.add(method, path + "?token=" + token, b"{}", with_auth=False)
        r.add(method, path, b"{}", "Content-Encoding: gzip\r\n")


def bad_runs_and_poses(r, run):
    """Runs with bad JSON, poses with bad fields or bodies."""
    runs = "/api/v1/runs/%d" % run
    for body in JSON_BODIES:
        r.json("POST", "/api/v1/runs", body)
    good = pose(0)
    for change in ({"sequence": -1}, {"sequence": 1.5}, {"sequence": "1"}, {"stamp_ns": None},
                   {"p": [1, 2]}, {"p": [1e999, 0, 0]}, {"q": [0, 0, 0, 2]}, {"q": [0, 0, 0]},
                   {"georeferenced": "yes"}, {"utm_zone": "99Q"}, {"utm_zone": 50},
                   {"p": [-5.0, 3585200.0, 30.0]}, {"sequence": 1 << 63}, {"stamp": 5}):
        r.json("POST", runs + "/poses", json.dumps({"poses": [dict(good, **change)]}).encode())
    for body in JSON_BODIES[:6] + [b'{"poses": 5}', b'{"poses": [1, 2]}', b'{"pose": []}']:
        r.json("POST", runs + "/poses", body)


def bad_submaps(r, run):
    """Submaps truncated, with a wrong header, zone, origin, stamps, sequence or points."""
    ok = submap_pcd(0)
    for body in [b"", b"garbage", ok[:-7], ok.replace(b"DATA binary", b"DATA ascii"),
                 ok.replace(b"POINTS 32000", b"POINTS 99999999999999999999"),
                 ok.replace(b"POINTS 32000", b"POINTS -1"),
                 ok.replace(b"FIELDS x y z intensity", b"FIELDS x y z"),
                 ok.replace(b"zone 50N", b"zone 51N"), ok.replace(b"zone 50N", b"zone local"),
                 ok.replace(b"zone 50N", b"zone 0Z"),
                 ok.replace(b"origin 432100", b"origin -432100"),
                 ok.replace(b"origin 432100.0000", b"origin nan"),
                 ok.replace(b"stamps 1600000000", b"stamps 1600000009"),
                 submap_pcd(0, sequence="-5"), submap_pcd(0, sequence="x"),
                 submap_pcd(0, sequence_line=False), submap_pcd(0, header_extra=ok[:40]),
                 submap_pcd(0, points=[(float("nan"), 0.0, 0.0)]),
                 submap_pcd(0, points=[(20000.0, 0.0, 0.0)]), submap_pcd(0, points=[]),
                 submap_pcd(0, points=[(0.0, 0.0, 0.0), (3000.0, 0.0, 0.0)])]:
        r.add("POST", "/api/v1/runs/%d/submaps" % run, body,
              "Content-Type: application/octet-stream\r\n")


def bad_posts_and_pois(r, run):
    """Kilometre posts and points of interest with bad fields, writes to runs that do not
    exist."""
    for body in [b'{"km": "1", "easting": 1, "northing": 2}', b'{"km": 1}', b"[]",
                 b'{"km": 1, "easting": 432100, "northing": 3585200}']:
        r.json("POST", "/api/v1/lines/Nowhere/kmposts", body)
    for body in [b'{"kind": 1}', b'{"kind": "m", "utm_zone": "50N", "position": [1, 2]}',
                 b'{"kind": "m", "utm_zone": "50N", "position": [1, 2, 3], "properties": []}',
                 b'{"kind": "m", "utm_zone": "50N", "position": [1, 2, 3], "line": 5}',
                 b'{"kind": "m", "utm_zone": "50N", "position": [432100, 3585200, 3], '
                 b'"properties": ' + b'{"a":' * 17 + b"1" + b"}" * 18]:
        r.json("POST", "/api/v1/pois", body)
        r.json("PUT", "/api/v1/pois/1", body)
    r.json("POST", "/api/v1/runs/%d/finish" % run, b'{"end_ns": "soon"}')
    r.add("POST", "/api/v1/runs/999/finish", b"{}")
    r.add("POST", "/api/v1/runs/0/poses", json.dumps({"poses": [pose(0)]}).encode())
    r.add("POST", "/api/v1/runs/99999999999999999999/submaps", submap_pcd(0))
    r.add("DELETE", "/api/v1/pois/999")


def bad_reads(r, run):
    """Reads of what does not exist, with bad levels, boxes, formats or paths."""
    runs = "/api/v1/runs/%d" % run
    reads = ["/api/v1/runs/999", "/api/v1/runs/abc", "/api/v1/runs/-1", "/api/v1/runs/1.0",
             runs + "/tiles?level=-1", runs + "/tiles?level=4", runs + "/tiles?level=1e3",
             runs + "/tiles?level=0x1", runs + "/tiles?bbox=1,2,3", runs + "/tiles?bbox=a,b,c,d",
             runs + "/tiles?bbox=1,2,3,4,5", runs + "/tiles?bbox=nan,0,1,1",
             runs + "/tiles/0/abc/1", runs + "/tiles/9/0/0", runs + "/tiles/0/1/99999999999999999999",
             runs + "/tiles/-1/0/0", runs + "/trajectory?format=xml",
             "/api/v1/runs/999/trajectory", runs + "/export", runs + "/export?format=xyz&bbox=0,0,1,1",
             runs + "/export?level=9&bbox=0,0,1,1", runs + "/export?bbox=0,0,1",
             runs + "/export?line=L&from_km=1", runs + "/export?line=L&from_km=a&to_km=1",
             runs + "/export?half_width_m=-1&line=L&from_km=0&to_km=1",
             runs + "/export?half_width_m=inf&bbox=0,0,1,1",
             runs + "/export?line=L&from_km=0&to_km=0.1&bbox=0,0,1,1",
             runs + "/export?bbox=0,0,1,1&from_km=abc", runs + "/export?bbox=0,0,1,1&half_width_m=-1",
             runs + "/export?line=L&from_km=0&to_km=1e306", runs + "/tiles?bbox=1,1,0,0",
             "/api/v1/pois?bbox=1e6,1e7,0,0", "/api/v1/lines/L/segment?from_km=0&to_km=1e306",
             "/api/v1/lines/Nowhere", "/api/v1/lines/Nowhere/segment?from_km=0&to_km=1",
             "/api/v1/lines/L/segment", "/api/v1/lines/L/segment?from_km=x&to_km=1",
             "/api/v1/lines/L/segment?from_km=1e999&to_km=1",
             "/api/v1/pois?bbox=1,2", "/api/v1/pois/abc", "/api/v1/pois/999", "/nowhere",
             "/api/v1/runs/%zz", "/api/v1/%00", "/api/v1/runs?x=%", "/api/v1/runs/1/../../health",
             "/" + "a" * 20000]
    for path in reads:
        r.add("GET", path, with_auth=False)


def bad_run_ids(r):
    """Every run route with an id that is no run's."""
    for bad_id in ("abc", "0", "-1", "999", "1e3", "01x"):
        base = "/api/v1/runs/" + bad_id
        for read in ("", "/tiles", "/tiles/0/0/0", "/trajectory", "/export?bbox=0,0,1,1"):
            r.add("GET", base + read, with_auth=False)
        r.add("POST", base + "/finish", b"{}")
        r.add("POST", base + "/submaps", submap_pcd(0))
        r.add("POST", base + "/poses", json.dumps({"poses": [pose(0)]}).encode())
    for method in ("PATCH", "OPTIONS", "TRACE", "CONNECT", "PROPFIND", "BREW"):
        r.add(method, "/api/v1/runs", b"{}")


def bad_protocol(auth):
    """Bytes that are not the HTTP/1.1 the server speaks."""
    return [b"GARBAGE\r\n\r\n", b"GET\r\n\r\n", b"GET / HTTP/9.9\r\n\r\n",
            b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n", b"GET /health HTTP/1.1\r\nNoColon\r\n\r\n",
            b"GET /health HTTP/1.1\r\nX: a\x00b\r\n\r\n",
            b"POST /api/v1/runs HTTP/1.1\r\nContent-Length: -5\r\n\r\n",
            b"POST /api/v1/runs HTTP/1.1\r\nContent-Length: 99999999999999999999999\r\n\r\n",
            b"POST /api/v1/runs HTTP/1.1\r\nContent-Length: 5\r\nContent-Length: 6\r\n\r\n",
            b"POST /api/v1/runs HTTP/1.1\r\nTransfer-Encoding: gzip\r\n\r\n",
            b"POST /api/v1/runs HTTP/1.1\r\nTransfer-Encoding: chunked\r\n" + auth.encode() +
            b"\r\nzz\r\n", b"GET /h\xffealth HTTP/1.1\r\n\r\n",
            b"GET http://evil/ HTTP/1.1\r\n\r\n", b"GET * HTTP/1.1\r\n\r\n"]


def bad_requests(run, token):
    """Malformed and hostile requests, as raw bytes: each must get a 4xx and change nothing."""
    r = Requests(token)
    unauthorised_writes(r, run, token)
    bad_runs_and_poses(r, run)
    bad_submaps(r, run)
    bad_posts_and_pois(r, run)
    bad_reads(r, run)
    bad_run_ids(r)
    return r.cases + bad_protocol(r.auth)


class BadInputs(unittest.TestCase):
    """About two hundred malformed and hostile requests: each gets a 4xx with a JSON error (or
    the connection closes on bytes that are no HTTP at all), never a 5xx; nothing changes."""

    def test_every_bad_request_gets_a_4xx_and_changes_nothing(self):
        server = Server()
        try:
            run = server.create_run()
            self.assertEqual(server.request("POST", "/api/v1/runs/%d/submaps" % run, submap_pcd(0),
                                            server.token)[0], 201)
            self.assertEqual(server.write("POST", "/api/v1/runs/%d/poses" % run,
                                          {"poses": [pose(0)]})[0], 200)
            before = server.json("GET", "/api/v1/runs/%d" % run)[1]
            cases = bad_requests(run, server.token)
            self.assertGreaterEqual(len(cases), 192)
            statuses = []
            for case in cases:
                answer, _ = raw_exchange(server.port, case, read_timeout=15)
                status = status_of(answer)
                statuses.append(status)
                self.assertTrue(400 <= status < 500, (case[:200], answer[:300]))
                error = json.loads(body_of(answer))["error"]
                self.assertTrue(error["code"] and error["message"], answer)
            self.assertTrue(server.alive())
            self.assertEqual(server.json("GET", "/api/v1/runs/%d" % run)[1], before)
            self.assertEqual(server.json("GET", "/api/v1/runs")[1]["runs"], [before])
            _, _, metrics = server.request("GET", "/metrics")
            self.assertNotIn(b'status="5', metrics)
        finally:
            server.cleanup()


class CommandLine(unittest.TestCase):
    """Bad flags and config paths: a message naming them and a non-zero exit, before any store
    is made."""

    def test_bad_flags_and_config_paths_are_named(self):
        work = tempfile.mkdtemp(prefix="raillomer_cli_")
        try:
            data = os.path.join(work, "data")
            for extra, words in ((["--config", work], "a folder, not a config file"),
                                 (["--config", os.path.join(work, "no.yaml")], "no such file"),
                                 (["--port", "-1"], "not in range 0 to 65535"),
                                 (["--ws-port", "70000"], "not in range 0 to 65535")):
                done = subprocess.run(
                    [os.path.join(bin_dir(), "raillomer-server"), "--data", data] + extra,
                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=30)
                self.assertNotEqual(done.returncode, 0, extra)
                self.assertIn(words, done.stdout + done.stderr, extra)
                self.assertFalse(os.path.exists(data), extra)
        finally:
            shutil.rmtree(work, ignore_errors=True)


class StaticFiles(unittest.TestCase):
    """6. The web root: nothing outside it, no NUL tricks, and the read token when reads need
    one."""

    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="raillomer_web_")
        web = os.path.join(self.dir, "web")
        os.makedirs(os.path.join(web, "assets"))
        with open(os.path.join(web, "index.html"), "w") as f:
            f.write("<html>viewer</html>")
        with open(os.path.join(web, "assets", "app-1a2b.js"), "w") as f:
            f.write("console.log(1)")
        with open(os.path.join(self.dir, "secret.txt"), "w") as f:
            f.write("not for the web")
        os.symlink(os.path.join(self.dir, "secret.txt"), os.path.join(web, "leak.txt"))
        os.symlink("index.html", os.path.join(web, "home.html"))
        self.web = web
        self.server = None

    def tearDown(self):
        if self.server:
            self.assertTrue(self.server.alive(), self.server.log_text())
            self.server.cleanup()
        shutil.rmtree(self.dir, ignore_errors=True)

    def test_nothing_outside_the_web_root_is_served(self):
        self.server = Server(flags=["--web-root", self.web])
        get = lambda path, **kw: self.server.request("GET", path, **kw)
        self.assertEqual(get("/")[2], b"<html>viewer</html>")
        self.assertEqual(get("/home.html")[0], 200)  # a symlink inside the root
        status, _, body = get("/leak.txt")
        self.assertEqual(status, 404)
        self.assertNotIn(b"not for the web", body)
        for path in ("/index.html%00.txt", "/index.html%00"):
            status, _, body = get(path)
            self.assertEqual(status, 400, path)
        status, headers, _ = get("/assets/app-1a2b.js")
        self.assertEqual(status, 200)
        self.assertTrue(headers["content-type"].startswith("text/javascript"))
        self.assertIn("immutable", headers["cache-control"])
        status, headers, _ = get("/index.html")
        self.assertEqual(get("/index.html", headers={"If-None-Match": headers["etag"]})[0], 304)
        answer, _ = raw_exchange(self.server.port, b"GET /../secret.txt HTTP/1.1\r\nHost: x\r\n\r\n")
        self.assertEqual(status_of(answer), 404)

    def test_static_files_need_the_read_token_when_reads_do(self):
        self.server = Server(config="reads_need_token: true\nread_token: read-token-0123456789\n",
                             flags=["--web-root", self.web])
        get = lambda path, **kw: self.server.request("GET", path, **kw)
        self.assertEqual(get("/index.html")[0], 401)
        self.assertEqual(get("/index.html", token="read-token-0123456789")[0], 200)
        status, headers, _ = get("/index.html?token=read-token-0123456789")
        self.assertEqual(status, 200)
        cookie = headers["set-cookie"].split(";")[0]
        self.assertEqual(cookie, "raillomer_token=read-token-0123456789")
        self.assertEqual(get("/assets/app-1a2b.js", headers={"Cookie": cookie})[0], 200)
        self.assertEqual(get("/index.html?token=wrong-token-0123456789")[0], 401)


class LostSubmaps(unittest.TestCase):
    """9. A submap acknowledged before a crash whose payload did not survive is logged at the
    next start, counted in /metrics, and out of its run's counts until it is sent again."""

    def test_lost_payloads_are_logged_counted_and_restored(self):
        # No flusher: the submaps' points stay in memory and their payloads in incoming/.
        server = Server(config="store:\n  flush_interval_ms: 0\n")
        data = server.data
        try:
            run = server.create_run()
            payloads = [submap_pcd(i) for i in range(3)]
            for p in payloads:
                status, _, body = server.request("POST", "/api/v1/runs/%d/submaps" % run, p,
                                                 server.token)
                self.assertEqual(status, 201, body)
            self.assertEqual(server.stop(signal.SIGKILL), -signal.SIGKILL)
            os.remove(os.path.join(data, "incoming", "%d-1.pcd" % run))  # a power cut
            server = Server(data=data)
            log = server.log_text()
            self.assertIn("recovered 2 submaps", log)
            self.assertIn("LOST 1 acknowledged submaps whose payload is gone (run %d: 1)" % run, log)
            self.assertEqual(server.metric("raillomer_submaps_lost"), 1)
            self.assertEqual(server.metric("raillomer_submaps_lost_total"), 1)
            self.assertEqual(server.metric("raillomer_submaps_recovered_total"), 2)
            info = server.json("GET", "/api/v1/runs/%d" % run)[1]
            self.assertEqual((info["submaps"], info["submaps_lost"], info["points"]),
                             (2, 1, 2 * 32000))
            # Submaps 0 and 2 do not overlap: their tiles hold both whole.
            tiles = wait_for_tiles(server, run)
            self.assertEqual(sum(t["points"] for t in tiles), 2 * 32000)
            status, _, _ = server.request("POST", "/api/v1/runs/%d/submaps" % run, payloads[1],
                                          server.token)
            self.assertEqual(status, 201)  # restored
            info = server.json("GET", "/api/v1/runs/%d" % run)[1]
            self.assertEqual((info["submaps"], info["submaps_lost"], info["points"]),
                             (3, 0, 3 * 32000))
            self.assertEqual(server.metric("raillomer_submaps_lost"), 0)
        finally:
            server.cleanup()
            shutil.rmtree(os.path.dirname(data), ignore_errors=True)


if __name__ == "__main__":
    unittest.main()
