#!/usr/bin/env python3
"""Digest of a replay output bag without its timings, to show a change keeps behaviour.

    output_digests.py OUT_BAG_DIR  ->  prints one sha256 hex digest

Every message is decoded (mcap + mcap_ros2, types from the bag's own schemas) and written out as
canonical JSON in log-time order; the diagnostics values whose key ends in `_ms` (wall-clock
timings, different on every run) are dropped. Floats keep every bit (`float.hex`).
"""
import hashlib
import json
import pathlib
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def plain(v):
    if isinstance(v, float):
        return v.hex()
    if isinstance(v, (bytes, bytearray)):
        return v.hex()
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if hasattr(v, "__slots__"):
        out = {k: plain(getattr(v, k)) for k in v.__slots__}
        if "key" in out and "value" in out and str(out["key"]).endswith("_ms"):
            out["value"] = "<timing>"
        return out
    return v


def digest(bag: pathlib.Path) -> str:
    h = hashlib.sha256()
    for path in sorted(bag.glob("*.mcap")):
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
                row = [channel.topic, message.log_time, plain(decoded)]
                h.update(json.dumps(row, sort_keys=True).encode())
                h.update(b"\n")
    return h.hexdigest()


if __name__ == "__main__":
    print(digest(pathlib.Path(sys.argv[1])))
