"""Camera frames taken while the wheel odometry says the base stood still.

A camera on a base that stands still sees no motion and makes no events, so an event camera's frames from such a
stretch come from something the calibration's model does not hold: a chassis that rocks or hums while the robot
idles, people passing, a flickering lamp. They carry no motion to calibrate against, and the rocking ones pulled the
refined time offset 35 ms (4.3 sigma) away from the truth on an independent recording whose robot stood parked for
its first 4 s and last 3 s with its chassis rocking (the closed form had it right): the refinement leaves them out.
"""

from __future__ import annotations

import numpy as np

from ..core.tracks import BaseTrack

#: Half the stretch (s) over which the base must stand still around a frame's time for the frame to count as still.
STILL_HALF_S = 0.25
#: Added to each side (s): the frame's time on the odometry clock comes from the closed form's offset, which can be
#: off by tens of milliseconds.
STILL_MARGIN_S = 0.1
#: Largest departure from the stretch's first pose (m, rad) that still counts as standing: a wheel encoder's tick
#: jitter is a fraction of a millimetre.
STILL_MOVE_M = 3e-3
STILL_TURN_RAD = float(np.radians(0.3))
#: Frames left out from which the refinement says so in a warning (fewer: report.json's ``discarded`` only).
WARN_FRAMES = 15
#: Frames left for the refinement below which none are left out (a recording mostly of a still base is diagnosed
#: by the rest of the pipeline, not emptied here).
MIN_FRAMES_LEFT = 50


def still_base(t_odom: np.ndarray, base: BaseTrack, half_s: float = STILL_HALF_S + STILL_MARGIN_S) -> np.ndarray:
    """Per time on the odometry clock (s): whether the base stood still over ``half_s`` either side of it (no sample
    in that stretch departs from the stretch's first pose by STILL_MOVE_M or turns by STILL_TURN_RAD). Near the
    odometry's first or last sample the stretch is cut there, and counts if at least STILL_HALF_S of it is left (a
    robot parked as the recording starts); times with less of it inside the odometry's span are not still (nothing
    says so)."""
    t = np.asarray(t_odom, dtype=float)
    still = np.zeros(t.size, dtype=bool)
    if base is None or len(base) < 2 or t.size == 0:
        return still
    tb = np.asarray(base.t, dtype=float)
    a, b = np.maximum(t - half_s, tb[0]), np.minimum(t + half_s, tb[-1])
    inside = (b - a >= min(half_s, STILL_HALF_S)) & (t >= tb[0]) & (t <= tb[-1])
    if not np.any(inside):
        return still
    T = np.asarray(base.T_world_base, dtype=float)
    xy = T[:, :2, 3]
    yaw = np.unwrap(np.arctan2(T[:, 1, 0], T[:, 0, 0]))
    i0 = np.maximum(np.searchsorted(tb, a[inside], side="left") - 1, 0)  # the sample before: a start inside counts
    i1 = np.minimum(np.searchsorted(tb, b[inside], side="right") + 1, tb.size)
    ok = np.zeros(i0.size, dtype=bool)
    for n, (j0, j1) in enumerate(zip(i0, i1, strict=True)):
        d = np.linalg.norm(xy[j0:j1] - xy[j0], axis=1).max(initial=0.0)
        w = np.abs(yaw[j0:j1] - yaw[j0]).max(initial=0.0)
        ok[n] = d < STILL_MOVE_M and w < STILL_TURN_RAD
    still[inside] = ok
    return still
