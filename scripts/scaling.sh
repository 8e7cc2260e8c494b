#!/usr/bin/env bash
# How the cost grows with the map and with the bag, in one run (`make scaling`): `synth --preset
# building` bags (the same frames whatever the map size: the matches come from the sparse map, the
# published map adds points on the same surfaces), each replayed with /usr/bin/time -v.
#   map rows:    per map size, a FRAMES-frame bag: time to the first pose (a 1-frame bag: bag read,
#                map decoded and indexed, one frame), then the whole bag: per-frame median and
#                peak RSS of replay;
#   length rows: per bag length, replay and eval of a LENGTH_MAP-point bag: peak RSS and wall time.
# Prints a Markdown table (and writes it to OUT/scaling.md). Environment:
#   SIZES="100000 200000 1000000 5000000"  LENGTHS="1000 2000"  FRAMES=200  LENGTH_MAP=1000000
#   METHOD=angle-i2p  OUT=out/scaling  BIN=…/angle-i2p  EXTRA="-p limits.max_map_points:=20000000 …"
#   REPEAT=1: replays of each map row; the per-frame median is the least of them (on a machine shared
#   with other work, the repeat nearest the machine's own speed)
# A map over 5 M points needs limits raised (limits.max_map_points, limits.max_record_bytes: a
# 20 M-point PointCloud2 is 320 MB), e.g. SIZES=20000000 EXTRA="-p limits.max_map_points:=20000000
# -p limits.max_record_bytes:=1000000000".
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${BIN:-${CARGO_TARGET_DIR:-target}/release/angle-i2p}
sizes=${SIZES:-100000 200000 1000000 5000000}
lengths=${LENGTHS:-1000 2000}
frames=${FRAMES:-200}
length_map=${LENGTH_MAP:-1000000}
method=${METHOD:-angle-i2p}
repeat=${REPEAT:-1}
out=${OUT:-out/scaling}
read -r -a extra <<< "${EXTRA:-}"
[ -x "$bin" ] || { echo "no binary at $bin (cargo build --release)" >&2; exit 1; }
[ -x /usr/bin/time ] || { echo "/usr/bin/time (GNU time) is needed for peak RSS" >&2; exit 1; }
mkdir -p "$out"
table="$out/scaling.md"

# Runs a command under GNU time; prints "<wall s> <peak RSS MB>" and keeps its stdout in $out/last.
timed() {
  /usr/bin/time -v -o "$out/time.txt" "$@" > "$out/last" 2> "$out/last.err" || {
    echo "failed: $*" >&2; tail -5 "$out/last.err" >&2; exit 1; }
  local wall rss
  wall=$(awk -F': ' '/Elapsed \(wall clock\)/ {n = split($2, t, ":"); s = 0; for (i = 1; i <= n; i++) s = s * 60 + t[i]; print s}' "$out/time.txt")
  rss=$(awk -F': ' '/Maximum resident set size/ {printf "%.0f", $2 / 1024}' "$out/time.txt")
  echo "$wall $rss"
}

synth() { # bag frames map_points
  [ -d "$1" ] && [ -f "$1/.done" ] && [ "$(cat "$1/.done")" = "$2 $3" ] && return
  "$bin" synth --preset building --seed 1 --frames "$2" --map-points "$3" --out "$1" --force > /dev/null
  echo "$2 $3" > "$1/.done"
}

median() { sed -n 's/.*ms\/frame median \([0-9.]*\),.*/\1/p' "$out/last"; }

{
  echo "| map points | frames | first pose s | per-frame median ms | replay peak RSS MB |"
  echo "|---:|---:|---:|---:|---:|"
} > "$table"
for n in $sizes; do
  synth "$out/bag-map$n-1" 1 "$n"
  res=$(timed "$bin" replay "$out/bag-map$n-1" --out "$out/est" --method "$method" "${extra[@]}")
  read -r first _ <<< "$res"
  rm -rf "$out/est"
  synth "$out/bag-map$n" "$frames" "$n"
  best=""
  for _ in $(seq "$repeat"); do
    rm -rf "$out/est"
    res=$(timed "$bin" replay "$out/bag-map$n" --out "$out/est" --method "$method" "${extra[@]}")
    read -r _ rss <<< "$res"
    m=$(median)
    best=$(awk -v a="$best" -v b="$m" 'BEGIN {print (a == "" || b + 0 < a + 0) ? b : a}')
  done
  echo "| $n | $frames | $first | $best | $rss |" | tee -a "$table"
  rm -rf "$out/est"
done
{
  echo
  echo "| bag frames | map points | replay s | replay peak RSS MB | per-frame median ms | eval s | eval peak RSS MB |"
  echo "|---:|---:|---:|---:|---:|---:|---:|"
} >> "$table"
for len in $lengths; do
  synth "$out/bag-len$len" "$len" "$length_map"
  res=$(timed "$bin" replay "$out/bag-len$len" --out "$out/est" --method "$method" "${extra[@]}")
  read -r rwall rrss <<< "$res"
  med=$(median)
  res=$(timed "$bin" eval "$out/bag-len$len" --est "$out/est")
  read -r ewall erss <<< "$res"
  echo "| $len | $length_map | $rwall | $rrss | $med | $ewall | $erss |" | tee -a "$table"
  rm -rf "$out/est"
done
echo
cat "$table"
