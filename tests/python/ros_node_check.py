"""Drives `latentam-ros` from an independent DDS implementation (Eclipse
Cyclone DDS, the `cyclonedds` package): publishes a log's messages as a
robot would (ROS 2 topic and type names, CDR, at the recorded rate),
waits until the node has mapped them, asks a relevance query, and prints
a JSON summary of what the node published: the map cloud, the keyframe
trajectory, the status, the query's relevance cloud, and the node's entry
in the ROS 2 graph (`ros_discovery_info`, its readers and writers matched
to the endpoints DDS discovery reports).

It also calls the node's services as a `rmw_cyclonedds_cpp` client does
(the request's fields after a 16-byte header of client id and sequence
number, which the reply carries back): a query, a query of the wrong
dimension, and a save into SAVE_DIR.

usage: ros_node_check.py LOG [--counts] [--save-dir SAVE_DIR]  (in a network
namespace holding only loopback; --counts gives point counts instead of
every point, for benchmarks)
"""

import json
import os
import struct
import sys
import time
import types
from dataclasses import dataclass

from cyclonedds.builtin import (
    BuiltinDataReader,
    BuiltinTopicDcpsPublication,
    BuiltinTopicDcpsSubscription,
)
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import (
    array,
    float64,
    int32,
    int64,
    sequence,
    uint8,
    uint16,
    uint32,
    uint64,
)
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from mcap.reader import make_reader


def typename(ros_type):
    pkg, _, name = ros_type.split("/")
    return f"{pkg}::msg::dds_::{name}_"


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Image(IdlStruct, typename=typename("sensor_msgs/msg/Image")):
    header: Header
    height: uint32
    width: uint32
    encoding: str
    is_bigendian: uint8
    step: uint32
    data: sequence[uint8]


@dataclass
class RegionOfInterest(IdlStruct, typename="sensor_msgs::msg::dds_::RegionOfInterest_"):
    x_offset: uint32
    y_offset: uint32
    height: uint32
    width: uint32
    do_rectify: bool


@dataclass
class CameraInfo(IdlStruct, typename=typename("sensor_msgs/msg/CameraInfo")):
    header: Header
    height: uint32
    width: uint32
    distortion_model: str
    d: sequence[float64]
    k: array[float64, 9]
    r: array[float64, 9]
    p: array[float64, 12]
    binning_x: uint32
    binning_y: uint32
    roi: RegionOfInterest


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseStamped(IdlStruct, typename=typename("geometry_msgs/msg/PoseStamped")):
    header: Header
    pose: Pose


@dataclass
class MaskFeatures(IdlStruct, typename=typename("latentam_msgs/msg/MaskFeatures")):
    header: Header
    height: uint32
    width: uint32
    labels: sequence[uint16]
    count: uint32
    dim: uint32
    dtype: str
    data: sequence[uint8]
    model: str


@dataclass
class TextEmbeddings(IdlStruct, typename=typename("latentam_msgs/msg/TextEmbeddings")):
    header: Header
    names: sequence[str]
    ids: sequence[uint16]
    dim: uint32
    dtype: str
    data: sequence[uint8]
    model: str


@dataclass
class PointField(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
    name: str
    offset: uint32
    datatype: uint8
    count: uint32


@dataclass
class PointCloud2(IdlStruct, typename=typename("sensor_msgs/msg/PointCloud2")):
    header: Header
    height: uint32
    width: uint32
    fields: sequence[PointField]
    is_bigendian: bool
    point_step: uint32
    row_step: uint32
    data: sequence[uint8]
    is_dense: bool


@dataclass
class Path(IdlStruct, typename=typename("nav_msgs/msg/Path")):
    header: Header
    poses: sequence[PoseStamped]


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]


@dataclass
class DiagnosticArray(IdlStruct, typename=typename("diagnostic_msgs/msg/DiagnosticArray")):
    header: Header
    status: sequence[DiagnosticStatus]


# Services as rmw_cyclonedds_cpp carries them: a header of client id and
# sequence number before the fields, echoed in the reply.
@dataclass
class QueryRequest(IdlStruct, typename="latentam_msgs::srv::dds_::Query_Request_"):
    client: uint64
    seq: int64
    query: TextEmbeddings


@dataclass
class QueryResponse(IdlStruct, typename="latentam_msgs::srv::dds_::Query_Response_"):
    client: uint64
    seq: int64
    success: bool
    message: str
    relevance: PointCloud2


@dataclass
class SaveRequest(IdlStruct, typename="latentam_msgs::srv::dds_::Save_Request_"):
    client: uint64
    seq: int64
    directory: str


@dataclass
class SaveResponse(IdlStruct, typename="latentam_msgs::srv::dds_::Save_Response_"):
    client: uint64
    seq: int64
    success: bool
    message: str


@dataclass
class ParameterValue(IdlStruct, typename="rcl_interfaces::msg::dds_::ParameterValue_"):
    type: uint8
    bool_value: bool
    integer_value: int64
    double_value: float64
    string_value: str
    byte_array_value: sequence[uint8]
    bool_array_value: sequence[bool]
    integer_array_value: sequence[int64]
    double_array_value: sequence[float64]
    string_array_value: sequence[str]


def parameter_value(**one):
    fields = dict(
        type=0, bool_value=False, integer_value=0, double_value=0.0, string_value="",
        byte_array_value=[], bool_array_value=[], integer_array_value=[],
        double_array_value=[], string_array_value=[],
    )
    fields.update(one)
    return ParameterValue(**fields)


@dataclass
class Parameter(IdlStruct, typename="rcl_interfaces::msg::dds_::Parameter_"):
    name: str
    value: ParameterValue


@dataclass
class SetParametersResult(IdlStruct, typename="rcl_interfaces::msg::dds_::SetParametersResult_"):
    successful: bool
    reason: str


@dataclass
class ListParametersResult(IdlStruct, typename="rcl_interfaces::msg::dds_::ListParametersResult_"):
    names: sequence[str]
    prefixes: sequence[str]


@dataclass
class FloatingPointRange(IdlStruct, typename="rcl_interfaces::msg::dds_::FloatingPointRange_"):
    from_value: float64
    to_value: float64
    step: float64


@dataclass
class IntegerRange(IdlStruct, typename="rcl_interfaces::msg::dds_::IntegerRange_"):
    from_value: int64
    to_value: int64
    step: uint64


@dataclass
class ParameterDescriptor(IdlStruct, typename="rcl_interfaces::msg::dds_::ParameterDescriptor_"):
    name: str
    type: uint8
    description: str
    additional_constraints: str
    read_only: bool
    dynamic_typing: bool
    floating_point_range: sequence[FloatingPointRange, 1]
    integer_range: sequence[IntegerRange, 1]


def rcl_service(name, request_fields, response_fields):
    """The Cyclone request and response types of rcl_interfaces/srv/NAME."""
    def make(suffix, fields):
        # Through the metaclass's __prepare__, which takes the type name.
        cls = types.new_class(
            f"{name}{suffix}",
            (IdlStruct,),
            {"typename": f"rcl_interfaces::srv::dds_::{name}_{suffix}_"},
            lambda ns: ns["__annotations__"].update({"client": uint64, "seq": int64, **fields}),
        )
        return dataclass(cls)
    return make("Request", request_fields), make("Response", response_fields)


GetParameters = rcl_service(
    "GetParameters", {"names": sequence[str]}, {"values": sequence[ParameterValue]}
)
GetParameterTypes = rcl_service(
    "GetParameterTypes", {"names": sequence[str]}, {"types": sequence[uint8]}
)
SetParameters = rcl_service(
    "SetParameters", {"parameters": sequence[Parameter]}, {"results": sequence[SetParametersResult]}
)
ListParameters = rcl_service(
    "ListParameters", {"prefixes": sequence[str], "depth": uint64}, {"result": ListParametersResult}
)
DescribeParameters = rcl_service(
    "DescribeParameters", {"names": sequence[str]}, {"descriptors": sequence[ParameterDescriptor]}
)


class Client:
    """A service client of the node's service `name`."""

    def __init__(self, dp, name, request_type, response_type):
        self.writer = DataWriter(
            dp, Topic(dp, f"rq/latentam/{name}Request", request_type, qos=DEFAULT), qos=DEFAULT
        )
        self.reader = DataReader(
            dp, Topic(dp, f"rr/latentam/{name}Reply", response_type, qos=DEFAULT), qos=DEFAULT
        )
        self.name = name

    def call(self, request, timeout=120):
        deadline = time.monotonic() + timeout
        while not (self.writer.get_matched_subscriptions() and self.reader.get_matched_publications()):
            if time.monotonic() > deadline:
                raise SystemExit(f"the service {self.name} never matched")
            time.sleep(0.1)
        self.writer.write(request)
        while time.monotonic() < deadline:
            for reply in self.reader.take(N=8):
                if (reply.client, reply.seq) == (request.client, request.seq):
                    return reply
            time.sleep(0.05)
        raise SystemExit(f"no reply from the service {self.name}")


# rmw_dds_common's Gid: 24 bytes up to Humble, 16 from Iron on.
GID_BYTES = 24 if os.environ.get("ROS_DISTRO") in ("foxy", "galactic", "humble") else 16


@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: array[uint8, GID_BYTES]


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: str
    node_name: str
    reader_gid_seq: sequence[Gid]
    writer_gid_seq: sequence[Gid]


@dataclass
class ParticipantEntitiesInfo(
    IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"
):
    gid: Gid
    node_entities_info_seq: sequence[NodeEntitiesInfo]


TYPES = {
    "sensor_msgs/msg/Image": Image,
    "sensor_msgs/msg/CameraInfo": CameraInfo,
    "geometry_msgs/msg/PoseStamped": PoseStamped,
    "latentam_msgs/msg/MaskFeatures": MaskFeatures,
    "latentam_msgs/msg/TextEmbeddings": TextEmbeddings,
}

RELIABLE = Policy.Reliability.Reliable(duration(seconds=1))
SENSOR = Qos(RELIABLE, Policy.Durability.Volatile, Policy.History.KeepLast(8))
LATCHED = Qos(RELIABLE, Policy.Durability.TransientLocal, Policy.History.KeepLast(1))
DEFAULT = Qos(RELIABLE, Policy.Durability.Volatile, Policy.History.KeepLast(10))


def dds(topic):
    return "rt/" + topic.lstrip("/")


def cloud_points(c):
    offsets = {f.name: f.offset for f in c.fields}
    data = bytes(c.data)
    out = []
    for start in range(0, len(data), c.point_step):
        p = {}
        for name, off in offsets.items():
            fmt = "<I" if name == "rgb" else "<f"
            (p[name],) = struct.unpack_from(fmt, data, start + off)
        out.append(p)
    return out


def find_node(graph_reader, name, namespace):
    """The newest entry of the node `namespace`/`name` on
    ros_discovery_info, if one arrived."""
    found = None
    for info in graph_reader.read(N=64):
        for node in info.node_entities_info_seq:
            if node.node_name == name and node.node_namespace == namespace:
                found = node
    return found


def endpoint_topics(dp, gids, builtin):
    """The DDS topics of the endpoints whose GUIDs are among `gids`, as
    DDS discovery reports them (what `ros2 node info` joins)."""
    guids = {bytes(g.data[:16]) for g in gids}
    reader = BuiltinDataReader(dp, builtin)
    return sorted({e.topic_name for e in reader.read(N=1024) if e.key.bytes in guids})


def value_of(v):
    """A ParameterValue as JSON: [type, value]."""
    field = {
        0: None, 1: "bool_value", 2: "integer_value", 3: "double_value", 4: "string_value",
        6: "bool_array_value", 7: "integer_array_value", 8: "double_array_value",
        9: "string_array_value",
    }[v.type]
    return [v.type, getattr(v, field) if field else None]


def parameters(clients, client):
    """What `ros2 param list / get / set / describe` would show."""
    get_req, _ = GetParameters
    listed = clients["list_parameters"].call(ListParameters[0](client, 10, [], 0)).result
    names = ["voxel_size", "map_points", "map_every", "no_such_parameter"]
    got = clients["get_parameters"].call(get_req(client, 11, names)).values
    kinds = clients["get_parameter_types"].call(GetParameterTypes[0](client, 12, names)).types
    wanted = [
        Parameter("map_every", parameter_value(type=3, double_value=0.5)),
        Parameter("voxel_size", parameter_value(type=3, double_value=0.02)),
        Parameter("map_points", parameter_value(type=4, string_value="many")),
    ]
    set_results = clients["set_parameters"].call(SetParameters[0](client, 13, wanted)).results
    after = clients["get_parameters"].call(get_req(client, 14, ["map_every", "voxel_size"])).values
    described = clients["describe_parameters"].call(
        DescribeParameters[0](client, 15, ["voxel_size", "map_every"])
    ).descriptors
    return {
        "names": list(listed.names),
        "prefixes": list(listed.prefixes),
        "got": dict(zip(names, map(value_of, got))),
        "types": list(kinds),
        "set": [[r.successful, r.reason] for r in set_results],
        "after": [value_of(v) for v in after],
        "read_only": [d.read_only for d in described],
    }


def main(log, counts_only=False, save_dir=None):
    started = time.monotonic()
    dp = DomainParticipant(0)
    query_service = Client(dp, "query", QueryRequest, QueryResponse)
    save_service = Client(dp, "save", SaveRequest, SaveResponse)
    param_clients = {
        name: Client(dp, name, *types)
        for name, types in [
            ("get_parameters", GetParameters),
            ("get_parameter_types", GetParameterTypes),
            ("set_parameters", SetParameters),
            ("list_parameters", ListParameters),
            ("describe_parameters", DescribeParameters),
        ]
    }
    graph_reader = DataReader(
        dp, Topic(dp, "ros_discovery_info", ParticipantEntitiesInfo, qos=LATCHED), qos=LATCHED
    )
    graph_seconds = None
    with open(log, "rb") as f:
        messages = [
            (channel.topic, schema.name, m.log_time, m.data)
            for schema, channel, m in make_reader(f).iter_messages()
            if schema.name in TYPES and channel.topic not in ("/camera/semantic", "/camera/instances")
        ]
    writers = {}
    for topic, ty, _, _ in messages:
        if topic not in writers:
            qos = LATCHED if topic == "/vocabulary" else SENSOR
            writers[topic] = DataWriter(dp, Topic(dp, dds(topic), TYPES[ty], qos=qos), qos=qos)
    read = lambda name, ty, qos: DataReader(dp, Topic(dp, dds("/latentam/" + name), ty, qos=qos), qos=qos)
    map_reader = read("map", PointCloud2, LATCHED)
    path_reader = read("trajectory", Path, LATCHED)
    status_reader = read("status", DiagnosticArray, DEFAULT)
    relevance_reader = read("query/relevance", PointCloud2, DEFAULT)
    query_writer = DataWriter(
        dp, Topic(dp, dds("/latentam/query"), TextEmbeddings, qos=DEFAULT), qos=DEFAULT
    )

    # The node subscribes once it has planned its inputs from the graph.
    colour = writers["/camera/color/image_raw"]
    deadline = time.monotonic() + 120
    while not colour.get_matched_subscriptions():
        if time.monotonic() > deadline:
            raise SystemExit("the node never subscribed to the colour images")
        if graph_seconds is None and find_node(graph_reader, "latentam", "/"):
            graph_seconds = time.monotonic() - started
        time.sleep(0.1)
    time.sleep(0.5)

    # Played at the recorded rate.
    start_wall, start_log = time.monotonic(), messages[0][2]
    vocabulary = None
    for topic, ty, log_time, data in messages:
        wait = (log_time - start_log) / 1e9 - (time.monotonic() - start_wall)
        if wait > 0:
            time.sleep(wait)
        msg = TYPES[ty].deserialize(data)
        if topic == "/vocabulary":
            vocabulary = msg
        writers[topic].write(msg)
    published_frames = sum(1 for t, *_ in messages if t == "/camera/color/image_raw")

    # Until the node has received every message (or nothing more came for
    # 15 s) and mapped every frame it queued.
    status = {}
    received, since = -1, time.monotonic()
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        for s in status_reader.take(N=16):
            status = {kv.key: kv.value for kv in s.status[0].values}
            status["level"] = s.status[0].level
            status["message"] = s.status[0].message
        if not status:
            time.sleep(0.2)
            continue
        if int(status["messages_received"]) != received:
            received, since = int(status["messages_received"]), time.monotonic()
        all_in = received >= len(messages) or time.monotonic() - since > 15
        # Frames the mapper had no room for are dropped by its policy.
        drained = (
            status["queued_frames"] == "0"
            and not status.get("mapping_now") == "1"
            and int(status["frames_integrated"])
            + int(status["dropped_not_keyframe"])
            + int(status["dropped_superseded"])
            == int(status["frames_submitted"])
            and status["frames_assembled"] == status["frames_submitted"]
        )
        if all_in and drained:
            break
        time.sleep(0.2)
    time.sleep(2.5)  # the map is published at most once a second

    # A query: the first vocabulary word's embedding alone (cosine).
    dim = vocabulary.dim
    size = 2 if vocabulary.dtype == "f16" else 4
    query = TextEmbeddings(
        header=Header(stamp=Time(0, 0), frame_id=""),
        names=[vocabulary.names[0]],
        ids=[vocabulary.ids[0]],
        dim=dim,
        dtype=vocabulary.dtype,
        data=vocabulary.data[: dim * size],
        model=vocabulary.model,
    )
    while not query_writer.get_matched_subscriptions():
        time.sleep(0.1)
    query_writer.write(query)
    relevance = None
    deadline = time.monotonic() + 120
    while relevance is None and time.monotonic() < deadline:
        got = relevance_reader.take(N=1)
        relevance = got[0] if got else None
        time.sleep(0.1)
    if relevance is None:
        raise SystemExit("no reply to the query")

    # The same query as a service, then one of the wrong dimension, then
    # a save.
    client = 0x1234_5678_9ABC_DEF0
    reply = query_service.call(QueryRequest(client, 1, query))
    wrong = query_service.call(
        QueryRequest(client, 2, TextEmbeddings(**{**query.__dict__, "dim": 3, "data": query.data[: 3 * size]}))
    )
    services = {
        "query": {
            "success": reply.success,
            "message": reply.message,
            "same_points_as_the_topic": cloud_points(reply.relevance) == cloud_points(relevance),
            "points": len(cloud_points(reply.relevance)),
        },
        "wrong_query": {
            "success": wrong.success,
            "message": wrong.message,
            "points": len(cloud_points(wrong.relevance)),
        },
    }
    if save_dir:
        saved = save_service.call(SaveRequest(client, 3, save_dir))
        services["save"] = {"success": saved.success, "message": saved.message}
    services["parameters"] = parameters(param_clients, client)

    node = find_node(graph_reader, "latentam", "/")
    if node is None:
        raise SystemExit("the node is not in ros_discovery_info")
    graph_seconds = graph_seconds if graph_seconds is not None else time.monotonic() - started
    graph = {
        "seconds_after_client_start": graph_seconds,
        "gid_bytes": GID_BYTES,
        "writers": endpoint_topics(dp, node.writer_gid_seq, BuiltinTopicDcpsPublication),
        "readers": endpoint_topics(dp, node.reader_gid_seq, BuiltinTopicDcpsSubscription),
        "writer_gids": len(node.writer_gid_seq),
        "reader_gids": len(node.reader_gid_seq),
    }

    maps = map_reader.read(N=16)
    paths = path_reader.read(N=16)
    summary = {
        "graph": graph,
        "services": services,
        "published_frames": published_frames,
        "published_messages": len(messages),
        "status": status,
        "map": {
            "frame_id": maps[-1].header.frame_id,
            "fields": [f.name for f in maps[-1].fields],
            "points": cloud_points(maps[-1]),
        },
        "trajectory": [
            [p.pose.position.x, p.pose.position.y, p.pose.position.z,
             p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w]
            for p in paths[-1].poses
        ],
        "relevance": {
            "fields": [f.name for f in relevance.fields],
            "points": cloud_points(relevance),
        },
        "word": vocabulary.names[0],
    }
    if counts_only:
        for part in ("map", "relevance"):
            summary[part]["points"] = len(summary[part]["points"])
    json.dump(summary, sys.stdout)


if __name__ == "__main__":
    args = sys.argv[2:]
    save_dir = args[args.index("--save-dir") + 1] if "--save-dir" in args else None
    main(sys.argv[1], "--counts" in args, save_dir)
