"""The one place that decides whether a result is fit to use (``ok``) and, when not, says why in plain words.

calibrate, diagnose, compare and batch all ask this gate, so they agree on the same recording.
"""

from __future__ import annotations

from typing import Any

SPEED_SCALE_LIMIT = 0.2  # |odometry speed scale - 1| beyond which the distances disagree too much to trust


def problems_of(closed_form: Any, refinement: Any) -> list[str]:
    """Reasons the result must not be used as it is (empty: fine)."""
    problems: list[str] = []
    cf = closed_form
    if cf is not None and cf.degenerate:
        problems += [f"closed form: {r}" for r in cf.degenerate_reasons]
    speed = (getattr(cf, "odometry_scale", None) or {}).get("speed") if cf is not None else None
    if speed is not None and abs(speed - 1.0) > SPEED_SCALE_LIMIT:
        # Rotations do not care about scale, distances do: a board printed at another size than its YAML says,
        # or a wrong wheel radius, shows up as the camera and the wheels disagreeing on how far the robot went.
        problems.append(
            f"the camera sees the robot travel {1 / speed:.2f} x as far as the wheel odometry says: the board "
            "definition's size (square_size) or --wheel-radius is probably wrong, and the translation and time "
            "offset cannot be trusted"
        )
    ref = refinement
    if ref is not None and not ref.converged:
        problems.append("refinement did not converge; the covariance is withheld and the closed form is reported")
    for q, z in (getattr(ref, "disagreement", None) or {}).items():
        problems.append(f"refinement and closed form disagree on {q} by {z:.1f} sigma; check the recording (motion, "
                        "board detections) before trusting either")
    return problems
