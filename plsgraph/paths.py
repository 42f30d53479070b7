"""Locations of the bundled data (board definitions, camera presets, sample recording) and of the shared
real recordings used by the tests."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = REPO_ROOT / "data"
BOARDS_DIR = DATA_DIR / "boards"
CAMERAS_DIR = DATA_DIR / "cameras"


def _shared_real_dir() -> Path:
    """The folder of small real recordings: $PLSGRAPH_REAL_DATA, else ../shared/data/real beside the
    checkout, else the workplace's /work/shared/data/real (a clean checkout elsewhere still finds it)."""
    candidates = [os.environ.get("PLSGRAPH_REAL_DATA"), REPO_ROOT.parent / "shared" / "data" / "real",
                  Path("/work/shared/data/real")]
    for c in candidates:
        if c and Path(c).is_dir():
            return Path(c)
    return REPO_ROOT.parent / "shared" / "data" / "real"


SHARED_REAL_DIR = _shared_real_dir()
