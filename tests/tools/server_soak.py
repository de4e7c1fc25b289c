#!/usr/bin/python3
"""Soak: raillomer-server under slow clients and normal readers at once, on loopback.

300 slow clients (slowloris: one header line every 10 s; a client the server closes opens
again at once) and 64 readers fetching tiles over keep-alive connections run for --seconds
(60). Meanwhile /health is asked every 0.25 s on a fresh connection. Targets: /health answers
within 1 s throughout, no reader gets an error, and the server's resident memory stays under
--memory-mb (200). Everything stops by itself.

Usage: /usr/bin/python3 tests/tools/server_soak.py [--build build] [--seconds 60]
           [--slow 300] [--readers 64] [--memory-mb 200] [--check]
With --check the exit status is 1 when a target is missed."""
import argparse
import http.client
import json
import os
import select
import socket
import sys
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                "server"))
import harness  # noqa: E402


def slow_clients(port, count, stop, stats):
    """Keeps `count` connections sending a request's header one line every 10 s."""
    def open_one():
        s = socket.create_connection(("127.0.0.1", port))
        s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        stats["opened"] += 1
        return s

    socks = [open_one() for _ in range(count)]
    last_line = time.time()
    while not stop.is_set():
        readable, _, _ = select.select(socks, [], [], 0.2)
        for s in readable:  # closed by the server's header deadline (or answered): reopen
            try:
                s.recv(4096)
            except OSError:
                pass
            s.close()
            socks[socks.index(s)] = open_one()
            stats["closed_by_server"] += 1
        if time.time() - last_line >= 10.0:
            last_line = time.time()
            for s in socks:
                try:
                    s.sendall(b"X-Slow: %d\r\n" % int(last_line))
                except OSError:
                    pass
    for s in socks:
        s.close()


def reader(port, paths, k, stop, stats, lock):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    i = k
    latencies, errors = [], 0
    while not stop.is_set():
        path = paths[i % len(paths)]
        i += 7
        t = time.perf_counter()
        try:
            conn.request("GET", path)
            r = conn.getresponse()
            r.read()
            if r.status != 200:
                errors += 1
        except (OSError, http.client.HTTPException):
            errors += 1
            conn.close()
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
            continue
        latencies.append(time.perf_counter() - t)
    conn.close()
    with lock:
        stats["latencies"] += latencies
        stats["errors"] += errors


def health_prober(server, stop, stats):
    while not stop.wait(0.25):
        t = time.perf_counter()
        try:
            status, _, _ = server.request("GET", "/health", timeout=5)
        except OSError:
            status = 0
        took = time.perf_counter() - t
        stats["health"].append(took)
        if status != 200:
            stats["health_errors"] += 1


def memory_sampler(server, stop, stats):
    while not stop.wait(0.5):
        stats["rss_mb"] = max(stats["rss_mb"], server.status("VmRSS"))


def parse_args():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(harness.ROOT, "build"))
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--slow", type=int, default=300)
    ap.add_argument("--readers", type=int, default=64)
    ap.add_argument("--memory-mb", type=float, default=200.0)
    ap.add_argument("--check", action="store_true")
    return ap.parse_args()


def ingest_run(server):
    """A finished run of 12 submaps; the URLs of its tiles at every level."""
    run = server.create_run(line="Soak")
    for i in range(12):
        status, _, body = server.request("POST", "/api/v1/runs/%d/submaps" % run,
                                         harness.submap_pcd(i), server.token)
        if status != 201:
            sys.exit("server_soak: ingesting submap %d: %d %s" % (i, status, body[:200]))
    server.write("POST", "/api/v1/runs/%d/finish" % run, {})
    paths = []
    for level in range(4):
        _, body = server.json("GET", "/api/v1/runs/%d/tiles?level=%d" % (run, level))
        paths += [t["url"] for t in body["tiles"]]
    return paths


def soak(server, paths, a, start_mb):
    """Slow clients, tile readers, a health prober and a memory sampler for a.seconds; their
    tallies."""
    stop = threading.Event()
    lock = threading.Lock()
    stats = {"opened": 0, "closed_by_server": 0, "latencies": [], "errors": 0, "health": [],
             "health_errors": 0, "rss_mb": start_mb}
    threads = [threading.Thread(target=slow_clients, args=(server.port, a.slow, stop, stats))]
    threads += [threading.Thread(target=reader, args=(server.port, paths, k, stop, stats, lock))
                for k in range(a.readers)]
    threads += [threading.Thread(target=health_prober, args=(server, stop, stats)),
                threading.Thread(target=memory_sampler, args=(server, stop, stats))]
    for t in threads:
        t.start()
    time.sleep(a.seconds)
    stop.set()
    for t in threads:
        t.join()
    return stats


def summary(server, stats, a, start_mb):
    """The figures as printed (JSON)."""
    lat = sorted(stats["latencies"])
    pick = lambda q: lat[min(len(lat) - 1, int(q * len(lat)))] * 1000.0 if lat else float("nan")
    worst_health = max(stats["health"]) if stats["health"] else float("inf")
    return {
        "seconds": a.seconds, "slow_clients": a.slow, "readers": a.readers,
        "slow_connections_opened": stats["opened"],
        "slow_connections_closed_by_server": stats["closed_by_server"],
        "tile_requests": len(lat), "tile_errors": stats["errors"],
        "tile_p50_ms": round(pick(0.5), 2), "tile_p99_ms": round(pick(0.99), 2),
        "health_probes": len(stats["health"]), "health_errors": stats["health_errors"],
        "health_worst_s": round(worst_health, 3),
        "rss_start_mb": round(start_mb, 1), "rss_peak_mb": round(stats["rss_mb"], 1),
        "memory_bound_mb": a.memory_mb,
        "header_timeouts": server.metric("raillomer_http_header_timeouts_total"),
    }


def main():
    a = parse_args()
    os.environ.setdefault("RAILLOMER_BIN", os.path.join(a.build, "bin"))
    server = harness.Server()
    try:
        paths = ingest_run(server)
        start_mb = server.status("VmRSS")
        print("server_soak: %d tiles; %d slow clients and %d readers for %.0f s ..."
              % (len(paths), a.slow, a.readers, a.seconds), flush=True)
        stats = soak(server, paths, a, start_mb)
        result = summary(server, stats, a, start_mb)
        print(json.dumps(result, indent=1))
        worst_health = max(stats["health"]) if stats["health"] else float("inf")
        ok = (worst_health < 1.0 and stats["health_errors"] == 0 and
              stats["errors"] == 0 and stats["rss_mb"] < a.memory_mb and server.alive())
        print("server_soak: " + ("all targets met" if ok else "a target was missed"))
        if a.check and not ok:
            sys.exit(1)
    finally:
        server.cleanup()


if __name__ == "__main__":
    main()
