#!/usr/bin/env python3
"""An independent DDS peer for marionette's ROS 2 interface: Eclipse Cyclone DDS (PyPI
`cyclonedds`), with ROS 2's wire names and types written out here, no ROS installed.

It reads `rt/joint_states` (sensor_msgs::msg::dds_::JointState_) and, given a target file,
publishes each effector's path on `rt/marionette/targets/<effector>`
(geometry_msgs::msg::dds_::PointStamped_, metres), then a few messages the loop must refuse.
It writes what it received as JSON: every joint state with its stamp and arrival time.

    peer.py --domain 42 --out got.json [--targets walk.csv --metres-per-unit M --rate 100]

Loopback only: the participant uses 127.0.0.1 and finds peers by unicast there."""

import argparse
import csv
import json
import math
import os
import sys
import threading
import time
from dataclasses import dataclass

LOOPBACK = """<CycloneDDS><Domain Id="any"><General><Interfaces>
<NetworkInterface address="127.0.0.1"/></Interfaces><AllowMulticast>false</AllowMulticast>
</General><Discovery><ParticipantIndex>auto</ParticipantIndex>
<MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>
<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>"""
os.environ["CYCLONEDDS_URI"] = LOOPBACK

from cyclonedds.core import Listener, Qos, Policy  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header
    name: sequence[str]
    position: sequence[float64]
    velocity: sequence[float64]
    effort: sequence[float64]


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
class PointStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PointStamped_"):
    header: Header
    point: Point


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
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header
    pose: Pose


# The ROS 2 graph (what `ros2 node list` reads): rmw_dds_common's messages, Jazzy's 16-byte gid.
@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: array[uint8, 16]


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: str
    node_name: str
    reader_gid_seq: sequence[Gid]
    writer_gid_seq: sequence[Gid]


@dataclass
class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
    gid: Gid
    node_entities_info_seq: sequence[NodeEntitiesInfo]


def turn_x_to(d):
    """The unit quaternion (x, y, z, w) turning +x to the direction d (shortest arc)."""
    n = math.sqrt(sum(c * c for c in d))
    dx, dy, dz = (c / n for c in d)
    # axis x × d = (0, -dz, dy), w = 1 + x·d
    q = (0.0, -dz, dy, 1.0 + dx)
    m = math.sqrt(sum(c * c for c in q))
    if m < 1e-9:  # d = -x: half a turn about z
        return (0.0, 0.0, 1.0, 0.0)
    return tuple(c / m for c in q)


def stamp_now():
    ns = time.time_ns()
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--targets", help="a `marionette targets` CSV (file units)")
    ap.add_argument("--metres-per-unit", type=float, default=1.0)
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--root", default="root")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--pose", action="store_true", help="PoseStamped from a file with directions")
    a = ap.parse_args()

    dp = DomainParticipant(a.domain)
    # Reliable, keep all: every joint state published is counted.
    reader_qos = Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
        Policy.History.KeepAll,
        Policy.DataRepresentation(use_cdrv0_representation=True),
    )
    writer_qos = Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
        Policy.History.KeepLast(1),
        Policy.DataRepresentation(use_cdrv0_representation=True),
    )
    got = []
    lock = threading.Lock()
    first = threading.Event()

    class OnData(Listener):
        def on_data_available(self, reader):
            arrived = time.time_ns()
            for s in reader.take(N=1000):
                if not isinstance(s, JointState):
                    continue  # the writer went away (an invalid sample with the news)
                with lock:
                    got.append(
                        {
                            "stamp_ns": s.header.stamp.sec * 1_000_000_000 + s.header.stamp.nanosec,
                            "arrived_ns": arrived,
                            "frame_id": s.header.frame_id,
                            "name": list(s.name),
                            "position": list(s.position),
                            "velocity": list(s.velocity),
                            "effort": list(s.effort),
                        }
                    )
            first.set()

    states = DataReader(dp, Topic(dp, "rt/joint_states", JointState), qos=reader_qos, listener=OnData())
    graph_qos = Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(1),
        Policy.DataRepresentation(use_cdrv0_representation=True),
    )
    graph = DataReader(dp, Topic(dp, "ros_discovery_info", ParticipantEntitiesInfo), qos=graph_qos)
    nodes = {}

    def read_graph():
        for s in graph.read(N=100):
            if isinstance(s, ParticipantEntitiesInfo):
                for n in s.node_entities_info_seq:
                    name = n.node_namespace.rstrip("/") + "/" + n.node_name
                    nodes[name] = {"readers": len(n.reader_gid_seq), "writers": len(n.writer_gid_seq)}

    sent = {"targets": 0, "bad": 0}
    start = time.monotonic()
    if a.targets:
        rows = []
        with open(a.targets) as f:
            for r in csv.reader(f):
                if not r or r[0] == "t":
                    continue
                d = tuple(float(v) for v in r[5:8]) if len(r) >= 8 else None
                rows.append((float(r[0]), r[1], float(r[2]), float(r[3]), float(r[4]), d))
        effectors = sorted({r[1] for r in rows}, key=[r[1] for r in rows].index)
        kind = PoseStamped if a.pose else PointStamped
        writers = {
            e: DataWriter(dp, Topic(dp, f"rt/marionette/targets/{e}", kind), qos=writer_qos)
            for e in effectors
        }
        # Start once the loop publishes and our writers have met its readers.
        if not first.wait(a.timeout):
            print("peer: no joint states arrived", file=sys.stderr)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if all(w.get_matched_subscriptions() for w in writers.values()):
                break
            time.sleep(0.05)
        time.sleep(0.2)
        read_graph()

        def send(e, x, y, z, frame=a.root, d=(1.0, 0.0, 0.0)):
            header = Header(stamp=stamp_now(), frame_id=frame)
            if a.pose:
                q = Quaternion(*turn_x_to(d))
                writers[e].write(PoseStamped(header=header, pose=Pose(position=Point(x=x, y=y, z=z), orientation=q)))
            else:
                writers[e].write(PointStamped(header=header, point=Point(x=x, y=y, z=z)))

        period = 1.0 / a.rate
        t0 = rows[0][0]
        begin = time.monotonic()
        last = {}
        for t, e, x, y, z, d in rows:
            due = begin + (t - t0)
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            m = a.metres_per_unit
            send(e, x * m, y * m, z * m, d=d or (1.0, 0.0, 0.0))
            last[e] = (x * m, y * m, z * m)
            sent["targets"] += 1
        del period
        # What must be refused: not a number and a frame it does not know (by the reader), a
        # target a kilometre away (by the loop: out of range). Apart, so each reaches the
        # reader (keep-last 1); then the last good target again.
        e0 = effectors[0]
        time.sleep(0.05)
        send(e0, math.nan, 0.0, 0.0)
        time.sleep(0.05)
        send(e0, *last[e0], frame="map")
        time.sleep(0.05)
        send(e0, 1000.0, 0.0, 0.0)
        time.sleep(0.05)
        send(e0, *last[e0])
        sent["bad"] = 3

    # Until the publisher has been quiet for a second (the run ended), or the timeout.
    while time.monotonic() - start < a.timeout:
        time.sleep(0.1)
        read_graph()
        with lock:
            quiet = got and time.time_ns() - got[-1]["arrived_ns"] > 1_000_000_000
        if quiet:
            break
    with lock:
        json.dump({"sent": sent, "joint_states": got, "nodes": nodes}, open(a.out, "w"))
    del states
    print(f"peer: {len(got)} joint states received, {sent['targets']} targets and {sent['bad']} bad messages sent")


if __name__ == "__main__":
    main()
