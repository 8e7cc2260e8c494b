#!/usr/bin/env bash
# Soak test of the live node: inside a private network namespace, play a bag in a loop at RATE×
# its recorded speed (the shared bags are 10 Hz, so 3 = 30 Hz) into `angle-i2p node` for
# DURATION seconds (the map is published once, the frame topics loop), sampling the node's RSS every PERIOD seconds; then print the samples and the
# node's last diagnostics (frames in/localized, drops and errors by reason). RSS should be flat
# after warm-up, and nothing dropped that the diagnostics do not count.
#   scripts/soak.sh [BAG] [RATE] [DURATION_S] [PERIOD_S]     (defaults: hard-val, 3, 600, 10)
set -euo pipefail
cd "$(dirname "$0")/.."
bag=${1:-../shared/data/redkitchen-hard-val}
rate=${2:-3}
duration=${3:-600}
period=${4:-10}
bin=${ANGLE_I2P_BIN:-$PWD/target/release/angle-i2p}
[ -x "$bin" ] || cargo build --release
dir=$(mktemp -d)
rec=$dir/rec
unshare -rn sh -c "
  ip link set lo up && ip link set lo multicast on
  export ROS_DOMAIN_ID=43
  '$bin' node --record '$rec' --ros-args -p diagnostics_period_ms:=1000 > '$rec.log' 2>&1 &
  node=\$!
  sleep 2
  # The map once (as a mapping system would), the frame topics in a loop.
  '$bin' play '$bag' --topic /map/points --wait-for /map/points --wait-timeout 20 > '$dir/map.log' 2>&1
  '$bin' play '$bag' --rate $rate --loop --wait-for /depth_prior/image --wait-timeout 20 \
    --topic /camera/camera_info --topic /camera/image_raw/compressed --topic /depth_prior/image \
    --topic /matcher/correspondences > '$dir/play.log' 2>&1 &
  play=\$!
  t=0
  while [ \$t -le $duration ]; do
    echo \"t=\${t}s node_rss_kb=\$(awk '/VmRSS/ {print \$2}' /proc/\$node/status)\"
    sleep $period
    t=\$((t + $period))
  done
  # SIGTERM: a background job of a non-interactive shell ignores SIGINT.
  kill -TERM \$play 2>/dev/null; wait \$play || true
  sleep 2
  kill -TERM \$node
  # The node prints 'recorded to' last; a zombie still answers kill -0, so watch the log.
  for i in \$(seq 120); do grep -q 'recorded to' '$rec.log' && break; sleep 1; done
  wait \$node || true
  echo \"node stopped \${i} s after SIGTERM\"
" | tee "$dir/rss.log"
echo "RSS samples: $dir/rss.log; node log: $rec.log"
"$bin" diagnostics "$rec"
