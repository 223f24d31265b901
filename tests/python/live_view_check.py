"""A Foxglove WebSocket client for `latentam map --live`: connects (retrying
until the server is up), subscribes to every advertised channel, and checks
each message as `foxglove_check.py` checks a file: against the JSON Schema
the channel advertises (`jsonschema`) and by building Foxglove's own
published message type from it (`foxglove-sdk`). Prints a JSON summary per
topic (messages, the last message's size and content digest) for the Rust
test to compare with the map the run saved.

usage: live_view_check.py URL TOPIC... (waits until every TOPIC got a message)
"""

import asyncio
import base64
import json
import struct
import sys
import time

import jsonschema
import websockets

from foxglove_check import BUILDERS, unpack

# The Foxglove SDK server speaks the WebSocket protocol under this name.
PROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01


async def connect(url, deadline):
    while True:
        try:
            return await websockets.connect(
                url, subprotocols=[PROTOCOL], max_size=None, open_timeout=5
            )
        except (OSError, websockets.exceptions.InvalidHandshake):
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.1)


def summarise(schema_name, m):
    entry = {"schema": schema_name, "frame_id": m["frame_id"]}
    if schema_name == "foxglove.PointCloud":
        entry["points"] = unpack(m)
        entry["fields"] = [f["name"] for f in m["fields"]]
    elif schema_name == "foxglove.PosesInFrame":
        entry["poses"] = [
            [p["position"][a] for a in "xyz"] + [p["orientation"][a] for a in "xyzw"]
            for p in m["poses"]
        ]
    elif schema_name == "foxglove.PoseInFrame":
        p = m["pose"]
        entry["pose"] = [p["position"][a] for a in "xyz"] + [p["orientation"][a] for a in "xyzw"]
    elif schema_name == "foxglove.RawImage":
        data = base64.b64decode(m["data"])
        assert len(data) == m["step"] * m["height"], (len(data), m["step"], m["height"])
        entry["size"] = [m["width"], m["height"]]
        entry["encoding"] = m["encoding"]
        entry["mean"] = sum(data) / max(len(data), 1)
    return entry


async def main(url, wanted):
    deadline = time.monotonic() + 120
    ws = await connect(url, deadline)
    channels = {}
    subscriptions = {}
    summary = {}
    server_info = None
    next_id = 1
    while not all(t in summary for t in wanted):
        if time.monotonic() > deadline:
            missing = [t for t in wanted if t not in summary]
            raise SystemExit(f"no message on {missing} within the deadline")
        try:
            frame = await asyncio.wait_for(ws.recv(), timeout=5)
        except asyncio.TimeoutError:
            continue
        if isinstance(frame, str):
            op = json.loads(frame)
            if op["op"] == "serverInfo":
                server_info = op
            elif op["op"] == "advertise":
                new = []
                for c in op["channels"]:
                    channels[c["id"]] = c
                    assert c["encoding"] == "json", c
                    assert c["schemaEncoding"] == "jsonschema", c
                    subscriptions[next_id] = c
                    new.append({"id": next_id, "channelId": c["id"]})
                    next_id += 1
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            continue
        assert frame[0] == MESSAGE_DATA, frame[0]
        sub, stamp = struct.unpack_from("<IQ", frame, 1)
        channel = subscriptions[sub]
        m = json.loads(frame[13:])
        jsonschema.validate(m, json.loads(channel["schema"]))
        BUILDERS[channel["schemaName"]](m).encode()
        entry = summarise(channel["schemaName"], m)
        entry["stamp"] = stamp
        entry["bytes"] = len(frame) - 13
        entry["messages"] = summary.get(channel["topic"], {}).get("messages", 0) + 1
        summary[channel["topic"]] = entry
    await ws.close()
    json.dump({"server": server_info["name"] if server_info else None, "topics": summary}, sys.stdout)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2:]))
