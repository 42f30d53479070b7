#!/usr/bin/env bash
# Regenerate the bundled sample recording data/sample/rich_sample.mcap (+ .truth.yaml): 10 s of simulated
# "rich" driving (forwards, backwards, turning) in front of the A2 circle board, events as evt3 EventPackets,
# wheel joint states and camera info, with a 0.7 log-contrast threshold to keep the file at a few MB.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
mkdir -p data/sample
.venv/bin/plsgraph simulate --ideal --motion rich --duration 10 --seed 1 --td 0.03 --contrast 0.7 \
    --board acircles_4x11_a2 --event-format evt3 --out data/sample/rich_sample.mcap --force
