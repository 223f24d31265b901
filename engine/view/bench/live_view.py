"""Benchmark of the live view: maps one log twice with `latentam map`,
without a viewer and with `--live` and a Foxglove WebSocket client
subscribed to every topic for the whole run (`--repeats` times each,
alternated), and writes JSON: keyframes per second of every run, the
ratio of the medians, and what the view sent in the last run (bytes per
second and per message, by topic).

Run it in a network namespace that holds only loopback, so nothing leaves
the machine (as root):

    unshare --net sh -c 'ip link set lo up && \\
        python engine/view/bench/live_view.py --bin target/release/latentam \\
            --log scene.mcap --out bench-live-view --words chair'

Needs `websockets`. Settings not given keep the CLI's defaults (point
budget 100 000, one publication a second at most, renders 320 wide).
"""

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import threading
import time

import websockets

PROTOCOL = "foxglove.sdk.v1"


def mapped(report_path):
    with open(report_path) as f:
        r = json.load(f)
    return {
        "keyframes": r["keyframes"],
        "wall_s": r["wall_s"],
        "keyframes_per_s": r["keyframes_per_s"],
        "frames": r["frames"],
        "device": r["device"],
    }


class Client:
    """Subscribes to every channel and counts what arrives until the
    server closes."""

    def __init__(self, url):
        self.url = url
        self.topics = {}
        self.connected_at = None
        self.done = threading.Event()

    async def run(self):
        deadline = time.monotonic() + 600
        while True:
            try:
                ws = await websockets.connect(self.url, subprotocols=[PROTOCOL], max_size=None)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                await asyncio.sleep(0.05)
        self.connected_at = time.monotonic()
        subs, next_id = {}, 1
        try:
            async for frame in ws:
                if isinstance(frame, str):
                    op = json.loads(frame)
                    if op["op"] == "advertise":
                        new = []
                        for c in op["channels"]:
                            subs[next_id] = c["topic"]
                            new.append({"id": next_id, "channelId": c["id"]})
                            next_id += 1
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                    continue
                sub = int.from_bytes(frame[1:5], "little")
                t = self.topics.setdefault(subs[sub], {"messages": 0, "bytes": 0})
                t["messages"] += 1
                t["bytes"] += len(frame) - 13
        except websockets.exceptions.ConnectionClosed:
            pass
        self.done.set()


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--bin", required=True, help="the latentam binary")
    p.add_argument("--log", required=True, help="the log to map")
    p.add_argument("--out", required=True, help="folder for the runs and live_view.json")
    p.add_argument("--words", default="", help="relevance words, comma-separated")
    p.add_argument("--port", type=int, default=8765)
    p.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="runs of each kind, alternated (the medians are compared)",
    )
    p.add_argument("--extra", default="", help="more `latentam map` flags for both runs, space-separated")
    p.add_argument(
        "--view-flags",
        default="",
        help="more --live-* flags for the run with the view, space-separated",
    )
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    extra = a.extra.split()

    base = [a.bin, "map", a.log, "--autosave-every", "0", *extra]
    live = ["--live", f"127.0.0.1:{a.port}"] + (["--live-words", a.words] if a.words else [])
    live += a.view_flags.split()
    withouts, withs, clients = [], [], []
    # Alternated, so that a slow spell of the machine hits both kinds.
    for i in range(a.repeats):
        out = os.path.join(a.out, f"without-{i}")
        subprocess.run(base + ["--out", out], check=True)
        withouts.append(mapped(os.path.join(out, "report.json")))

        client = Client(f"ws://127.0.0.1:{a.port}")
        thread = threading.Thread(target=lambda: asyncio.run(client.run()), daemon=True)
        thread.start()
        started = time.monotonic()
        out = os.path.join(a.out, f"with-{i}")
        subprocess.run(base + ["--out", out, *live], check=True)
        ended = time.monotonic()
        client.done.wait(30)
        withs.append(mapped(os.path.join(out, "report.json")))
        clients.append((client, ended - (client.connected_at or started)))

    rate = lambda runs: statistics.median(r["keyframes_per_s"] for r in runs)
    client, seconds = clients[-1]
    total = sum(t["bytes"] for t in client.topics.values())
    result = {
        "log": a.log,
        "device": withouts[0]["device"],
        "flags": extra + live,
        "repeats": a.repeats,
        "without_view": withouts,
        "with_view_and_client": withs,
        "median_keyframes_per_s_without": rate(withouts),
        "median_keyframes_per_s_with": rate(withs),
        "keyframes_per_s_ratio": rate(withs) / rate(withouts),
        "client_seconds": seconds,
        "bytes_per_s": total / seconds if seconds > 0 else None,
        "topics": {
            k: dict(v, bytes_per_message=v["bytes"] / max(v["messages"], 1))
            for k, v in sorted(client.topics.items())
        },
    }
    with open(os.path.join(a.out, "live_view.json"), "w") as f:
        json.dump(result, f, indent=2)
    json.dump(result, sys.stdout, indent=2)
    print()


if __name__ == "__main__":
    main()
