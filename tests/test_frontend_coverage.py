"""Per-window outcomes of the front end, as the report's coverage section reads them."""

from __future__ import annotations

import numpy as np

from plsgraph.frontend.track import OUTCOMES
from plsgraph.report.coverage import _fig_coverage, outcome_counts


def test_outcome_counts_and_coverage_figure(tmp_path):
    code = np.array([0, 0, 1, 3, 3, 3, 0], dtype=np.int8)
    info = {"window_outcomes": {"t": np.arange(code.size) / 30.0, "code": code, "names": OUTCOMES}}
    assert outcome_counts(info) == {"detected": 3, "held_still": 1, "grid_not_found": 3}
    assert _fig_coverage(info, tmp_path) == "coverage.png" and (tmp_path / "coverage.png").stat().st_size > 0
    assert outcome_counts({}) == {}
