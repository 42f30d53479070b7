#!/usr/bin/env bash
# Create the project virtual environment (.venv) when missing and install plsgraph into it.
# Idempotent: a second run only re-checks the installation.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
stamp=.venv/.plsgraph-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[dev,dask]"
    touch "$stamp"
fi
# The editable install leaves plsgraph's own modules uncompiled (pip compiles the packages it copies, not a source
# folder). Compile them once here, as a normal install would: where PYTHONDONTWRITEBYTECODE is set, Python would
# otherwise compile every module again in every process of every run (the calibration, its front-end workers and
# its figure worker). Quick when nothing changed: only stale files are compiled again.
.venv/bin/python -m compileall -q plsgraph factors > /dev/null
