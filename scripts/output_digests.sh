#!/usr/bin/env bash
# Replays the shipped bags and the shared val bags (every prior variant) with each method and
# compares a digest of every output bag (timings left out: scripts/output_digests.py) with the
# recorded ones in tests/fixtures/output_digests.txt. A refactor that claims "same behaviour"
# must pass `scripts/output_digests.sh check`; a change of behaviour re-records with `record`.
#   scripts/output_digests.sh check|record [BIN]
# Digests are of this machine's floating point: ONNX Runtime may pick other kernels on another CPU,
# so record and check on one machine (this is a development check, not part of `make test`).
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:?check or record}
bin=${2:-${CARGO_TARGET_DIR:-target}/release/angle-i2p}
py=${ANGLE_I2P_PYTHON:-.venv/bin/python}
shared=${ANGLE_I2P_DATA:-../shared/data}
fixture=tests/fixtures/output_digests.txt
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
bags=(bags/synth-sift bags/synth-hard bags/synth-extreme)
for b in "$shared"/redkitchen-*-val*; do [ -d "$b" ] && bags+=("$b"); done
: > "$tmp/digests"
for bag in "${bags[@]}"; do
  name=$(basename "$bag")
  extra=()
  [[ $name == *disparity* ]] && extra=(-p depth_kind:=disparity)
  # angle-i2p-alone: the default method with frames alone (tracking off), whose outputs must
  # stay those of the method before tracking.
  for method in angle-i2p angle-i2p-alone consistency ransac; do
    out="$tmp/$name-$method"
    run=(--method "${method%-alone}")
    [[ $method == *-alone ]] && run+=(-p tracking.enabled:=false)
    "$bin" replay "$bag" --out "$out" "${run[@]}" "${extra[@]}" > /dev/null 2>&1
    echo "$name $method $("$py" scripts/output_digests.py "$out")" >> "$tmp/digests"
    rm -rf "$out"
  done
done
if [ "$mode" = record ]; then
  cp "$tmp/digests" "$fixture"
  echo "recorded $(wc -l < "$fixture") digests in $fixture"
else
  if diff <(sort "$fixture") <(sort "$tmp/digests"); then
    echo "same outputs: $(wc -l < "$fixture") bag × method digests match"
  else
    echo "outputs differ from $fixture (lines above: < recorded, > now)"; exit 1
  fi
fi
