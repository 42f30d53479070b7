#!/usr/bin/env bash
# Regenerate the bundled sample recordings (+ .truth.yaml), events as evt3 EventPackets with wheel joint states and
# camera info:
#  - data/sample/realistic_sample.mcap: 15 s of driving with every realism effect at its default (docs/simulation.md):
#    pixel latency, hot pixels, flicker, lens distortion, a skid-steer robot whose effective track is 1.5 x the
#    nominal, wheel slip, odometry jitter; what the demo calibrates;
#  - data/sample/rich_sample.mcap: 10 s of the ideal simulator, the tests' clean recording.
# A 0.7-0.8 log-contrast threshold keeps each file at a few MB.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
mkdir -p data/sample
.venv/bin/plsgraph simulate --motion rich --duration 15 --seed 1 --td 0.03 --contrast 0.8 \
    --board acircles_4x11_a2 --event-format evt3 --out data/sample/realistic_sample.mcap --force
.venv/bin/plsgraph simulate --ideal --motion rich --duration 10 --seed 1 --td 0.03 --contrast 0.7 \
    --board acircles_4x11_a2 --event-format evt3 --out data/sample/rich_sample.mcap --force
