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
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ..core.board import Board, load_board
from ..core.camera import CameraModel, davis346_default
from ..core.geometry import inv_T, make_T, rot_z, se3_exp
from ..core.tracks import BaseTrack, CameraTrack, Detections
from ..errors import InputError

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
    frames in which every board point projects inside the image.
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

    @property
    def R_base_cam(self) -> np.ndarray:
        return self.T_base_cam[:3, :3]

    def project_truth(self) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free pixels (m, N, 2) of the board points and a mask (m, N) of those inside the image."""
        T_cam_board = inv_T(self.T_board_cam)
        pts = self.board.points
        p_cam = np.einsum("mij,nj->mni", T_cam_board[:, :3, :3], pts) + T_cam_board[:, None, :3, 3]
        m, n = p_cam.shape[:2]
        in_front = p_cam[..., 2] > 1e-3
        safe = np.where(in_front[..., None], p_cam, np.array([0.0, 0.0, 1.0]))
        uv = self.camera.project(safe.reshape(-1, 3)).reshape(m, n, 2)
        inside = (
            in_front
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
        return simulate_events(t, self.camera_poses_at(t), self.camera, self.board, **options)


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
) -> SimRecording:
    """Simulate a differential-drive recording in front of a board.

    ``motion``: "rich" (forwards/backwards while turning), "straight" (forwards/backwards only) or
    "spin" (turning in place). ``slip`` is the standard deviation of a slowly varying relative error
    of each wheel's rotation (1 % = 0.01); ``encoder_ticks_per_rev`` quantizes the joint angles
    (0 disables it). The board is placed ~1.5 m ahead of the mean robot position, facing it, with its
    centre at ``board_height`` (default: the camera height). ``truth_rate`` is the rate of the exact
    base truth.
    """
    if duration <= 1.0 or odom_rate <= 0 or cam_rate <= 0 or truth_rate < odom_rate:
        raise InputError("simulate_robot: need duration > 1 s, positive rates and truth_rate >= odom_rate")
    if wheel_radius <= 0 or track_width <= 0 or slip < 0:
        raise InputError("simulate_robot: wheel_radius and track_width must be positive and slip >= 0")
    rng = np.random.default_rng(seed)
    board = board if board is not None else load_board("acircles_4x11")
    camera = camera if camera is not None else davis346_default()
    T_base_cam = default_T_base_cam() if T_base_cam is None else np.asarray(T_base_cam, dtype=float)
    if T_base_cam.shape != (4, 4):
        raise InputError(f"T_base_cam must be 4x4, got {T_base_cam.shape}")
    speed, heading = _motion_design(motion, rng)

    # Exact truth on a fine grid in the odometry clock.
    t = np.arange(int(round(duration * truth_rate)) + 1) / truth_rate
    v = speed.value(t)
    theta = heading.value(t) - heading.value(np.zeros(1))[0]  # the world is the odometry origin
    omega = heading.derivative(t)
    dt = np.diff(t)
    # Trapezoidal integration of the planar velocity; the error is O(dt^2) ~ 1e-7 m over a recording.
    vx, vy = v * np.cos(theta), v * np.sin(theta)
    x = np.r_[0.0, np.cumsum(0.5 * (vx[1:] + vx[:-1]) * dt)]
    y = np.r_[0.0, np.cumsum(0.5 * (vy[1:] + vy[:-1]) * dt)]
    T_world_base = make_T(rot_z(theta), np.stack([x, y, np.zeros_like(x)], axis=1))
    zeros = np.zeros_like(t)
    truth_base = BaseTrack(
        t,
        T_world_base,
        np.stack([v, zeros, zeros], axis=1),
        np.stack([zeros, zeros, omega], axis=1),
        info={"source": "sim-truth"},
    )

    # Board: ahead of the mean camera position along the mean heading, facing back at the robot.
    mean_heading = float(np.arctan2(np.mean(np.sin(theta)), np.mean(np.cos(theta))))
    cam_pos = (T_world_base @ T_base_cam)[:, :3, 3]
    centre_xy = cam_pos[:, :2].mean(axis=0) + _NOMINAL_RANGE * np.array([np.cos(mean_heading), np.sin(mean_heading)])
    height = float(T_base_cam[2, 3]) if board_height is None else float(board_height)
    fwd = np.array([np.cos(mean_heading), np.sin(mean_heading), 0.0])
    left = np.array([-np.sin(mean_heading), np.cos(mean_heading), 0.0])
    R_world_board = np.stack([-left, np.array([0.0, 0.0, -1.0]), fwd], axis=1)  # x right, y down, z away
    half = 0.5 * np.ptp(board.points, axis=0)
    origin = np.r_[centre_xy, height] - R_world_board @ (board.points.min(axis=0) + half)
    T_world_board = make_T(R_world_board, origin)

    # Camera stamps: a regular camera clock, kept where the odometry time t_cam + td lies in the truth.
    phase = rng.uniform(0.0, 1.0 / cam_rate)
    cam_t = np.arange(phase - td, duration - td, 1.0 / cam_rate)
    # Stamps stay non-negative in both clocks: recordings store unsigned nanoseconds.
    cam_t = cam_t[(cam_t + td >= t[0]) & (cam_t + td <= t[-1]) & (cam_t >= 0.0)]
    T_board_cam = inv_T(T_world_board) @ truth_base.poses_at(cam_t + td) @ T_base_cam

    # Wheels: exact angles from arc length and heading, then slip and quantization.
    wheel_t = np.arange(int(np.floor(duration * odom_rate)) + 1) / odom_rate
    s = speed.integral(wheel_t)
    th_w = heading.value(wheel_t) - heading.value(np.zeros(1))[0]
    phi_r = (s + 0.5 * track_width * th_w) / wheel_radius
    phi_l = (s - 0.5 * track_width * th_w) / wheel_radius
    if slip > 0:
        # A slowly varying relative error of each wheel's increments (a 1 s moving average of white noise).
        k = max(1, int(round(odom_rate)))
        kernel = np.ones(k) / np.sqrt(k)
        gains = [1.0 + slip * np.convolve(rng.normal(size=wheel_t.size + k - 1), kernel, "valid") for _ in range(2)]
        phi_r = phi_r[0] + np.r_[0.0, np.cumsum(np.diff(phi_r) * gains[0][1:])]
        phi_l = phi_l[0] + np.r_[0.0, np.cumsum(np.diff(phi_l) * gains[1][1:])]
    if encoder_ticks_per_rev:
        q = 2 * np.pi / encoder_ticks_per_rev
        phi_r = np.round(phi_r / q) * q
        phi_l = np.round(phi_l / q) * q

    rec = SimRecording(
        T_base_cam=T_base_cam,
        td=float(td),
        T_world_board=T_world_board,
        wheel_radius=float(wheel_radius),
        track_width=float(track_width),
        truth_base=truth_base,
        cam_t=cam_t,
        T_board_cam=T_board_cam,
        wheel_t=wheel_t,
        wheel_left=phi_l,
        wheel_right=phi_r,
        camera=camera,
        board=board,
        info={"motion": motion, "seed": seed, "duration": duration, "slip": slip, "ticks": encoder_ticks_per_rev},
    )
    inside = rec.project_truth()[1]
    centre_board = board.points.min(axis=0) + half
    rng_cam = np.linalg.norm(T_board_cam[:, :3, 3] - centre_board, axis=1)
    rec.info["visible_fraction"] = float(np.mean(inside.all(axis=1)))
    rec.info["range_m"] = (float(rng_cam.min()), float(rng_cam.max()))
    if rec.info["visible_fraction"] < 0.8:
        log.warning("board fully visible in only %.0f %% of camera frames", 100 * rec.info["visible_fraction"])
    return rec
