#!/usr/bin/env python3
"""Cross-check latentam's hand-written ROS 2 CDR code against an independent one.

The engine reads and writes ROS 2 messages in MCAP logs with its own CDR
serialiser.  Round-tripping through that same code cannot catch a mistake that
is made symmetrically on both sides (a field in the wrong place, a wrong
alignment rule, a wrong schema text), so the Rust tests call this script,
which uses the ``mcap`` / ``mcap-ros2-support`` Python packages instead:

``write OUT.mcap``
    Writes one message on each topic listed in ``MESSAGES`` below and the
    expected decoded values to ``OUT.json`` (same stem).  The Rust side reads
    the log and compares what it decodes with the JSON.

``read IN.mcap``
    Decodes every message of a log (normally written by the Rust side) and
    prints it as JSON on stdout, in file order.  For the message types known
    here, the payload is decoded with this script's own definitions; the
    schema text stored in the log must describe the same fields, and (unless
    ``--no-byte-check``) encoding the decoded values again must reproduce the
    payload byte for byte, so stray padding or trailing bytes are caught too.
    ``--file-schema`` decodes with the log's schema texts instead.

``selftest``
    Runs ``write`` then ``read`` in a temporary directory and checks that the
    two JSON documents agree.

The standard message definitions below are written here from the ROS 2
interface definitions, independently of the Rust sources; the engine's own
types are read from ``engine/msg/latentam_msgs/msg/*.msg``.

JSON layout (both for ``OUT.json`` and for the output of ``read``)::

    {"messages": [
        {"topic": "/pose", "schema": "geometry_msgs/msg/PoseStamped",
         "log_time": 1700000000100000000,
         "fields": {"header": {"stamp": {"sec": 1700000000, "nanosec": 100000001},
                               "frame_id": "map"},
                    "pose": {...}}},
        ...]}

``fields`` holds every field of the message, keyed by its ROS name, in
definition order: nested messages are objects, ``uint8[]`` / ``byte[]``
arrays (fixed or not) are lowercase hex strings, every other array is a JSON
list, integers are JSON integers, booleans are JSON booleans, floats are
JSON numbers (``float32`` values are written as the exact double they widen
to), strings are JSON strings.  Non-finite floats are an error.

Exit status: 0 on success, 1 on any failure (message on stderr), 2 for a
usage error, 3 when the Python packages are missing.
"""

import argparse
import io
import json
import math
import re
import struct
import sys
import tempfile
from pathlib import Path

try:
    from mcap.reader import NonSeekingReader, make_reader
    from mcap.records import Schema
    from mcap.writer import CompressionType
    from mcap_ros2.decoder import DecoderFactory
    from mcap_ros2.writer import Writer
except ImportError as import_error:  # pragma: no cover - depends on the host
    sys.stderr.write(
        f"ros2_cross_check: cannot import the MCAP packages ({import_error}).\n"
        "Install them with: pip install mcap==1.6.0 mcap-ros2-support==0.6.0\n"
    )
    sys.exit(3)

REPO_ROOT = Path(__file__).resolve().parents[2]
ENGINE_MSG_DIR = REPO_ROOT / "engine" / "msg" / "latentam_msgs" / "msg"
ENGINE_TYPES = ("MaskFeatures", "FeatureGrid", "TextEmbeddings")
SEPARATOR = "=" * 80


class CheckError(Exception):
    """A failure worth reporting to the caller in one line."""


# ---------------------------------------------------------------------------
# Message definitions
# ---------------------------------------------------------------------------

# Standard ROS 2 types, keyed by "pkg/Type".  Nested types are always spelled
# with their package so each text stands on its own.
STANDARD_DEFINITIONS = {
    "builtin_interfaces/Time": """
int32 sec
uint32 nanosec
""",
    "std_msgs/Header": """
builtin_interfaces/Time stamp
string frame_id
""",
    "sensor_msgs/Image": """
std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data
""",
    "sensor_msgs/CompressedImage": """
std_msgs/Header header
string format
uint8[] data
""",
    "sensor_msgs/RegionOfInterest": """
uint32 x_offset
uint32 y_offset
uint32 height
uint32 width
bool do_rectify
""",
    "sensor_msgs/CameraInfo": """
std_msgs/Header header
uint32 height
uint32 width
string distortion_model
float64[] d
float64[9] k
float64[9] r
float64[12] p
uint32 binning_x
uint32 binning_y
sensor_msgs/RegionOfInterest roi
""",
    "geometry_msgs/Point": """
float64 x
float64 y
float64 z
""",
    "geometry_msgs/Quaternion": """
float64 x 0
float64 y 0
float64 z 0
float64 w 1
""",
    "geometry_msgs/Pose": """
geometry_msgs/Point position
geometry_msgs/Quaternion orientation
""",
    "geometry_msgs/PoseStamped": """
std_msgs/Header header
geometry_msgs/Pose pose
""",
    "geometry_msgs/PoseWithCovariance": """
geometry_msgs/Pose pose
float64[36] covariance
""",
    "geometry_msgs/Vector3": """
float64 x
float64 y
float64 z
""",
    "geometry_msgs/Twist": """
geometry_msgs/Vector3 linear
geometry_msgs/Vector3 angular
""",
    "geometry_msgs/TwistWithCovariance": """
geometry_msgs/Twist twist
float64[36] covariance
""",
    "geometry_msgs/Transform": """
geometry_msgs/Vector3 translation
geometry_msgs/Quaternion rotation
""",
    "geometry_msgs/TransformStamped": """
std_msgs/Header header
string child_frame_id
geometry_msgs/Transform transform
""",
    "nav_msgs/Odometry": """
std_msgs/Header header
string child_frame_id
geometry_msgs/PoseWithCovariance pose
geometry_msgs/TwistWithCovariance twist
""",
    "tf2_msgs/TFMessage": """
geometry_msgs/TransformStamped[] transforms
""",
}


def own_definitions():
    """All definitions this script knows: the standard ones and the engine's."""
    defs = {name: text.strip() + "\n" for name, text in STANDARD_DEFINITIONS.items()}
    for name in ENGINE_TYPES:
        path = ENGINE_MSG_DIR / f"{name}.msg"
        try:
            defs[f"latentam_msgs/{name}"] = path.read_text(encoding="utf-8")
        except OSError as err:
            raise CheckError(f"cannot read the engine message definition {path}: {err}")
    return defs


PRIMITIVE_TYPES = {
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
    "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring",
}
FLOAT_TYPES = {"float32", "float64"}
BYTE_TYPES = {"uint8", "byte"}

TYPE_RE = re.compile(
    r"^(?P<base>[A-Za-z][A-Za-z0-9_/]*)(?P<bound><=\d+)?(?P<array>\[(?:<=)?\d*\])?$"
)


def short_name(name):
    """Normalise "pkg/msg/Type" or "pkg/Type" to "pkg/Type"."""
    parts = name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return f"{parts[0]}/{parts[2]}"
    if len(parts) == 2:
        return name
    raise CheckError(f"malformed message type name {name!r}")


class Field:
    """One field of a message definition (constants are not kept)."""

    __slots__ = ("name", "base", "bound", "array")

    def __init__(self, name, base, bound, array):
        self.name = name
        self.base = base  # a primitive name, or "pkg/Type"
        self.bound = bound  # "<=N" for bounded strings, else ""
        self.array = array  # None for a scalar, else "[]", "[N]" or "[<=N]"

    @property
    def primitive(self):
        return self.base in PRIMITIVE_TYPES

    @property
    def fixed_length(self):
        if self.array and self.array[1:-1].isdigit():
            return int(self.array[1:-1])
        return None

    def signature(self):
        return f"{self.base}{self.bound}{self.array or ''} {self.name}"


def parse_definition(type_name, text):
    """Parses the fields of one message definition of type "pkg/Type"."""
    package = type_name.split("/")[0]
    fields = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split(None, 1)
        if len(parts) != 2:
            raise CheckError(f"{type_name}: line {number}: cannot parse {raw!r}")
        type_text, rest = parts
        if "=" in rest:
            continue  # a constant
        name = rest.split()[0]
        match = TYPE_RE.match(type_text)
        if match is None:
            raise CheckError(f"{type_name}: line {number}: bad type {type_text!r}")
        base = match.group("base")
        if base not in PRIMITIVE_TYPES:
            if "/" in base:
                base = short_name(base)
            elif base == "Header":
                base = "std_msgs/Header"
            else:
                base = f"{package}/{base}"
        fields.append(Field(name, base, match.group("bound") or "", match.group("array")))
    return fields


def parse_schema_text(root_name, text):
    """Splits a rosbag2-style schema text into {"pkg/Type": [Field, ...]}."""
    sections = re.split(r"^={3,}[ \t]*$", text, flags=re.MULTILINE)
    result = {}
    for index, section in enumerate(sections):
        name = short_name(root_name) if index == 0 else None
        lines = []
        for line in section.splitlines():
            match = re.match(r"^MSG:\s*(\S+)\s*$", line)
            if match:
                name = short_name(match.group(1))
            else:
                lines.append(line)
        if name is None:
            raise CheckError(f"schema {root_name}: section {index} has no 'MSG:' line")
        result[name] = parse_definition(name, "\n".join(lines))
    return result


def dependencies(root, defs):
    """The nested types of `root`, depth first, each once, in first-use order."""
    parsed = {}
    order = []

    def visit(name):
        if name not in defs:
            raise CheckError(f"no definition for message type {name}")
        fields = parsed.setdefault(name, parse_definition(name, defs[name]))
        for field in fields:
            if not field.primitive and field.base not in parsed:
                order.append(field.base)
                visit(field.base)

    visit(root)
    return order


def schema_text(full_name, defs):
    """The schema text of a type: its definition, then each dependency's."""
    root = short_name(full_name)
    chunks = [defs[root].rstrip("\n")]
    for dep in dependencies(root, defs):
        chunks.append(f"{SEPARATOR}\nMSG: {dep}\n{defs[dep].rstrip(chr(10))}")
    return "\n".join(chunks) + "\n"


def compare_schemas(full_name, ours, theirs):
    """Checks that the log's schema text describes the same fields as ours."""
    root = short_name(full_name)
    mine = parse_schema_text(full_name, ours)
    other = parse_schema_text(full_name, theirs)
    for name in [root] + [n for n in mine if n != root]:
        if name not in other:
            raise CheckError(f"schema {full_name}: the log's schema text has no definition of {name}")
        want = [f.signature() for f in mine[name]]
        got = [f.signature() for f in other[name]]
        if want != got:
            raise CheckError(
                f"schema {full_name}: fields of {name} differ: expected {want}, log has {got}"
            )


# ---------------------------------------------------------------------------
# Rendering messages as JSON-ready values
# ---------------------------------------------------------------------------


def _get(message, name, where):
    if isinstance(message, dict):
        if name not in message:
            raise CheckError(f"{where}: field {name!r} is missing")
        return message[name]
    if not hasattr(message, name):
        raise CheckError(f"{where}: field {name!r} is missing")
    return getattr(message, name)


def _scalar(value, base, where):
    if base in FLOAT_TYPES:
        value = float(value)
        if not math.isfinite(value):
            raise CheckError(f"{where}: non-finite float {value!r} cannot be written as JSON")
        return value
    if base == "bool":
        if value not in (0, 1, True, False):
            raise CheckError(f"{where}: bool holds {value!r}")
        return bool(value)
    if base in ("string", "wstring"):
        return str(value)
    return int(value)


def render(message, type_name, schema, where):
    """Renders `message` (a dict or a decoded object) field by field."""
    out = {}
    for field in schema[type_name]:
        here = f"{where}.{field.name}"
        value = _get(message, field.name, where)
        if field.array is not None:
            length = field.fixed_length
            if length is not None and len(value) != length:
                raise CheckError(f"{here}: expected {length} elements, got {len(value)}")
            if field.base in BYTE_TYPES:
                out[field.name] = bytes(value).hex()
            elif field.primitive:
                out[field.name] = [_scalar(v, field.base, here) for v in value]
            else:
                out[field.name] = [
                    render(v, field.base, schema, f"{here}[{i}]") for i, v in enumerate(value)
                ]
        elif field.primitive:
            out[field.name] = _scalar(value, field.base, here)
        else:
            out[field.name] = render(value, field.base, schema, here)
    return out


def full_schema(full_name, defs):
    root = short_name(full_name)
    return {name: parse_definition(name, defs[name]) for name in [root] + dependencies(root, defs)}


# ---------------------------------------------------------------------------
# The messages written by `write`
# ---------------------------------------------------------------------------

BASE_TIME_NS = 1_700_000_000_000_000_000


def stamp(k):
    """A distinct, non-zero stamp with nanoseconds for message `k`."""
    return {"sec": 1_700_000_000 + k, "nanosec": 123_456_789 + 1_000 * k + k}


def header(k, frame_id):
    return {"stamp": stamp(k), "frame_id": frame_id}


def quaternion(x, y, z, w):
    return {"x": x, "y": y, "z": z, "w": w}


def vector(x, y, z):
    return {"x": x, "y": y, "z": z}


# Floats are dyadic fractions so that every JSON parser reads them back exactly.
MESSAGES = [
    (
        "/image",
        "sensor_msgs/msg/Image",
        {
            "header": header(1, "rgb_optical"),
            "height": 2,
            "width": 3,
            "encoding": "rgb8",
            "is_bigendian": 0,
            "step": 9,
            "data": bytes((17 * i + 3) % 256 for i in range(18)),
        },
    ),
    (
        "/compressed",
        "sensor_msgs/msg/CompressedImage",
        {
            "header": header(2, "cam"),
            "format": "jpeg",
            "data": bytes([0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x10, 0x4A]),
        },
    ),
    (
        "/camera_info",
        "sensor_msgs/msg/CameraInfo",
        {
            "header": header(3, "rgb_optical"),
            "height": 480,
            "width": 640,
            "distortion_model": "plumb_bob",
            "d": [-0.25, 0.125, -0.001953125, 0.0009765625, -0.03125],
            "k": [525.5, 0.0, 319.75, 0.0, 526.25, 239.5, 0.0, 0.0, 1.0],
            "r": [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            "p": [525.5, 0.0, 319.75, -37.5, 0.0, 526.25, 239.5, 0.0, 0.0, 0.0, 1.0, 0.0],
            "binning_x": 2,
            "binning_y": 1,
            "roi": {"x_offset": 5, "y_offset": 7, "height": 301, "width": 401, "do_rectify": True},
        },
    ),
    (
        "/pose",
        "geometry_msgs/msg/PoseStamped",
        {
            "header": header(4, "map"),
            "pose": {
                "position": vector(1.5, -2.25, 0.375),
                "orientation": quaternion(0.5, -0.5, 0.5, 0.5),
            },
        },
    ),
    (
        "/odom",
        "nav_msgs/msg/Odometry",
        {
            "header": header(5, "world"),
            "child_frame_id": "base_link",
            "pose": {
                "pose": {
                    "position": vector(-3.125, 4.5, 0.0625),
                    "orientation": quaternion(0.5, 0.5, -0.5, 0.5),
                },
                "covariance": [0.25 * i - 4.5 for i in range(36)],
            },
            "twist": {
                "twist": {"linear": vector(0.75, -0.125, 0.0), "angular": vector(0.0, 0.0, -1.25)},
                "covariance": [0.5 * (i % 7) - 1.0 for i in range(36)],
            },
        },
    ),
    (
        "/tf",
        "tf2_msgs/msg/TFMessage",
        {
            "transforms": [
                {
                    "header": header(6, "map"),
                    "child_frame_id": "base_link",
                    "transform": {
                        "translation": vector(0.5, -1.75, 2.0),
                        "rotation": quaternion(0.0, 0.0, -0.5, 0.5),
                    },
                },
                {
                    "header": header(7, "base_link"),
                    "child_frame_id": "rgb_optical",
                    "transform": {
                        "translation": vector(-0.0625, 0.125, -0.25),
                        "rotation": quaternion(-0.5, 0.5, -0.5, 0.5),
                    },
                },
            ]
        },
    ),
    (
        "/mask",
        "latentam_msgs/msg/MaskFeatures",
        {
            "header": header(8, "rgb_optical"),
            "height": 2,
            "width": 3,
            "labels": [0, 1, 65535, 1, 0, 65535],
            "count": 2,
            "dim": 3,
            "dtype": "f16",
            "data": struct.pack("<6e", 0.5, -1.0, 0.25, 1.5, -0.125, 2.0),
            "model": "clip-test",
        },
    ),
    (
        "/grid",
        "latentam_msgs/msg/FeatureGrid",
        {
            "header": header(9, "rgb_optical"),
            "rows": 1,
            "cols": 2,
            "dim": 2,
            "dtype": "f32",
            "data": struct.pack("<4f", 0.5, -1.5, 3.25, -0.0625),
            "model": "lseg-test",
        },
    ),
    (
        "/vocab",
        "latentam_msgs/msg/TextEmbeddings",
        {
            "header": header(10, "map"),
            "names": ["chair", "table lamp", "x"],
            "ids": [1, 2, 3],
            "dim": 2,
            "dtype": "f32",
            "data": struct.pack("<6f", 1.0, 0.0, -0.75, 0.5, 0.125, -2.0),
            "model": "clip-test",
        },
    ),
]


def log_time(index):
    return BASE_TIME_NS + 100_000_000 * (index + 1) + 7 * index + 1


def expected_document(defs):
    messages = []
    for index, (topic, full_name, value) in enumerate(MESSAGES):
        schema = full_schema(full_name, defs)
        messages.append(
            {
                "topic": topic,
                "schema": full_name,
                "log_time": log_time(index),
                "fields": render(value, short_name(full_name), schema, topic),
            }
        )
    return {"messages": messages}


COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


def write_log(out_path, compression="zstd"):
    """Writes the test log and its JSON; returns the expected document."""
    out_path = Path(out_path)
    defs = own_definitions()
    expected = expected_document(defs)
    with open(out_path, "wb") as stream:
        writer = Writer(stream, compression=COMPRESSIONS[compression])
        registered = {}
        for index, (topic, full_name, value) in enumerate(MESSAGES):
            if full_name not in registered:
                registered[full_name] = writer.register_msgdef(full_name, schema_text(full_name, defs))
            writer.write_message(
                topic, registered[full_name], value, log_time=log_time(index), publish_time=log_time(index)
            )
        writer.finish()
    json_path = out_path.with_suffix(".json")
    json_path.write_text(json.dumps(expected, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return expected


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------


def encode(full_name, text, message):
    """CDR payload of `message`, encoded by mcap_ros2 with the given schema text."""
    buffer = io.BytesIO()
    writer = Writer(buffer, compression=CompressionType.NONE)
    schema = writer.register_msgdef(full_name, text)
    writer.write_message("/encode", schema, message, log_time=0)
    writer.finish()
    buffer.seek(0)
    for _, _, record in make_reader(buffer).iter_messages():
        return record.data
    raise CheckError("re-encoding produced no message")


def first_difference(a, b):
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return i
    return min(len(a), len(b))


def read_log(in_path, file_schema=False, byte_check=True):
    """Decodes every message of a log; returns the JSON document."""
    defs = own_definitions()
    factory = DecoderFactory()
    decoders = {}  # schema id in the log -> (decode function, schema text used, parsed schema)
    messages = []
    with open(in_path, "rb") as stream:
        reader = NonSeekingReader(stream, validate_crcs=True)
        for index, (schema, channel, record) in enumerate(reader.iter_messages(log_time_order=False)):
            where = f"message {index} on {channel.topic}"
            if schema is None:
                raise CheckError(f"{where}: the channel has no schema")
            if channel.message_encoding != "cdr":
                raise CheckError(f"{where}: message encoding is {channel.message_encoding!r}, not 'cdr'")
            if schema.encoding != "ros2msg":
                raise CheckError(f"{where}: schema encoding is {schema.encoding!r}, not 'ros2msg'")
            if schema.id not in decoders:
                theirs = schema.data.decode("utf-8")
                root = short_name(schema.name)
                if root in defs and not file_schema:
                    text = schema_text(schema.name, defs)
                    compare_schemas(schema.name, text, theirs)
                else:
                    text = theirs
                # A private id space: each text gets its own decoder.
                own = Schema(id=len(decoders) + 1, data=text.encode("utf-8"), encoding="ros2msg", name=schema.name)
                decoders[schema.id] = (
                    factory.decoder_for("cdr", own),
                    text,
                    parse_schema_text(schema.name, text),
                )
            decode, text, parsed = decoders[schema.id]
            try:
                decoded = decode(record.data)
            except Exception as err:  # the decoder raises assorted types
                raise CheckError(f"{where}: cannot decode the {schema.name} payload: {err!r}")
            if byte_check:
                again = encode(schema.name, text, decoded)
                if again != record.data and record.data.startswith(again):
                    raise CheckError(
                        f"{where}: the {schema.name} payload has {len(record.data) - len(again)} "
                        f"trailing byte(s) after the last field"
                    )
                if again != record.data:
                    at = first_difference(again, record.data)
                    raise CheckError(
                        f"{where}: the {len(record.data)}-byte payload differs from the "
                        f"{len(again)}-byte re-encoding of its decoded values, first at byte {at} "
                        f"(log: {record.data[at:at + 8].hex()}, expected: {again[at:at + 8].hex()})"
                    )
            messages.append(
                {
                    "topic": channel.topic,
                    "schema": schema.name,
                    "log_time": record.log_time,
                    "fields": render(decoded, short_name(schema.name), parsed, channel.topic),
                }
            )
    return {"messages": messages}


# ---------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------


def selftest():
    with tempfile.TemporaryDirectory() as tmp:
        for compression in COMPRESSIONS:
            path = Path(tmp) / f"selftest-{compression}.mcap"
            write_log(path, compression)
            expected = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
            got = json.loads(json.dumps(read_log(path), allow_nan=False))
            if got != expected:
                for want, have in zip(expected["messages"], got["messages"]):
                    if want != have:
                        raise CheckError(
                            f"selftest ({compression}): {want['topic']} reads back differently:\n"
                            f"expected {json.dumps(want)}\ngot      {json.dumps(have)}"
                        )
                raise CheckError(
                    f"selftest ({compression}): wrote {len(expected['messages'])} messages, "
                    f"read {len(got['messages'])}"
                )
    print(f"selftest ok: {len(MESSAGES)} messages, compressions {', '.join(COMPRESSIONS)}")


def main(argv=None):
    parser = argparse.ArgumentParser(
        description="Cross-check latentam's ROS 2 CDR encoding against mcap-ros2-support."
    )
    commands = parser.add_subparsers(dest="command", required=True)
    write = commands.add_parser("write", help="write the reference log OUT.mcap and OUT.json")
    write.add_argument("out", help="path of the .mcap file to write; the JSON goes next to it")
    write.add_argument(
        "--compression", choices=sorted(COMPRESSIONS), default="zstd", help="chunk compression (default zstd)"
    )
    read = commands.add_parser("read", help="decode a log and print its messages as JSON")
    read.add_argument("path", help="the .mcap file to read")
    read.add_argument(
        "--file-schema",
        action="store_true",
        help="decode with the schema texts stored in the log instead of this script's definitions",
    )
    read.add_argument(
        "--no-byte-check",
        action="store_true",
        help="do not require the payload to equal the re-encoding of its decoded values",
    )
    commands.add_parser("selftest", help="write then read in a temporary directory and compare")
    args = parser.parse_args(argv)

    try:
        if args.command == "write":
            expected = write_log(args.out, args.compression)
            print(f"wrote {len(expected['messages'])} messages to {args.out}")
        elif args.command == "read":
            document = read_log(args.path, file_schema=args.file_schema, byte_check=not args.no_byte_check)
            json.dump(document, sys.stdout, indent=2, allow_nan=False)
            sys.stdout.write("\n")
        else:
            selftest()
    except CheckError as err:
        sys.stderr.write(f"ros2_cross_check: {err}\n")
        return 1
    except Exception as err:  # anything from the MCAP libraries or the file system
        sys.stderr.write(f"ros2_cross_check: {type(err).__name__}: {err}\n")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
