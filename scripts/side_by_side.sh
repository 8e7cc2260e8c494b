#!/usr/bin/env bash
# scripts/side_by_side.py with the eval venv's Python (`make py-venv`); same arguments, e.g.
#   scripts/side_by_side.sh ../shared/data/redkitchen-hard-val --out out/side-by-side --method consistency
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
python="${ANGLE_I2P_PYTHON:-$repo/.venv/bin/python}"
if [[ ! -x "$python" ]]; then
    echo "no Python with poselib and rosbags at $python: run \`make py-venv\` or set ANGLE_I2P_PYTHON" >&2
    exit 2
fi
exec "$python" "$repo/scripts/side_by_side.py" "$@"
