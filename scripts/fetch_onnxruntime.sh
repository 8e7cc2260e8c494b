#!/usr/bin/env bash
# Puts ONNX Runtime's shared library where angle-i2p looks for it by default:
# .ort/libonnxruntime.so.1.31.1, taken from the PyPI wheel onnxruntime==1.31.1 (a set-up step;
# nothing is downloaded at run time). Override the location with ORT_DYLIB_PATH.
set -euo pipefail
cd "$(dirname "$0")/.."
version=1.31.1
dest=.ort
lib="$dest/libonnxruntime.so.$version"
[ -f "$lib" ] && { echo "$lib"; exit 0; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
python3 -m pip download --quiet --no-deps --only-binary=:all: \
  --python-version 3.11 --platform manylinux_2_28_x86_64 \
  "onnxruntime==$version" -d "$tmp"
mkdir -p "$dest"
python3 - "$tmp" "$dest" "$version" <<'PY'
import sys, zipfile, pathlib
tmp, dest, version = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2]), sys.argv[3]
wheel = next(tmp.glob("onnxruntime-*.whl"))
with zipfile.ZipFile(wheel) as z:
    name = f"onnxruntime/capi/libonnxruntime.so.{version}"
    (dest / f"libonnxruntime.so.{version}").write_bytes(z.read(name))
PY
echo "$lib"
