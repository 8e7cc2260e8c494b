#!/usr/bin/env bash
# Creates training/.venv with PyTorch 2.15.0 (CPU use) and the pinned libraries it links.
# Once per machine, ~4.4 GB; not part of CI. Usage: bash training/setup.sh
set -euo pipefail
cd "$(dirname "$0")"
python3 -m venv .venv
.venv/bin/pip install --quiet --disable-pip-version-check -r requirements.txt
.venv/bin/pip install --quiet --disable-pip-version-check --no-deps torch==2.15.0
.venv/bin/python -c "import torch; print('torch', torch.__version__, 'threads', torch.get_num_threads())"
