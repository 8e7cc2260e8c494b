#!/usr/bin/env python3
"""Subscribe to a ROS 2 PoseStamped topic with Eclipse Cyclone DDS (not our DDS stack) and
print each sample as a JSON line.

    echo_pose.py [--topic /angle_i2p/pose] [--count N] [--timeout S] [--domain D]

Prints `READY` once a publisher is matched, then one line per sample:
{"stamp_ns", "frame_id", "position": [x, y, z], "orientation": [x, y, z, w]}. Exits after
N samples (status 0) or at the time-out (status 0 if any sample arrived, else 1); status 3
when the cyclonedds package is missing.
"""
import argparse
import json
import os
import sys
import time
from dataclasses import dataclass

try:
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl import IdlStruct
    import cyclonedds.idl.types as t
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration
except ImportError as e:  # the Rust test skips (or fails under CI) on status 3
    print(f"missing Python package: {e}", file=sys.stderr)
    sys.exit(3)


# ROS 2 types as DDS sees them: `pkg::msg::dds_::Type_`.
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32
    nanosec: t.uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64
    y: t.float64
    z: t.float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64
    y: t.float64
    z: t.float64
    w: t.float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header
    pose: Pose


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--topic", default="/angle_i2p/pose")
    ap.add_argument("--count", type=int, default=0, help="exit after this many samples (0: at the time-out)")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0") or 0))
    a = ap.parse_args()

    dp = DomainParticipant(a.domain)
    topic = Topic(dp, "rt" + a.topic, PoseStamped)
    qos = Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(1000),
    )
    reader = DataReader(dp, topic, qos=qos)
    end = time.monotonic() + a.timeout
    ready = False
    got = 0
    while time.monotonic() < end:
        if not ready and reader.get_matched_publications():
            print("READY", flush=True)
            ready = True
        for s in reader.take(N=100):
            if not isinstance(s, PoseStamped):
                continue
            h, p = s.header, s.pose
            print(json.dumps({
                "stamp_ns": h.stamp.sec * 1_000_000_000 + h.stamp.nanosec,
                "frame_id": h.frame_id,
                "position": [p.position.x, p.position.y, p.position.z],
                "orientation": [p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w],
            }), flush=True)
            got += 1
            if a.count and got >= a.count:
                return 0
        time.sleep(0.02)
    print(f"time-out after {a.timeout} s with {got} samples", file=sys.stderr)
    return 0 if got else 1


if __name__ == "__main__":
    sys.exit(main())
