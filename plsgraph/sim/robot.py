"""Simulated recording of a differential-drive robot driving in front of a calibration board.

The motion is designed in closed form so that the whole simulation is vectorized: the heading
theta(t) and the forward speed v(t) are sums of sinusoids with incommensurate frequencies. Because
v and theta never share a frequency, the position x' = v cos(theta), y' = v sin(theta) has no
secular drift and the robot stays in a bounded region in front of the board while it drives
forwards, backwards and turns. The wheel angles follow in closed form from the arc length s(t) and
theta(t): phi_R = (s + theta b / 2) / r, phi_L = (s - theta b / 2) / r.

Frames: world z up, the floor is z = 0 and the world is the odometry origin (base pose at t = 0 is
the identity). Base: x forward, y left, z up. The board hangs vertically, facing the robot, with
its z axis pointing away from the robot (as OpenCV's calibrateCamera places targets).

Clocks: every truth quantity is kept in the odometry clock except the camera samples, which carry
camera stamps; a camera stamp t_cam belongs to odometry time t_cam + td.

Realism (plsgraph.sim.realism, docs/simulation.md): ``realism="realistic"`` (the default) adds a skid-steer
robot whose effective track and wheel radius differ from the nominal ones, correlated wheel slip, odometry
timestamp jitter and latency, a board at a chosen distance, turned and printed slightly off size, a lens with
chosen distortion, and a person driving with a joystick. ``realism="ideal"`` reproduces the original
recording exactly. With odometry latency lambda the odometry stamps are lambda later than the motion they
measure; the truth is kept in the stamps' clock, so ``td`` is the camera-to-motion offset plus lambda, the
offset an estimator sees.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np

from ..core.board import Board, load_board
from ..core.camera import CameraModel, davis346_default
from ..core.geometry import inv_T, make_T, rot_z, se3_exp
from ..core.tracks import BaseTrack, CameraTrack, Detections
from ..errors import InputError
from .realism import MotionStyle, Realism, resolve

log = logging.getLogger(__name__)

MOTIONS = ("rich", "straight", "spin")

# Mean distance (m) from the camera to the board centre the motions are designed around.
_NOMINAL_RANGE = 1.5


def default_T_base_cam(
    position: tuple[float, float, float] = (0.15, 0.02, 0.25),
    yaw_deg: float = 3.0,
    pitch_deg: float = 6.0,
    roll_deg: float = 1.0,
) -> np.ndarray:
    """A realistic forward-looking mount: optical z along base x, pitched down, slightly yawed and rolled.

    The angles are applied in the base frame (yaw about base z, pitch about base y with positive =
    looking down, roll about base x) to the nominal optical frame x_cam = -y_base, y_cam = -z_base.
    """
    R_nominal = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    from scipy.spatial.transform import Rotation

    R_tilt = Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_matrix()
    return make_T(R_tilt @ R_nominal, np.asarray(position, dtype=float))


@dataclass(frozen=True)
class _Sinusoids:
    """f(t) = sum_k a_k sin(2 pi f_k t + phase_k) with its integral and derivative in closed form."""

    amp: np.ndarray
    freq: np.ndarray
    phase: np.ndarray

    def value(self, t: np.ndarray) -> np.ndarray:
        arg = 2 * np.pi * self.freq[None, :] * t[:, None] + self.phase[None, :]
        return np.sin(arg) @ self.amp

    def derivative(self, t: np.ndarray) -> np.ndarray:
        arg = 2 * np.pi * self.freq[None, :] * t[:, None] + self.phase[None, :]
        return np.cos(arg) @ (self.amp * 2 * np.pi * self.freq)

    def integral(self, t: np.ndarray) -> np.ndarray:
        """Integral from 0 to t."""
        w = 2 * np.pi * self.freq
        arg = w[None, :] * t[:, None] + self.phase[None, :]
        return (np.cos(self.phase)[None, :] - np.cos(arg)) @ (self.amp / w)


def _motion_design(motion: str, rng: np.random.Generator) -> tuple[_Sinusoids, _Sinusoids]:
    """Speed and heading sinusoids of a motion profile; small random jitter keeps seeds distinct."""

    def jitter(x: np.ndarray, rel: float = 0.1) -> np.ndarray:
        return np.asarray(x, dtype=float) * (1.0 + rel * rng.uniform(-1.0, 1.0, np.size(x)))

    def phases(n: int) -> np.ndarray:
        return rng.uniform(0.0, 2 * np.pi, n)

    empty = _Sinusoids(np.zeros(1), np.ones(1), np.zeros(1))
    # Frequencies are chosen so that no speed frequency equals a heading frequency, their sum or their
    # difference, which would make the lateral drift v sin(theta) accumulate.
    v_rich = _Sinusoids(jitter([0.3, 0.08]), jitter([0.11, 0.37], 0.05), phases(2))
    th_rich = _Sinusoids(jitter(np.radians([16.0, 6.0])), jitter([0.19, 0.53], 0.05), phases(2))
    if motion == "rich":
        return v_rich, th_rich
    if motion == "straight":
        return v_rich, empty
    if motion == "spin":
        return empty, _Sinusoids(jitter(np.radians([18.0, 6.0])), jitter([0.21, 0.47], 0.05), phases(2))
    raise InputError(f"unknown motion {motion!r}; use one of {', '.join(MOTIONS)}")


@dataclass(frozen=True)
class SimRecording:
    """Truth and measurements of one simulated recording.

    Truth: ``T_base_cam``, ``td``, ``T_world_board``, ``wheel_radius``, ``track_width``;
    ``truth_base`` (BaseTrack at ``truth_rate`` in the odometry clock, with v and omega);
    ``cam_t`` (m,) camera stamps (camera clock) and ``T_board_cam`` (m, 4, 4) the true camera poses
    at odometry time cam_t + td.
    Measurements: ``wheel_t`` (odometry clock), ``wheel_left`` / ``wheel_right`` joint positions (rad)
    with encoder quantization and slip. Fast paths: ``detections()``, ``camera_track()``, ``gyro()``.
    ``info`` holds the design (motion, seed, noise) and ``visible_fraction``, the share of camera
    frames in which every board point projects inside the image (``board_in_view`` per frame).

    ``wheel_radius`` and ``track_width`` are the true effective values (what explains the wheel angles);
    ``wheel_radius_nominal`` and ``track_width_nominal`` what the user believes (the nominal radius and the
    geometric track). ``board`` is the nominal board (its YAML); the printed board is ``board_scale`` times
    larger (``board_true``), and the truth projections use it. ``td`` includes the odometry latency
    ``odom_latency``. ``realism`` holds the effects the recording was made with (None: ideal).
    """

    T_base_cam: np.ndarray
    td: float
    T_world_board: np.ndarray
    wheel_radius: float
    track_width: float
    truth_base: BaseTrack
    cam_t: np.ndarray
    T_board_cam: np.ndarray
    wheel_t: np.ndarray
    wheel_left: np.ndarray
    wheel_right: np.ndarray
    camera: CameraModel
    board: Board
    info: dict = field(default_factory=dict)
    wheel_radius_nominal: float | None = None
    track_width_nominal: float | None = None
    board_scale: float = 1.0
    odom_latency: float = 0.0
    realism: Realism | None = None

    @property
    def R_base_cam(self) -> np.ndarray:
        return self.T_base_cam[:3, :3]

    @property
    def board_true(self) -> Board:
        """The board as printed: the nominal board scaled by ``board_scale``."""
        return _scaled_board(self.board, self.board_scale)

    @property
    def board_in_view(self) -> np.ndarray:
        """(m,) bool per camera frame: every board point projects inside the image."""
        return self.project_truth()[1].all(axis=1)

    def truth_dict(self) -> dict:
        """Truth for the recording's truth YAML beyond T_base_cam and td: nominal vs true odometry intrinsics,
        board scale, timing, lens, visibility and every drawn effect."""
        r_nom = self.wheel_radius if self.wheel_radius_nominal is None else self.wheel_radius_nominal
        b_nom = self.track_width if self.track_width_nominal is None else self.track_width_nominal
        vis = self.board_in_view
        # Spans of camera frames without the whole board, in camera-clock seconds of the simulation.
        edges = np.flatnonzero(np.diff(np.r_[0, (~vis).astype(np.int8), 0]))
        spans = [[float(self.cam_t[a]), float(self.cam_t[b - 1])] for a, b in zip(edges[::2], edges[1::2], strict=True)]
        fx = self.realism
        return {
            "td": float(self.td),
            "td_clock_s": float(self.td - self.odom_latency),
            "odometry_latency_s": float(self.odom_latency),
            "wheel_radius": float(self.wheel_radius),
            "track_width": float(self.track_width),
            "wheel_radius_true": float(self.wheel_radius),
            "wheel_radius_nominal": float(r_nom),
            "track_width_effective": float(self.track_width),
            "track_width_nominal": float(b_nom),
            "track_ratio": float(self.track_width / b_nom),
            "board_scale": float(self.board_scale),
            "board_distance_m": self.info.get("board_distance_m"),
            "board_yaw_deg": self.info.get("board_yaw_deg"),
            "odometry_rate_hz": self.info.get("odom_rate"),
            "encoder_ticks_per_rev": self.info.get("ticks"),
            "camera_distortion": self.camera.dist.tolist(),
            "board_in_view_fraction": float(np.mean(vis)) if vis.size else 0.0,
            "board_out_of_view_s": spans,
            "realism": fx.to_dict() if fx is not None else {"name": "ideal"},
        }

    def project_truth(self) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free pixels (m, N, 2) of the board points and a mask (m, N) of those inside the image and seen from
        the printed side (from behind the board is blank, as the renderer draws it)."""
        T_cam_board = inv_T(self.T_board_cam)
        pts = self.board.points if self.board_scale == 1.0 else self.board_true.points
        p_cam = np.einsum("mij,nj->mni", T_cam_board[:, :3, :3], pts) + T_cam_board[:, None, :3, 3]
        m, n = p_cam.shape[:2]
        in_front = p_cam[..., 2] > 1e-3
        safe = np.where(in_front[..., None], p_cam, np.array([0.0, 0.0, 1.0]))
        uv = self.camera.project(safe.reshape(-1, 3)).reshape(m, n, 2)
        # The camera's position along the board's normal: circle grids are printed on the -z face, AprilGrids on +z.
        z = np.asarray(self.T_board_cam)[:, 2, 3]
        printed_side = (z < 0) if self.board.pattern == "asymmetric_circles" else (z > 0)
        inside = (
            in_front
            & printed_side[:, None]
            & (uv[..., 0] >= 0)
            & (uv[..., 0] <= self.camera.width - 1)
            & (uv[..., 1] >= 0)
            & (uv[..., 1] <= self.camera.height - 1)
        )
        return uv, inside

    def detections(self, noise_px: float = 0.3, seed: int = 1, only_complete: bool = False) -> Detections:
        """Board points seen by the camera at the camera stamps, with Gaussian pixel noise.

        Points outside the image (or behind the camera) are NaN. With ``only_complete`` frames in
        which part of the board is out of view are dropped, as a circle-grid detector would.
        """
        if noise_px < 0:
            raise InputError(f"noise_px must be >= 0, got {noise_px}")
        rng = np.random.default_rng(seed)
        uv, inside = self.project_truth()
        uv = uv + rng.normal(0.0, noise_px, uv.shape)
        uv[~inside] = np.nan
        det = Detections(self.cam_t, uv, self.board.points)
        if only_complete:
            det = det.subset(inside.all(axis=1))
        return det

    def camera_track(
        self,
        noise_rot_deg: float = 0.1,
        noise_trans_m: float = 0.002,
        seed: int = 2,
        only_visible: bool = True,
    ) -> CameraTrack:
        """Camera poses T_board_cam at the camera stamps with right-multiplied Gaussian noise.

        The covariance of each pose is the (diagonal) noise that was applied. ``only_visible`` keeps the
        frames in which the whole board is in view, as a detector plus PnP would.
        """
        if noise_rot_deg < 0 or noise_trans_m < 0:
            raise InputError("camera_track: noise levels must be >= 0")
        rng = np.random.default_rng(seed)
        m = self.cam_t.size
        xi = np.concatenate(
            [rng.normal(0.0, np.radians(noise_rot_deg), (m, 3)), rng.normal(0.0, noise_trans_m, (m, 3))], axis=1
        )
        T = self.T_board_cam @ se3_exp(xi)
        sig = np.r_[np.full(3, np.radians(noise_rot_deg)), np.full(3, noise_trans_m)]
        cov = np.broadcast_to(np.diag(np.maximum(sig, 1e-12) ** 2), (m, 6, 6)).copy()
        keep = np.ones(m, dtype=bool)
        if only_visible:
            keep = self.project_truth()[1].all(axis=1)
        return CameraTrack(
            self.cam_t[keep],
            T[keep],
            cov=cov[keep],
            info={"source": "sim", "noise_rot_deg": noise_rot_deg, "noise_trans_m": noise_trans_m},
        )

    def gyro(
        self, rate: float = 100.0, noise_rad_s: float = 0.005, bias_rad_s: float = 0.0, seed: int = 3
    ) -> tuple[np.ndarray, np.ndarray]:
        """A base-mounted gyroscope in the odometry clock: times (n,) and angular rates (n, 3) in base."""
        rng = np.random.default_rng(seed)
        tb = self.truth_base.t
        t = np.arange(tb[0], tb[-1], 1.0 / rate)
        w = np.stack([np.interp(t, tb, self.truth_base.omega[:, k]) for k in range(3)], axis=1)
        w = w + bias_rad_s + rng.normal(0.0, noise_rad_s, w.shape)
        return t, w

    def base_track_truth_at(self, t_odom: np.ndarray) -> np.ndarray:
        """True base poses at odometry times (interpolated from the high-rate truth)."""
        return self.truth_base.poses_at(t_odom)

    def camera_poses_at(self, t_cam: np.ndarray) -> np.ndarray:
        """True T_board_cam at camera stamps (camera clock), from the high-rate base truth."""
        t_cam = np.asarray(t_cam, dtype=float)
        return inv_T(self.T_world_board) @ self.truth_base.poses_at(t_cam + self.td) @ self.T_base_cam

    def events(self, trajectory_rate: float = 500.0, **options):
        """Event stream (camera clock) of the board seen along the true camera trajectory.

        The printed (scaled) board is rendered, with the recording's sensor and scene effects applied to
        ``params`` (default EventSimParams()).
        Calls ``plsgraph.sim.events.simulate_events`` with the true camera poses sampled at
        ``trajectory_rate`` Hz over the camera stamps (the simulator interpolates between them linearly, so a
        dense trajectory keeps the motion's curvature); ``options`` (params, seed, progress) are passed on.
        """
        try:
            from .events import simulate_events
        except ImportError as exc:  # the event simulator is a separately written module
            raise InputError(
                "the event-level simulation needs plsgraph.sim.events.simulate_events, which is not available; "
                "use detections() or camera_track() instead"
            ) from exc
        if trajectory_rate <= 0:
            raise InputError(f"trajectory_rate must be positive, got {trajectory_rate}")
        t0, t1 = float(self.cam_t[0]), float(self.cam_t[-1])
        t = np.r_[np.arange(t0, t1, 1.0 / trajectory_rate), t1]
        t = t[np.r_[np.diff(t) > 1e-9, True]]
        if self.realism is not None:
            options["params"] = self.realism.event_params(options.get("params"))
        return simulate_events(t, self.camera_poses_at(t), self.camera, self.board_true, **options)


def _scaled_board(board: Board, scale: float) -> Board:
    """``board`` printed ``scale`` times its nominal size (points scale about the board origin)."""
    if scale == 1.0:
        return board
    return dataclasses.replace(
        board,
        square_size=board.square_size * scale,
        circle_diameter=board.circle_diameter * scale,
        tag_size=board.tag_size * scale,
    )


def _board_pose(points: np.ndarray, centre_xy: np.ndarray, height: float, heading: float, yaw_deg: float) -> np.ndarray:
    """T_world_board of a vertical board centred at (centre_xy, height), facing back along ``heading``, then
    turned by ``yaw_deg`` about its vertical axis."""
    fwd = np.array([np.cos(heading), np.sin(heading), 0.0])
    left = np.array([-np.sin(heading), np.cos(heading), 0.0])
    R_world_board = np.stack([-left, np.array([0.0, 0.0, -1.0]), fwd], axis=1)  # x right, y down, z away
    if yaw_deg != 0.0:
        R_world_board = rot_z(np.radians(yaw_deg)) @ R_world_board
    half = 0.5 * np.ptp(points, axis=0)
    origin = np.r_[centre_xy, height] - R_world_board @ (points.min(axis=0) + half)
    return make_T(R_world_board, origin)


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def _joystick_drive(
    motion: str,
    style: MotionStyle,
    t: np.ndarray,
    T_base_cam: np.ndarray,
    board_xy: np.ndarray,
    distance: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """v, omega, theta, x, y on the truth grid ``t`` of a person driving with a joystick in front of the board.

    Segment by segment the driver looks at where the board is and picks a command: turn back to the board if it
    is off-centre (or out of view), drive towards or away from it if too far or too near, else a random
    forward, reverse, turn, arc or stop. A turn sometimes swings the board out of the image
    (``look_away_prob``). The robot follows each command with a first-order lag (``smoothing_s``), so speeds
    and turn rates are continuous; within a segment everything is in closed form, so only segments loop.
    "straight" never turns and "spin" never drives.
    """
    n = t.size
    dt = float(t[1] - t[0])
    v, w, th, x, y = (np.zeros(n) for _ in range(5))
    tau = style.smoothing_s
    vm, wm = style.v_max_mps, style.omega_max_rad_s
    can_turn, can_drive = motion != "straight", motion != "spin"
    p_cam = T_base_cam[:2, 3]
    z_cam = T_base_cam[:3, :3] @ np.array([0.0, 0.0, 1.0])
    psi_cam = float(np.arctan2(z_cam[1], z_cam[0]))
    near, far = max(0.5, distance - 0.35), distance + 0.35
    k0 = 0
    while k0 < n - 1:
        c, s_ = np.cos(th[k0]), np.sin(th[k0])
        cam = np.array([x[k0], y[k0]]) + np.array([[c, -s_], [s_, c]]) @ p_cam
        delta = board_xy - cam
        d = float(np.hypot(*delta))
        beta = _wrap(float(np.arctan2(delta[1], delta[0])) - th[k0] - psi_cam)
        dur = style.segment_s * rng.uniform(0.5, 1.5)
        vc = wc = 0.0
        if can_turn and abs(beta) > np.radians(12.0):
            wc = float(np.clip(1.3 * beta / dur, -wm, wm))
            if can_drive and rng.random() < 0.5:
                vc = (1.0 if d > distance else -1.0) * rng.uniform(0.0, 0.3) * vm
        elif can_drive and (d > far or d < near):
            vc = (1.0 if d > far else -1.0) * rng.uniform(0.5, 1.0) * vm
            wc = float(np.clip(beta / dur, -wm, wm)) if can_turn else 0.0
        else:
            acts = (["forward", "reverse", "stop"] if can_drive else ["stop"]) + (["turn", "turn"] if can_turn else [])
            if can_drive and can_turn:
                acts.append("arc")
            act = acts[int(rng.integers(0, len(acts)))]
            sign = 1.0 if rng.random() < 0.5 else -1.0
            if act in ("forward", "reverse"):
                room = (d - near) if act == "forward" else (far - d)
                speed = min(rng.uniform(0.4, 1.0) * vm, max(room, 0.05) / dur + 0.05)
                vc = speed if act == "forward" else -speed
            elif act == "turn":
                if rng.random() < style.look_away_prob:
                    angle = np.radians(rng.uniform(45.0, 70.0))
                    dur = max(dur, angle / (0.9 * wm))
                else:
                    angle = np.radians(rng.uniform(8.0, 25.0))
                wc = float(np.clip(sign * angle / dur, -wm, wm))
            elif act == "arc":
                vc = sign * rng.uniform(0.3, 0.8) * vm
                wc = (1.0 if rng.random() < 0.5 else -1.0) * rng.uniform(0.3, 0.8) * wm
                dur *= 0.6
            else:
                dur *= 0.6
        k1 = min(n - 1, k0 + max(2, int(round(dur / dt))))
        dtk = t[k0 : k1 + 1] - t[k0]
        e = np.exp(-dtk / tau)
        v[k0 : k1 + 1] = vc + (v[k0] - vc) * e
        w[k0 : k1 + 1] = wc + (w[k0] - wc) * e
        th[k0 : k1 + 1] = th[k0] + wc * dtk + (w[k0] - wc) * tau * (1.0 - e)
        vx, vy = v[k0 : k1 + 1] * np.cos(th[k0 : k1 + 1]), v[k0 : k1 + 1] * np.sin(th[k0 : k1 + 1])
        x[k0 + 1 : k1 + 1] = x[k0] + np.cumsum(0.5 * (vx[1:] + vx[:-1]) * dt)
        y[k0 + 1 : k1 + 1] = y[k0] + np.cumsum(0.5 * (vy[1:] + vy[:-1]) * dt)
        k0 = k1
    return v, w, th, x, y


def _ou_gains(
    t: np.ndarray, omega: np.ndarray, sigma: float, tau: float, turn_gain: float, rng: np.random.Generator
) -> np.ndarray:
    """(2, n) multiplicative gains 1 + e(t) of the two wheels' increments: e is an Ornstein-Uhlenbeck process
    (correlation time ``tau``) whose std ``sigma (1 + turn_gain |omega|)`` grows when the robot turns."""
    from scipy.signal import lfilter

    dt = np.diff(t, prepend=t[0] - (t[1] - t[0]))
    a = np.exp(-np.median(dt) / tau)
    z0 = rng.standard_normal((2, 1))
    z, _ = lfilter([np.sqrt(1.0 - a * a)], [1.0, -a], rng.standard_normal((2, t.size)), axis=1, zi=a * z0)
    return 1.0 + sigma * (1.0 + turn_gain * np.abs(omega))[None, :] * z


def on_floor(T_world_base: np.ndarray, slope_deg: float, wavelength_m: float, seed: int) -> np.ndarray:
    """Planar base poses put on an undulating floor: height h(x, y) a sum of three plane waves (random directions,
    wavelengths 0.7-1.4 ``wavelength_m``, phases) scaled to an RMS slope of ``slope_deg``; each pose is lifted to
    the floor's height and tilted so that its z axis is the floor's normal (heading kept). The floor is drawn from
    its own generator (``seed``), so the rest of a simulation's draws do not change."""
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0xF1002])
    ang = rng.uniform(0.0, 2.0 * np.pi, 3)
    u = np.stack([np.cos(ang), np.sin(ang)], axis=1)  # (3, 2)
    k = 2.0 * np.pi / (wavelength_m * rng.uniform(0.7, 1.4, 3))  # wavenumbers
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    amp = np.tan(np.radians(slope_deg)) / np.sqrt(np.sum(k**2) / 2.0) * np.ones(3)  # equal amplitudes
    p = T_world_base[:, :2, 3]
    arg = p @ (u * k[:, None]).T + phase  # (n, 3)
    h = np.sin(arg) @ amp
    grad = (np.cos(arg) * (amp * k)) @ u  # (n, 2)
    normal = np.stack([-grad[:, 0], -grad[:, 1], np.ones(len(p))], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    # The smallest rotation taking z to the normal (Rodrigues), then the heading.
    axis = np.stack([-normal[:, 1], normal[:, 0], np.zeros(len(p))], axis=1)  # z x n
    s = np.linalg.norm(axis, axis=1)
    c = normal[:, 2]
    K = np.zeros((len(p), 3, 3))
    a = np.divide(axis, s[:, None], out=np.zeros_like(axis), where=s[:, None] > 0)
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 0], K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -a[:, 2], a[:, 1], a[:, 2], -a[:, 0], \
        -a[:, 1], a[:, 0]
    R_tilt = np.eye(3) + s[:, None, None] * K + (1.0 - c)[:, None, None] * (K @ K)
    out = T_world_base.copy()
    out[:, :3, :3] = R_tilt @ T_world_base[:, :3, :3]
    out[:, 2, 3] = T_world_base[:, 2, 3] + h
    return out


def simulate_robot(
    motion: str = "rich",
    duration: float = 20.0,
    seed: int = 0,
    T_base_cam: np.ndarray | None = None,
    td: float = 0.03,
    odom_rate: float = 50.0,
    cam_rate: float = 30.0,
    board: Board | None = None,
    camera: CameraModel | None = None,
    wheel_radius: float = 0.098,
    track_width: float = 0.37,
    encoder_ticks_per_rev: int = 4096,
    slip: float = 0.005,
    truth_rate: float = 1000.0,
    board_height: float | None = None,
    realism: Realism | str = "realistic",
) -> SimRecording:
    """Simulate a differential-drive (skid-steer) recording in front of a board.

    ``motion``: "rich" (forwards/backwards while turning), "straight" (forwards/backwards only) or
    "spin" (turning in place). ``slip`` is the standard deviation of a slowly varying relative error
    of each wheel's rotation (1 % = 0.01); ``encoder_ticks_per_rev`` quantizes the joint angles
    (0 disables it). The board is placed ~1.5 m ahead of the mean robot position, facing it, with its
    centre at ``board_height`` (default: the camera height). ``truth_rate`` is the rate of the exact
    base truth.

    ``realism``: "realistic" (default, every effect of plsgraph.sim.realism at its typical value), "ideal"
    (the original clean recording, exactly) or a :class:`~plsgraph.sim.realism.Realism` (e.g. from
    ``draw_realism`` or ``only``). ``wheel_radius`` and ``track_width`` are then the nominal (geometric)
    values a user would pass; the robot's true effective ones follow from the realism's robot effects. With
    a joystick motion style the robot starts at the origin facing the board at the scene's board distance;
    otherwise the board is placed as above at that distance.
    """
    fx = resolve(realism)
    rob, scene = fx.robot, fx.scene
    if duration <= 1.0 or odom_rate <= 0 or cam_rate <= 0 or truth_rate < odom_rate:
        raise InputError("simulate_robot: need duration > 1 s, positive rates and truth_rate >= odom_rate")
    if wheel_radius <= 0 or track_width <= 0 or slip < 0:
        raise InputError("simulate_robot: wheel_radius and track_width must be positive and slip >= 0")
    if motion not in MOTIONS:
        raise InputError(f"unknown motion {motion!r}; use one of {', '.join(MOTIONS)}")
    rng = np.random.default_rng(seed)
    # Realism draws from its own generator, so that the ideal recording of a seed stays what it was.
    rng_fx = np.random.default_rng([seed, 2])
    board = board if board is not None else load_board("acircles_4x11")
    camera = fx.sensor.camera(camera if camera is not None else davis346_default())
    T_base_cam = default_T_base_cam() if T_base_cam is None else np.asarray(T_base_cam, dtype=float)
    if T_base_cam.shape != (4, 4):
        raise InputError(f"T_base_cam must be 4x4, got {T_base_cam.shape}")
    if rob.odom_rate_hz is not None:
        odom_rate = float(rob.odom_rate_hz)
    ticks = encoder_ticks_per_rev if rob.encoder_ticks_per_rev is None else int(rob.encoder_ticks_per_rev)
    r_true = wheel_radius * (1.0 + rob.wheel_radius_error)
    b_eff = track_width * rob.track_ratio
    board_true = _scaled_board(board, scene.board_scale)
    height = float(T_base_cam[2, 3]) if board_height is None else float(board_height)

    t = np.arange(int(round(duration * truth_rate)) + 1) / truth_rate
    wheel_t = np.arange(int(np.floor(duration * odom_rate)) + 1) / odom_rate  # sample times (motion clock)
    if fx.motion.joystick:
        # The robot starts at the origin, the board ahead of the camera along its optical axis.
        z_cam = T_base_cam[:3, :3] @ np.array([0.0, 0.0, 1.0])
        psi = float(np.arctan2(z_cam[1], z_cam[0]))
        centre_xy = T_base_cam[:2, 3] + scene.board_distance_m * np.array([np.cos(psi), np.sin(psi)])
        v, omega, theta, x, y = _joystick_drive(motion, fx.motion, t, T_base_cam, centre_xy, scene.board_distance_m,
                                                rng_fx)
        T_world_board = _board_pose(board_true.points, centre_xy, height, psi, scene.board_yaw_deg)
        s_truth = np.r_[0.0, np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))]
        s = np.interp(wheel_t, t, s_truth)
        th_w = np.interp(wheel_t, t, theta)
    else:
        speed, heading = _motion_design(motion, rng)
        # Exact truth on a fine grid in the odometry clock.
        v = speed.value(t)
        theta = heading.value(t) - heading.value(np.zeros(1))[0]  # the world is the odometry origin
        omega = heading.derivative(t)
        dt = np.diff(t)
        # Trapezoidal integration of the planar velocity; the error is O(dt^2) ~ 1e-7 m over a recording.
        vx, vy = v * np.cos(theta), v * np.sin(theta)
        x = np.r_[0.0, np.cumsum(0.5 * (vx[1:] + vx[:-1]) * dt)]
        y = np.r_[0.0, np.cumsum(0.5 * (vy[1:] + vy[:-1]) * dt)]
        s = speed.integral(wheel_t)
        th_w = heading.value(wheel_t) - heading.value(np.zeros(1))[0]
    T_world_base = make_T(rot_z(theta), np.stack([x, y, np.zeros_like(x)], axis=1))
    if scene.floor_slope_deg > 0:
        T_world_base = on_floor(T_world_base, scene.floor_slope_deg, scene.floor_wavelength_m, seed)
    zeros = np.zeros_like(t)
    # With odometry latency the truth moves into the clock of the odometry stamps (lambda later).
    lam = float(rob.odom_latency_s)
    truth_base = BaseTrack(
        t + lam if lam else t,
        T_world_base,
        np.stack([v, zeros, zeros], axis=1),
        np.stack([zeros, zeros, omega], axis=1),
        info={"source": "sim-truth"},
    )
    td_total = float(td) + lam

    if not fx.motion.joystick:
        # Board: ahead of the mean camera position along the mean heading, facing back at the robot.
        mean_heading = float(np.arctan2(np.mean(np.sin(theta)), np.mean(np.cos(theta))))
        cam_pos = (T_world_base @ T_base_cam)[:, :3, 3]
        centre_xy = cam_pos[:, :2].mean(axis=0) + scene.board_distance_m * np.array(
            [np.cos(mean_heading), np.sin(mean_heading)]
        )
        T_world_board = _board_pose(board_true.points, centre_xy, height, mean_heading, scene.board_yaw_deg)

    # Camera stamps: a regular camera clock, kept where the odometry time t_cam + td lies in the truth.
    phase = rng.uniform(0.0, 1.0 / cam_rate)
    cam_t = np.arange(phase - td, duration - td, 1.0 / cam_rate)
    # Stamps stay non-negative in both clocks: recordings store unsigned nanoseconds.
    cam_t = cam_t[(cam_t + td >= t[0]) & (cam_t + td <= t[-1]) & (cam_t >= 0.0)]
    T_board_cam = inv_T(T_world_board) @ truth_base.poses_at(cam_t + td_total) @ T_base_cam

    # Wheels: a skid-steer robot turns by the effective track, its wheels roll with the true radius.
    phi_r = (s + 0.5 * b_eff * th_w) / r_true
    phi_l = (s - 0.5 * b_eff * th_w) / r_true
    if slip > 0:
        # A slowly varying relative error of each wheel's increments (a 1 s moving average of white noise).
        k = max(1, int(round(odom_rate)))
        kernel = np.ones(k) / np.sqrt(k)
        gains = [1.0 + slip * np.convolve(rng.normal(size=wheel_t.size + k - 1), kernel, "valid") for _ in range(2)]
        phi_r = phi_r[0] + np.r_[0.0, np.cumsum(np.diff(phi_r) * gains[0][1:])]
        phi_l = phi_l[0] + np.r_[0.0, np.cumsum(np.diff(phi_l) * gains[1][1:])]
    if rob.slip_sigma > 0:
        g = _ou_gains(wheel_t, np.interp(wheel_t, t, omega), rob.slip_sigma, rob.slip_tau_s, rob.slip_turn_gain,
                      rng_fx)
        phi_r = phi_r[0] + np.r_[0.0, np.cumsum(np.diff(phi_r) * g[0, 1:])]
        phi_l = phi_l[0] + np.r_[0.0, np.cumsum(np.diff(phi_l) * g[1, 1:])]
    if ticks:
        q = 2 * np.pi / ticks
        phi_r = np.round(phi_r / q) * q
        phi_l = np.round(phi_l / q) * q
    if lam or rob.odom_jitter_s > 0:
        jitter = np.clip(rng_fx.normal(0.0, rob.odom_jitter_s, wheel_t.size), -0.4 / odom_rate, 0.4 / odom_rate)
        wheel_t = np.maximum(wheel_t + lam + jitter, 0.0)  # stamps are unsigned

    rec = SimRecording(
        T_base_cam=T_base_cam,
        td=td_total,
        T_world_board=T_world_board,
        wheel_radius=float(r_true),
        track_width=float(b_eff),
        truth_base=truth_base,
        cam_t=cam_t,
        T_board_cam=T_board_cam,
        wheel_t=wheel_t,
        wheel_left=phi_l,
        wheel_right=phi_r,
        camera=camera,
        board=board,
        info={"motion": motion, "seed": seed, "duration": duration, "slip": slip, "ticks": ticks,
              "odom_rate": odom_rate, "realism": fx.name, "board_distance_m": scene.board_distance_m,
              "board_yaw_deg": scene.board_yaw_deg},
        wheel_radius_nominal=float(wheel_radius),
        track_width_nominal=float(track_width),
        board_scale=float(scene.board_scale),
        odom_latency=lam,
        realism=fx,
    )
    inside = rec.project_truth()[1]
    pts = board_true.points
    centre_board = pts.min(axis=0) + 0.5 * np.ptp(pts, axis=0)
    rng_cam = np.linalg.norm(T_board_cam[:, :3, 3] - centre_board, axis=1)
    rec.info["visible_fraction"] = float(np.mean(inside.all(axis=1)))
    rec.info["range_m"] = (float(rng_cam.min()), float(rng_cam.max()))
    if rec.info["visible_fraction"] < 0.8:
        log.warning("board fully visible in only %.0f %% of camera frames", 100 * rec.info["visible_fraction"])
    return rec
