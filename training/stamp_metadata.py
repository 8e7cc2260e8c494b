"""Writes a model's constants into its ONNX file's metadata, without retraining.

The model constants are the `network.*` parameters the training inputs were built with (K, M,
the graphs' θ and σ_d, the prior alignment, the keypoint pass and ranking) and the confidence the
model reads for a matcher without one. A model only works with the values it was trained on, so
the model carries them: metadata_props `angle_i2p.<key>` (the value as a params file writes it)
and `angle_i2p.format`. The runtime reads them at load (src/reject/model_constants.rs), uses
them, and refuses a params file that sets one to another value.

    python3 training/stamp_metadata.py MODEL.onnx --set neighbours=32 --set theta=angle ... [--out OUT.onnx]
    python3 training/stamp_metadata.py MODEL.onnx --constants DATA/model_constants.json [--out OUT.onnx]
    python3 training/stamp_metadata.py MODEL.onnx --show
    python3 training/stamp_metadata.py MODEL.onnx --clear [--out OUT.onnx]   (as an older model)

`angle-i2p export` writes `model_constants.json` beside the samples; `train.py` stamps what it
exports from there. Only `angle_i2p.*` entries are replaced, every other byte of the file is
kept: the graph is not decoded (ONNX is protobuf and metadata_props, field 14 of ModelProto, is
a top-level field), so a stamped model scores bit for bit as before, and this needs no package.
"""
import argparse
import json
import sys

PREFIX = "angle_i2p."
FORMAT_KEY = PREFIX + "format"
FORMAT = "1"
# The runtime's ModelConstant::ALL, in its order.
CONSTANTS = ("neighbours", "keypoints", "theta", "sigma_d", "align_prior", "keypoint_iterations",
             "keypoint_ranking", "missing_confidence")
EXPORT_FILE = "model_constants.json"  # what `angle-i2p export` writes beside the samples
METADATA_FIELD = 14  # ModelProto.metadata_props (StringStringEntryProto: key = 1, value = 2)


class StampError(Exception):
    """A model file or a constant this script cannot take."""


def read_varint(buf, pos):
    """The varint at `pos` and the position after it."""
    value, shift = 0, 0
    while True:
        if pos >= len(buf):
            raise StampError("truncated varint: not an ONNX file?")
        byte = buf[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if byte < 0x80:
            return value, pos
        shift += 7


def varint(value):
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def fields(buf):
    """The top-level fields of a protobuf message: (number, payload or None, whole field's bytes)."""
    pos, out = 0, []
    while pos < len(buf):
        start = pos
        tag, pos = read_varint(buf, pos)
        number, wire = tag >> 3, tag & 7
        payload = None
        if wire == 0:
            _, pos = read_varint(buf, pos)
        elif wire == 1:
            pos += 8
        elif wire == 2:
            length, pos = read_varint(buf, pos)
            payload, pos = buf[pos:pos + length], pos + length
        elif wire == 5:
            pos += 4
        else:
            raise StampError(f"wire type {wire} at byte {start}: not an ONNX file?")
        if pos > len(buf):
            raise StampError(f"field {number} runs past the end of the file: truncated?")
        out.append((number, payload, buf[start:pos]))
    return out


def decode_entry(payload):
    """A StringStringEntryProto's (key, value)."""
    entry = {1: "", 2: ""}
    for number, data, _ in fields(payload):
        if number in entry and data is not None:
            entry[number] = data.decode("utf-8")
    return entry[1], entry[2]


def encode_entry(key, value):
    """One metadata_props field (tag, length, StringStringEntryProto)."""
    k, v = key.encode("utf-8"), value.encode("utf-8")
    payload = b"\x0a" + varint(len(k)) + k + b"\x12" + varint(len(v)) + v
    return varint(METADATA_FIELD << 3 | 2) + varint(len(payload)) + payload


def metadata(model):
    """Every metadata_props entry of the ONNX bytes `model`, in file order."""
    return dict(decode_entry(p) for n, p, _ in fields(model) if n == METADATA_FIELD and p is not None)


def stamped_constants(model):
    """The constants already in the ONNX bytes `model` (key without prefix → text)."""
    return {k[len(PREFIX):]: v for k, v in metadata(model).items() if k.startswith(PREFIX) and k != FORMAT_KEY}


def check_constants(constants):
    """The constants as metadata entries (format first; none at all for no constants): known
    keys only, each a plain value."""
    if not constants:
        return {}
    unknown = sorted(set(constants) - set(CONSTANTS))
    if unknown:
        raise StampError(f"not a model constant: {', '.join(unknown)} (known: {', '.join(CONSTANTS)})")
    entries = {FORMAT_KEY: FORMAT}
    for key in CONSTANTS:
        if key in constants:
            value = str(constants[key]).strip()
            if not value or "\n" in value:
                raise StampError(f"{key}: {constants[key]!r} is no single value")
            entries[PREFIX + key] = value
    return entries


def stamp(model, constants):
    """`model` (ONNX bytes) with its `angle_i2p.*` metadata replaced by `constants` (key → text);
    every other field kept as it is, the new entries appended."""
    kept = [whole for n, p, whole in fields(model)
            if not (n == METADATA_FIELD and p is not None and decode_entry(p)[0].startswith(PREFIX))]
    return b"".join(kept) + b"".join(encode_entry(k, v) for k, v in check_constants(constants).items())


def stamp_file(path, constants, out=None):
    """Stamps the ONNX file at `path` (in place, or into `out`)."""
    with open(path, "rb") as f:
        model = f.read()
    stamped = stamp(model, constants)
    with open(out or path, "wb") as f:
        f.write(stamped)
    return stamped


def load_constants(path):
    """Constants from `angle-i2p export`'s model_constants.json (`angle_i2p.<key>`: text), keys
    given with or without the prefix."""
    with open(path) as f:
        data = json.load(f)
    return {k[len(PREFIX):] if k.startswith(PREFIX) else k: v for k, v in data.items() if k != FORMAT_KEY}


def parse_set(items):
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise StampError(f"--set {item}: expected KEY=VALUE")
        out[key.strip()] = value
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model")
    ap.add_argument("--constants", help="model_constants.json written by `angle-i2p export`")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a constant (after --constants, so it wins); repeat for each. Constants the model "
                         "already carries and that are not given again are kept")
    ap.add_argument("--out", help="write the stamped model here (default: in place)")
    ap.add_argument("--show", action="store_true", help="print the model's metadata and stop")
    ap.add_argument("--clear", action="store_true",
                    help="remove every angle_i2p.* entry (the model then runs with the params' values)")
    a = ap.parse_args()
    try:
        if a.show:
            with open(a.model, "rb") as f:
                for key, value in metadata(f.read()).items():
                    print(f"{key}: {value}")
            return 0
        given = load_constants(a.constants) if a.constants else {}
        given.update(parse_set(a.set))
        if not given and not a.clear:
            raise StampError("no constants: give --constants, --set or --clear")
        with open(a.model, "rb") as f:
            constants = {} if a.clear else stamped_constants(f.read())  # kept where not given again
        constants.update(given)
        stamped = stamp_file(a.model, constants, a.out)
        written = {k: v for k, v in metadata(stamped).items() if k.startswith(PREFIX)}
        print(f"{a.out or a.model}: " + (", ".join(f"{k[len(PREFIX):]}={v}" for k, v in written.items()) or
                                          "no model constants"))
        return 0
    except (OSError, ValueError, StampError) as e:
        print(f"stamp_metadata: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
