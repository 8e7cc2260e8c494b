#!/usr/bin/env bash
# Sustained-rate benchmark of the live node: inside a private network namespace, play a bag at
# RATE× its recorded speed (the shared bags are 10 Hz, so 3 = 30 Hz) into `angle-i2p node`, then
# print the node's last diagnostics: frames in/localized, drops, most frames queued, latency.
#   [NODE_ARGS="-p method:=angle-i2p"] scripts/bench_live.sh [BAG] [RATE]
set -euo pipefail
cd "$(dirname "$0")/.."
bag=${1:-../shared/data/redkitchen-hard-val}
rate=${2:-3}
bin=$PWD/target/release/angle-i2p
[ -x "$bin" ] || cargo build --release
rec=$(mktemp -d)/rec
unshare -rn sh -c "
  ip link set lo up && ip link set lo multicast on
  export ROS_DOMAIN_ID=42
  '$bin' node --record '$rec' --ros-args -p diagnostics_period_ms:=200 ${NODE_ARGS:-} > '$rec.log' 2>&1 &
  node=\$!
  sleep 2
  '$bin' play '$bag' --rate $rate --wait-for /depth_prior/image --wait-timeout 20 --linger 1
  sleep 1
  kill -INT \$node; wait \$node
"
"$bin" diagnostics "$rec"
