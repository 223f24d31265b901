#!/bin/sh
# Benchmark of latentam-ros's input path: a Cyclone DDS publisher
# (tests/python/ros_node_check.py) plays LOG as ROS 2 topics at its
# recorded rate; the node maps them; OUT/summary.json gets the node's
# status at the end (messages received, frames assembled and dropped by
# policy, p99 of the time from the message that completes a frame to the
# frame being queued, and of the time from its colour image), the counts
# of the map and query clouds, and OUT/node.err the node's own summary.
#
# Runs in a network namespace holding only loopback (as root):
#   tools/ros/bench/topic_latency.sh LOG OUT [PYTHON] [NODE]
# e.g. with `latentam gen-scene --width 640 --height 480 --fps 30 --frames 300`.
set -eu
log=$(realpath "$1")
mkdir -p "$2"
out=$(realpath "$2")
here=$(dirname "$(realpath "$0")")
python=${3:-python3}
node=${4:-$here/../../../target/release/latentam-ros}
exec unshare --net sh -c '
ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo
export CYCLONEDDS_URI="<CycloneDDS><Domain><General><Interfaces><NetworkInterface name=\"lo\" multicast=\"true\"/></Interfaces></General></Domain></CycloneDDS>"
"$0" --out "$1/run" > "$1/node.out" 2> "$1/node.err" &
pid=$!
"$2" "$3/../../../tests/python/ros_node_check.py" "$4" --counts > "$1/summary.json"
kill -INT $pid
wait $pid
tail -n 2 "$1/node.err"
' "$node" "$out" "$python" "$here" "$log"
