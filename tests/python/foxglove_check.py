"""Reads a `latentam export --foxglove` file with the `mcap` package and
checks every message twice: against the JSON Schema the file carries
(`jsonschema`), and by building Foxglove's own published message types
from it (`foxglove-sdk`: an unknown field, a wrong type or an unknown
numeric type fails). Prints a JSON summary for the Rust test to compare
with the map.

usage: foxglove_check.py FILE
"""

import base64
import json
import struct
import sys

import foxglove.messages as fm
import jsonschema
from mcap.reader import make_reader

NUMERIC_TYPES = {
    int(getattr(fm.PackedElementFieldNumericType, name)): getattr(
        fm.PackedElementFieldNumericType, name
    )
    for name in [
        "Unknown",
        "Uint8",
        "Int8",
        "Uint16",
        "Int16",
        "Uint32",
        "Int32",
        "Float32",
        "Float64",
    ]
}
FORMATS = {"Uint8": "B", "Float32": "<f"}


def timestamp(t):
    return fm.Timestamp(**t)


def pose(p):
    return fm.Pose(
        position=fm.Vector3(**p["position"]),
        orientation=fm.Quaternion(**p["orientation"]),
    )


def point_cloud(m):
    convert = {
        "timestamp": timestamp,
        "frame_id": str,
        "pose": pose,
        "point_stride": int,
        "fields": lambda fs: [
            fm.PackedElementField(
                name=f["name"], offset=f["offset"], type=NUMERIC_TYPES[f["type"]]
            )
            for f in fs
        ],
        "data": base64.b64decode,
    }
    return fm.PointCloud(**{k: convert[k](v) for k, v in m.items()})


def poses_in_frame(m):
    convert = {
        "timestamp": timestamp,
        "frame_id": str,
        "poses": lambda ps: [pose(p) for p in ps],
    }
    return fm.PosesInFrame(**{k: convert[k](v) for k, v in m.items()})


def pose_in_frame(m):
    convert = {"timestamp": timestamp, "frame_id": str, "pose": pose}
    return fm.PoseInFrame(**{k: convert[k](v) for k, v in m.items()})


def raw_image(m):
    convert = {
        "timestamp": timestamp,
        "frame_id": str,
        "width": int,
        "height": int,
        "encoding": str,
        "step": int,
        "data": base64.b64decode,
    }
    return fm.RawImage(**{k: convert[k](v) for k, v in m.items()})


BUILDERS = {
    "foxglove.PointCloud": point_cloud,
    "foxglove.PosesInFrame": poses_in_frame,
    "foxglove.PoseInFrame": pose_in_frame,
    "foxglove.RawImage": raw_image,
}


def unpack(m):
    """Every point of a cloud as {field: value}."""
    data = base64.b64decode(m["data"])
    stride = m["point_stride"]
    points = []
    for start in range(0, len(data), stride):
        point = {}
        for f in m["fields"]:
            kind = str(NUMERIC_TYPES[f["type"]]).split(".")[-1]
            (point[f["name"]],) = struct.unpack_from(FORMATS[kind], data, start + f["offset"])
        points.append(point)
    return points


def main(path):
    summary = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            assert schema.encoding == "jsonschema", schema.encoding
            assert channel.message_encoding == "json", channel.message_encoding
            m = json.loads(message.data)
            jsonschema.validate(m, json.loads(schema.data))
            built = BUILDERS[schema.name](m)
            built.encode()
            entry = {"schema": schema.name, "frame_id": m["frame_id"], "log_time": message.log_time}
            if schema.name == "foxglove.PointCloud":
                assert len(base64.b64decode(m["data"])) % m["point_stride"] == 0
                entry["points"] = unpack(m)
            else:
                entry["poses"] = [
                    [p["position"][a] for a in "xyz"] + [p["orientation"][a] for a in "xyzw"]
                    for p in m["poses"]
                ]
            assert channel.topic not in summary, f"two messages on {channel.topic}"
            summary[channel.topic] = entry
    json.dump(summary, sys.stdout)


if __name__ == "__main__":
    main(sys.argv[1])
