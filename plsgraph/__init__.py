"""plsgraph: event camera to wheel-odometry extrinsic and time-offset calibration for ground robots.

    import plsgraph
    r = plsgraph.calibrate("run.mcap", board="acircles_4x11", wheel_radius=0.098, track_width=0.37)
    r.T_base_cam, r.time_offset_s, r.covariance, r.ok, r.problems

The public calls are imported on first use, so ``import plsgraph`` (and the command's start) stays fast.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

_LAZY = {
    "calibrate": "plsgraph.api",
    "calibrate_tracks": "plsgraph.api",
    "calibrate_to_dir": "plsgraph.api",
    "diagnose": "plsgraph.api",
    "compare": "plsgraph.api",
    "simulate": "plsgraph.api",
    "CalibrationResult": "plsgraph.result",
    "Diagnosis": "plsgraph.result",
    "Comparison": "plsgraph.result",
    "CalibrationOptions": "plsgraph.options",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'plsgraph' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
