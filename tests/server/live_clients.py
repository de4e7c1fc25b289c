#!/usr/bin/env python3
"""WebSocket clients of raillomer-server's live hub, with the websockets library (not ours).

Connects --clients readers and --slow clients that subscribe and then never read (with a tiny
receive buffer), subscribes all to --run, writes "<out>.ready" beside stdout's file once all are
subscribed (when stdout is a file), and counts the poses each reader receives until it has
--expect of them or --timeout passes. Prints JSON: per reader the poses received, whether in
order, and the delivery latency (server send stamp to receipt) p50/p99 in ms.
"""
import argparse
import asyncio
import json
import os
import socket
import sys
import time

import websockets


async def reader(url, run, expect, timeout, ready):
    async with websockets.connect(url, max_queue=None) as ws:
        await ws.send(json.dumps({"subscribe": [run]}))
        json.loads(await ws.recv())  # the subscription's answer
        ready.set()
        poses, last, in_order, latencies = 0, -1, True, []
        deadline = time.monotonic() + timeout
        while poses < expect and time.monotonic() < deadline:
            try:
                text = await asyncio.wait_for(ws.recv(), deadline - time.monotonic())
            except asyncio.TimeoutError:
                break
            m = json.loads(text)
            if m.get("type") != "pose":
                continue
            latencies.append((time.time_ns() - m["sent_ns"]) / 1e6)
            in_order = in_order and m["sequence"] > last
            last = m["sequence"]
            poses += 1
        latencies.sort()
        pick = lambda q: latencies[min(len(latencies) - 1, int(q * len(latencies)))] if latencies else None
        return {"poses": poses, "in_order": in_order, "latency_p50_ms": pick(0.5), "latency_p99_ms": pick(0.99)}


async def slow(url, run, ready, done):
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    host, port = url.split("//")[1].split("/")[0].split(":")
    sock.connect((host, int(port)))
    async with websockets.connect(url, sock=sock, max_queue=1, read_limit=1024) as ws:
        await ws.send(json.dumps({"subscribe": [run]}))
        ready.set()
        await done.wait()  # never reads


async def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--run", type=int, required=True)
    p.add_argument("--clients", type=int, default=1)
    p.add_argument("--slow", type=int, default=0)
    p.add_argument("--expect", type=int, required=True)
    p.add_argument("--timeout", type=float, default=30.0)
    a = p.parse_args()
    url = f"ws://127.0.0.1:{a.port}/live"
    readies = [asyncio.Event() for _ in range(a.clients + a.slow)]
    done = asyncio.Event()
    slow_tasks = [asyncio.create_task(slow(url, a.run, readies[a.clients + i], done)) for i in range(a.slow)]
    tasks = [asyncio.create_task(reader(url, a.run, a.expect, a.timeout, readies[i])) for i in range(a.clients)]
    await asyncio.wait_for(asyncio.gather(*(r.wait() for r in readies)), 30)
    out = os.readlink("/proc/self/fd/1") if os.path.islink("/proc/self/fd/1") else ""
    if out.startswith("/"):
        open(out + ".ready", "w").close()
    results = await asyncio.gather(*tasks)
    done.set()
    for t in slow_tasks:
        t.cancel()
    json.dump({"clients": results}, sys.stdout)


if __name__ == "__main__":
    asyncio.run(main())
