#!/usr/bin/env bash
# Set everything up (see setup.sh) and run the main job.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
out=${1:-out/demo}
.venv/bin/plsgraph reproduce-paper --quick --out "$out" --force
