"""Where the tests and scripts find data that is not part of the installed package: the checkout's sample
recording and the shared real recordings (``$PLSGRAPH_REAL_DATA``, else ``../shared/data/real`` beside the
checkout). Tests that need the real recordings skip with the reason when the folder is absent."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = REPO_ROOT / "data"
SAMPLE = DATA_DIR / "sample" / "rich_sample.mcap"


def _shared_real_dir() -> Path:
    env = os.environ.get("PLSGRAPH_REAL_DATA")
    if env:
        return Path(env)
    return REPO_ROOT.parent / "shared" / "data" / "real"


SHARED_REAL_DIR = _shared_real_dir()
SHARED_REAL_MISSING = (
    f"shared real recordings not found at {SHARED_REAL_DIR} (set PLSGRAPH_REAL_DATA to their folder)"
)
