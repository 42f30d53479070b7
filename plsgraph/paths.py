"""Locations of the bundled data (board definitions, camera presets, sample recording)."""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = REPO_ROOT / "data"
BOARDS_DIR = DATA_DIR / "boards"
CAMERAS_DIR = DATA_DIR / "cameras"
SHARED_REAL_DIR = REPO_ROOT.parent / "shared" / "data" / "real"
