"""Reads a `latentam export --foxglove` file with the `mcap` package and
checks every message twice: it decodes it with Google's `protobuf` runtime
from the schema the file carries (a FileDescriptorSet), then builds
Foxglove's own published message type from what it decoded (`foxglove-sdk`)
and requires that type to encode to the very bytes in the file (an unknown
field, a wrong type, a wrong tag or an unknown numeric type fails). Prints
a JSON summary for the Rust test to compare with the map.

usage: foxglove_check.py FILE
"""

import json
import struct
import sys

import foxglove.messages as fm
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
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


def message_class(schema_name, encoding, data):
    """The protobuf class of `schema_name`, from the FileDescriptorSet
    `data` that a file or channel carries (not from foxglove-sdk)."""
    assert encoding == "protobuf", encoding
    files = list(descriptor_pb2.FileDescriptorSet.FromString(data).file)
    pool = descriptor_pool.DescriptorPool()
    # A file's dependencies first, in whatever order the set lists them.
    while files:
        added = [f for f in files if all(_has(pool, d) for d in f.dependency)]
        assert added, f"unresolved imports in the schema of {schema_name}"
        for f in added:
            pool.Add(f)
        files = [f for f in files if f not in added]
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def _has(pool, name):
    try:
        pool.FindFileByName(name)
        return True
    except KeyError:
        return False


def timestamp(t):
    # google.protobuf.Timestamp on the wire.
    return fm.Timestamp(sec=t.seconds, nsec=t.nanos)


def pose(p):
    return fm.Pose(
        position=fm.Vector3(x=p.position.x, y=p.position.y, z=p.position.z),
        orientation=fm.Quaternion(
            x=p.orientation.x, y=p.orientation.y, z=p.orientation.z, w=p.orientation.w
        ),
    )


def point_cloud(m):
    return fm.PointCloud(
        timestamp=timestamp(m.timestamp),
        frame_id=m.frame_id,
        pose=pose(m.pose),
        point_stride=m.point_stride,
        fields=[
            fm.PackedElementField(name=f.name, offset=f.offset, type=NUMERIC_TYPES[f.type])
            for f in m.fields
        ],
        data=m.data,
    )


def poses_in_frame(m):
    return fm.PosesInFrame(
        timestamp=timestamp(m.timestamp),
        frame_id=m.frame_id,
        poses=[pose(p) for p in m.poses],
    )


def pose_in_frame(m):
    return fm.PoseInFrame(timestamp=timestamp(m.timestamp), frame_id=m.frame_id, pose=pose(m.pose))


def raw_image(m):
    return fm.RawImage(
        timestamp=timestamp(m.timestamp),
        frame_id=m.frame_id,
        width=m.width,
        height=m.height,
        encoding=m.encoding,
        step=m.step,
        data=m.data,
    )


BUILDERS = {
    "foxglove.PointCloud": point_cloud,
    "foxglove.PosesInFrame": poses_in_frame,
    "foxglove.PoseInFrame": pose_in_frame,
    "foxglove.RawImage": raw_image,
}


def decode_and_check(schema_name, cls, data):
    """The message `data` decoded by `cls`, after checking that
    foxglove-sdk's own type, built from it, encodes to the same bytes."""
    m = cls.FromString(data)
    again = BUILDERS[schema_name](m).encode()
    assert again == data, f"{schema_name}: foxglove-sdk encodes it otherwise"
    return m


def unpack(m):
    """Every point of a cloud as {field: value}."""
    points = []
    for start in range(0, len(m.data), m.point_stride):
        point = {}
        for f in m.fields:
            kind = str(NUMERIC_TYPES[f.type]).split(".")[-1]
            (point[f.name],) = struct.unpack_from(FORMATS[kind], m.data, start + f.offset)
        points.append(point)
    return points


def pose_list(p):
    return [p.position.x, p.position.y, p.position.z] + [
        p.orientation.x,
        p.orientation.y,
        p.orientation.z,
        p.orientation.w,
    ]


def main(path):
    summary = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        classes = {}
        for schema, channel, message in reader.iter_messages():
            assert channel.message_encoding == "protobuf", channel.message_encoding
            if schema.id not in classes:
                classes[schema.id] = message_class(schema.name, schema.encoding, schema.data)
            m = decode_and_check(schema.name, classes[schema.id], message.data)
            entry = {"schema": schema.name, "frame_id": m.frame_id, "log_time": message.log_time}
            if schema.name == "foxglove.PointCloud":
                assert len(m.data) % m.point_stride == 0
                entry["points"] = unpack(m)
                entry["point_stride"] = m.point_stride
            else:
                entry["poses"] = [pose_list(p) for p in m.poses]
            assert channel.topic not in summary, f"two messages on {channel.topic}"
            summary[channel.topic] = entry
    json.dump(summary, sys.stdout)


if __name__ == "__main__":
    main(sys.argv[1])
