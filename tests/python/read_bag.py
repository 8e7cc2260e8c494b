#!/usr/bin/env python3
"""Decode every message of a rosbag2 MCAP bag with two independent Python readers and print JSON.

    read_bag.py BAG_DIR   ->   {"rosbags": [...], "mcap_ros2": [...]}

Each list holds {"topic", "type", "log_time", "msg"} in log-time order, messages as plain JSON
(rosbags' AnyReader with types from the bag's own schemas; mcap + mcap_ros2's DecoderFactory).
Exits with status 3 when a reader package is missing.
"""
import dataclasses
import json
import pathlib
import sys

try:
    import numpy as np
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader
except ImportError as e:  # the Rust test skips (or fails under CI) on status 3
    print(f"missing Python package: {e}", file=sys.stderr)
    sys.exit(3)


def plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (bytes, bytearray)):
        return list(v)
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if isinstance(v, (np.integer, np.floating)):
        return v.item()
    if hasattr(v, "__dataclass_fields__"):
        return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)
                if f.name != "__msgtype__" and not f.name.isupper()}  # constants are upper case
    if hasattr(v, "__slots__"):
        return {k: plain(getattr(v, k)) for k in v.__slots__}
    return v


def with_rosbags(path):
    out = []
    with AnyReader([path]) as reader:
        for conn, t, raw in reader.messages():
            out.append({"topic": conn.topic, "type": conn.msgtype, "log_time": t,
                        "msg": plain(reader.deserialize(raw, conn.msgtype))})
    return out


def with_mcap(path):
    out = []
    for f in sorted(path.glob("*.mcap")):
        with open(f, "rb") as fi:
            reader = make_reader(fi, decoder_factories=[DecoderFactory()])
            if reader.get_header().profile != "ros2":
                raise SystemExit(f"{f}: profile {reader.get_header().profile!r}")
            for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
                out.append({"topic": channel.topic, "type": schema.name, "log_time": message.log_time,
                            "msg": plain(decoded)})
    return out


def main():
    path = pathlib.Path(sys.argv[1])
    print(json.dumps({"rosbags": with_rosbags(path), "mcap_ros2": with_mcap(path)}))


if __name__ == "__main__":
    main()
