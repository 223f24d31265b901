"""A Foxglove WebSocket client for `latentam map --live`: connects (retrying
until the server is up), subscribes to every advertised channel, and checks
each message as `foxglove_check.py` checks a file: decoded with Google's
`protobuf` runtime from the schema the channel advertises, then rebuilt as
Foxglove's own published message type (`foxglove-sdk`), which must encode
to the same bytes. Prints a JSON summary per topic (messages, the last
message's size and content digest) for the Rust test to compare with the
map the run saved.

usage: live_view_check.py URL TOPIC... (waits until every TOPIC got a message)
"""

import asyncio
import base64
import json
import struct
import sys
import time

import websockets

from foxglove_check import decode_and_check, message_class, pose_list, unpack

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
    entry = {"schema": schema_name, "frame_id": m.frame_id}
    if schema_name == "foxglove.PointCloud":
        entry["points"] = unpack(m)
        entry["fields"] = [f.name for f in m.fields]
        entry["point_stride"] = m.point_stride
    elif schema_name == "foxglove.PosesInFrame":
        entry["poses"] = [pose_list(p) for p in m.poses]
    elif schema_name == "foxglove.PoseInFrame":
        entry["pose"] = pose_list(m.pose)
    elif schema_name == "foxglove.RawImage":
        data = m.data
        assert len(data) == m.step * m.height, (len(data), m.step, m.height)
        entry["size"] = [m.width, m.height]
        entry["encoding"] = m.encoding
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
                    assert c["encoding"] == "protobuf", c
                    # A binary schema travels base64-encoded.
                    c["class"] = message_class(
                        c["schemaName"], c["schemaEncoding"], base64.b64decode(c["schema"])
                    )
                    channels[c["id"]] = c
                    subscriptions[next_id] = c
                    new.append({"id": next_id, "channelId": c["id"]})
                    next_id += 1
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            continue
        assert frame[0] == MESSAGE_DATA, frame[0]
        sub, stamp = struct.unpack_from("<IQ", frame, 1)
        channel = subscriptions[sub]
        m = decode_and_check(channel["schemaName"], channel["class"], frame[13:])
        entry = summarise(channel["schemaName"], m)
        entry["stamp"] = stamp
        entry["bytes"] = len(frame) - 13
        entry["messages"] = summary.get(channel["topic"], {}).get("messages", 0) + 1
        summary[channel["topic"]] = entry
    await ws.close()
    json.dump({"server": server_info["name"] if server_info else None, "topics": summary}, sys.stdout)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2:]))
