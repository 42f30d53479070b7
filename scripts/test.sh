#!/usr/bin/env bash
# Set everything up (see setup.sh) and run the lint check and the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
.venv/bin/ruff check plsgraph factors tests scripts
# One pytest worker per processor (pytest-xdist; PYTEST_WORKERS=0 runs the suite in this process alone).
.venv/bin/python -m pytest -n "${PYTEST_WORKERS:-auto}" "$@"
