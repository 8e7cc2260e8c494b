#!/usr/bin/env python3
"""A matcher for angle-i2p, over Eclipse Cyclone DDS (no ROS installation needed): a starting
point for a matcher author. It hears each camera frame's CameraInfo, runs `match_frame` and
publishes the putative correspondences as angle_i2p_msgs/Correspondences, following the contract:

- header.stamp = the image's stamp, exactly (angle-i2p joins a frame's parts by stamp);
- header.frame_id = the camera's optical frame (the CameraInfo's frame_id); map_frame_id = the
  frame of the map points;
- (u, v) in the pixel grid of the image CameraInfo describes, pixel centres at integer
  coordinates ((0, 0) is the centre of the top-left pixel); angle-i2p uses CameraInfo's K only
  (no undistortion yet), so with a distorting lens match on the rectified image;
- score in [0, 1], higher = more confident (angle-i2p samples the best first);
- reliable or best effort: angle-i2p reads best effort, which matches both.

    matcher_cyclonedds.py [--namespace /cam0] [--domain D] [--replay FILE.json] [--count N]

`match_frame` here replays correspondences from a JSON file ({"<stamp_ns>": [[u, v, x, y, z,
score], ...]}), which is how tests/node_ros.rs drives it; put your matcher there. Prints READY
once its writer is matched; exits after --count published frames. Status 3: cyclonedds missing.
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
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration
except ImportError as e:
    print(f"missing Python package: {e}", file=sys.stderr)
    sys.exit(3)


# ROS 2 types as DDS sees them (`pkg::msg::dds_::Type_`), field order as in the .msg files.
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32
    nanosec: t.uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class RegionOfInterest(IdlStruct, typename="sensor_msgs::msg::dds_::RegionOfInterest_"):
    x_offset: t.uint32
    y_offset: t.uint32
    height: t.uint32
    width: t.uint32
    do_rectify: bool


@dataclass
class CameraInfo(IdlStruct, typename="sensor_msgs::msg::dds_::CameraInfo_"):
    header: Header
    height: t.uint32
    width: t.uint32
    distortion_model: str
    d: t.sequence[t.float64]
    k: t.array[t.float64, 9]
    r: t.array[t.float64, 9]
    p: t.array[t.float64, 12]
    binning_x: t.uint32
    binning_y: t.uint32
    roi: RegionOfInterest


@dataclass
class Correspondence(IdlStruct, typename="angle_i2p_msgs::msg::dds_::Correspondence_"):
    u: t.float32
    v: t.float32
    x: t.float32
    y: t.float32
    z: t.float32
    score: t.float32


@dataclass
class Correspondences(IdlStruct, typename="angle_i2p_msgs::msg::dds_::Correspondences_"):
    header: Header
    map_frame_id: str
    correspondences: t.sequence[Correspondence]


def topic(namespace, name):
    """The DDS name of a ROS topic relative to `namespace` (ROS 2 prefixes `rt`)."""
    return "rt" + (namespace.rstrip("/") + "/" + name if namespace else "/" + name)


def match_frame(info, replay, map_frame_id):
    """The putative matches of one frame: replace this with your matcher (image + map in,
    [(u, v, x, y, z, score)] out). Returns None to publish nothing for this frame."""
    stamp_ns = info.header.stamp.sec * 1_000_000_000 + info.header.stamp.nanosec
    rows = replay.get(str(stamp_ns))
    if rows is None:
        return None
    return [Correspondence(*map(float, r)) for r in rows]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--namespace", default="")
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0") or 0))
    ap.add_argument("--replay", help="JSON: stamp_ns -> [[u, v, x, y, z, score], ...]")
    ap.add_argument("--map-frame", default="map")
    ap.add_argument("--count", type=int, default=0, help="exit after this many frames (0: never)")
    ap.add_argument("--timeout", type=float, default=120.0)
    a = ap.parse_args()
    replay = json.load(open(a.replay)) if a.replay else {}

    dp = DomainParticipant(a.domain)
    sensor = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(10))
    reliable = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(10))
    reader = DataReader(dp, Topic(dp, topic(a.namespace, "camera/camera_info"), CameraInfo), qos=sensor)
    writer = DataWriter(dp, Topic(dp, topic(a.namespace, "matcher/correspondences"), Correspondences), qos=reliable)

    end = time.time() + a.timeout
    while writer.get_matched_subscriptions() == [] and time.time() < end:
        time.sleep(0.05)
    print("READY", flush=True)
    published, seen = 0, set()
    while time.time() < end and (a.count == 0 or published < a.count):
        for info in reader.take(N=10):
            key = (info.header.stamp.sec, info.header.stamp.nanosec)
            if key in seen:
                continue
            matches = match_frame(info, replay, a.map_frame)
            if matches is None:
                continue
            seen.add(key)
            # The contract: the image's stamp and the camera's frame, copied as they came.
            writer.write(Correspondences(header=info.header, map_frame_id=a.map_frame, correspondences=matches))
            published += 1
            print(f"published {len(matches)} matches for {key[0]}.{key[1]:09d}", flush=True)
        time.sleep(0.01)
    sys.exit(0 if published else 1)


if __name__ == "__main__":
    main()
