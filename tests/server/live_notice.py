#!/usr/bin/env python3
"""One WebSocket client of raillomer-server's live hub (Python websockets, not ours).

Connects to ws://127.0.0.1:PORT/live (with ?token=T if given), subscribes to --run, writes
"<ready file>" once subscribed, and prints the first message of --type as JSON (exit 0), or exits
1 on timeout and 2 if the connection is refused (the HTTP status on stderr).
"""
import argparse
import asyncio
import json
import sys

import websockets


async def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--run", type=int, required=True)
    p.add_argument("--token", default="")
    p.add_argument("--type", default="tiles")
    p.add_argument("--ready", required=True)
    p.add_argument("--timeout", type=float, default=20.0)
    a = p.parse_args()
    url = f"ws://127.0.0.1:{a.port}/live" + (f"?token={a.token}" if a.token else "")
    try:
        ws = await websockets.connect(url)
    except websockets.exceptions.InvalidStatusCode as e:
        print(e.status_code, file=sys.stderr)
        sys.exit(2)
    try:
        await ws.send(json.dumps({"subscribe": [a.run]}))
        await ws.recv()
        open(a.ready, "w").close()
        while True:
            m = json.loads(await asyncio.wait_for(ws.recv(), a.timeout))
            if m.get("type") == a.type:
                print(json.dumps(m))
                return
    except asyncio.TimeoutError:
        sys.exit(1)
    finally:
        await ws.close()


if __name__ == "__main__":
    asyncio.run(main())
