#!/usr/bin/env bash
# Set everything up (see setup.sh) and run the lint check and the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
.venv/bin/ruff check plsgraph factors tests scripts
.venv/bin/python -m pytest "$@"
