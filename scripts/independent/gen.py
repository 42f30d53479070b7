#!/usr/bin/env python3
"""Independent DVS346 + Jackal wheel-odometry recording generator (written from scratch).

One seed -> one ROS 2 MCAP (dvs_msgs/EventArray, sensor_msgs/JointState, sensor_msgs/CameraInfo)
plus <rec>.indep_truth.yaml and <rec>.indep_traj.npz (truth trajectory, for checking).

World frame: z up, floor z = 0. Base frame: x forward, y left, z up, origin on the floor between
the wheels. Camera optical frame: x right, y down, z forward. Time: world time = odometry clock;
a camera sample stamped t_cam belongs to odometry time t_cam + td.
"""
from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import cv2
import numpy as np
import yaml
from mcap_ros2.writer import Writer
from scipy.spatial.transform import Rotation as Rot

W, H = 346, 260
# scenario switches (all off by default -> output identical to gen.py)
SC: dict = dict(park_start=0.0, park_end=0.0, mount_yaw=0.0, mount_pitch=0.0, mount_roll=0.0, cam_z=None,
                far=False, extend_plan=False, js_rate=None, js_jitter=0.0, lookaway=False,
                board_bump=None, board_scale=1.0, gentle=None, diff_drive=False, second_board=None, walker=None,
                board_drift=None, cinfo_nodist=False, cinfo_focal=1.0, wheel_asym=0.0)
EPOCH_NS = 1_700_000_000_000_000_000
SEP = "=" * 80 + "\n"
TIME_DEF = "int32 sec\nuint32 nanosec\n"
HEADER_DEF = "builtin_interfaces/Time stamp\nstring frame_id\n"
DEP_HEADER = SEP + "MSG: std_msgs/Header\n" + HEADER_DEF + SEP + "MSG: builtin_interfaces/Time\n" + TIME_DEF
EVENT_ARRAY_DEF = ("std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n" + DEP_HEADER
                   + SEP + "MSG: dvs_msgs/Event\nuint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\n")
JOINT_DEF = ("std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n"
             + DEP_HEADER)
CINFO_DEF = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
             "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\n"
             "sensor_msgs/RegionOfInterest roi\n" + DEP_HEADER + SEP + "MSG: sensor_msgs/RegionOfInterest\n"
             "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n")

# board (acircles_4x11_a2): OpenCV asymmetric grid, point k = i*cols + j at ((2j + i%2) s, i s, 0)
B_COLS, B_ROWS, B_S, B_DIAM = 4, 11, 0.05, 0.04


def board_points() -> np.ndarray:
    i, j = np.divmod(np.arange(B_ROWS * B_COLS), B_COLS)
    return np.stack([(2 * j + i % 2) * B_S, i * B_S, np.zeros(i.size)], axis=-1)


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


# ----------------------------------------------------------------------------- parameters
def make_params(seed: int, duration: float) -> dict:
    rng = np.random.default_rng(seed)
    p: dict = {"seed": seed, "duration": duration}
    f = 320.0 * (1 + rng.uniform(-0.04, 0.04))
    p["K"] = np.array([[f, 0, 173 + rng.uniform(-5, 5)], [0, f * (1 + rng.uniform(-0.006, 0.006)),
                                                           130 + rng.uniform(-5, 5)], [0, 0, 1]])
    p["D"] = np.array([rng.uniform(-0.12, -0.03), rng.uniform(0.0, 0.06), rng.normal(0, 3e-4),
                       rng.normal(0, 3e-4), 0.0])
    # mount: nominal optical axes, then small roll/pitch/yaw about the base axes
    R_nom = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    rpy = np.array([rng.uniform(-4, 4), rng.uniform(-6, 3), rng.uniform(-5, 5)])  # deg about base x, y, z
    rpy = rpy + np.array([SC["mount_roll"], SC["mount_pitch"], SC["mount_yaw"]])  # extra mount angles
    R_mis = Rot.from_euler("ZYX", [rpy[2], rpy[1], rpy[0]], degrees=True).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R_mis @ R_nom
    T[:3, 3] = [0.15 + rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), 0.25 + rng.uniform(-0.04, 0.04)]
    if math.cos(math.radians(SC["mount_yaw"])) < -0.5:  # rear camera sits at the back of the robot
        T[0, 3] = -T[0, 3]
    if SC["cam_z"] is not None:  # camera on a mast
        T[2, 3] = SC["cam_z"] + (T[2, 3] - 0.25)
    p["T_base_cam"], p["mount_rpy_deg"] = T, rpy
    p["td"] = float(rng.choice([-1, 1]) * rng.uniform(0.012, 0.09))
    p["r_eff"] = 0.098 * (1 + rng.uniform(-0.05, 0.05))
    p["b_eff"] = 0.37 * rng.uniform(1.3, 1.8)
    if SC["diff_drive"]:  # two-wheel differential drive: no skid, effective track ~ nominal
        p["b_eff"] = 0.37 * (1 + np.random.default_rng([seed, 3031]).uniform(-0.01, 0.01))
    # sensor
    p["C"] = rng.uniform(0.2, 0.3)
    p["C_mismatch"] = rng.uniform(0.05, 0.10)
    p["refractory"] = rng.uniform(1e-4, 5e-4)
    p["ba_rate"] = rng.uniform(0.1, 1.0)
    p["n_hot"] = int(rng.integers(3, 9))
    p["tau_bright"] = rng.uniform(0.2e-3, 0.5e-3)  # photoreceptor time constant at white paper
    # board pose: centre of the grid in front of the robot start, facing it (yaw +-15 deg)
    p["board_yaw"] = rng.uniform(-15, 15)
    p["board_centre_h"] = rng.uniform(0.36, 0.46)
    p["room"] = dict(xmin=-7.0, xmax=rng.uniform(1.0, 2.5), ymax=rng.uniform(2.5, 4.0), zmax=2.6)
    p["start"] = dict(d=rng.uniform(1.8, 2.4), phi=rng.uniform(-0.2, 0.2))
    if SC["far"]:  # board farther away (2.5-3.8 m)
        p["start"]["d"] = 2.8 + (p["start"]["d"] - 1.8) / 0.6 * 0.6
    return p


# ----------------------------------------------------------------------------- trajectory
def simulate_trajectory(p: dict, rng: np.random.Generator, dt: float):
    """Unicycle (true base motion) driven by a controller that keeps the board in view."""
    mg = 0.3 if abs(p["td"]) < 0.25 else abs(p["td"]) + 0.3  # a large |td| needs a wider margin
    T = p["duration"] + 2 * mg  # a margin either side
    n = int(round(T / dt)) + 1
    tt = np.arange(n) * dt - mg
    by = math.radians(p["board_yaw"])
    Bc = np.zeros(2)                          # board grid centre (x, y) in the world
    normal_out = np.array([-math.cos(by), -math.sin(by)])  # from the board towards the robot side
    phi0 = p["start"]["phi"]
    ang = math.atan2(normal_out[1], normal_out[0]) + phi0
    P = Bc + p["start"]["d"] * np.array([math.cos(ang), math.sin(ang)])
    myaw = math.radians(SC["mount_yaw"])
    side = abs(math.cos(myaw)) < 0.5  # sideways camera -> tangential driving mode
    cy = 1.0 if side else float(np.sign(math.cos(myaw)))
    th = math.atan2(Bc[1] - P[1], Bc[0] - P[0]) + rng.uniform(-0.1, 0.1) - myaw
    # segment plan
    segs, t_acc = [], tt[0] + SC["park_start"]
    kinds = ["straight", "spin", "arc", "scurve"]
    order = list(rng.permutation(kinds)) + list(rng.choice(kinds, 12))
    if SC["extend_plan"]:
        order += list(np.random.default_rng([p["seed"], 515]).choice(kinds, 40))
    if SC["lookaway"]:  # two segments where the robot turns the camera far off the board and back
        order[5], order[10] = "away", "away"
    if SC["gentle"] is not None:  # low yaw excitation: no spins, turning amplitudes scaled by the factor
        order = ["straight" if k == "spin" else k for k in order]
    d_lo, d_hi = (2.5, 3.8) if SC["far"] else (1.3, 2.9)
    d_cur = p["start"]["d"]
    for k in order:
        dur = rng.uniform(2.0, 3.5)
        d_new = d_cur if k in ("spin", "away") else float(np.clip(d_cur + rng.choice([-1, 1]) * rng.uniform(0.5, 1.2), d_lo, d_hi))
        if not d_lo <= d_new <= d_hi or abs(d_new - d_cur) < 0.3 and k not in ("spin", "away"):
            d_new = d_hi if d_cur < (d_lo + d_hi) / 2 - 0.0 else d_lo + 0.05
        A = rng.uniform(0.2, 0.3)
        u_rate = rng.uniform(0.6, 1.0)
        if p.get("fast"):  # harsh: same draw mapped to a peak rate of 1.0-1.5 rad/s
            u_rate = 1.0 + (u_rate - 0.6) * 1.25
        Pd = 2 * np.pi * A / u_rate      # peak rate 0.6-1.0 rad/s (level 0)
        segs.append(dict(kind=k, t0=t_acc, t1=t_acc + dur, d0=d_cur, d1=d_new, A=A, P=Pd,
                         sgn=rng.choice([-1, 1]), phi_des=rng.uniform(-0.35, 0.35)))
        if SC["gentle"] is not None:
            segs[-1]["A"] *= SC["gentle"]
            segs[-1]["phi_des"] *= SC["gentle"]
            segs[-1]["arc"] = 0.2 * SC["gentle"]
        d_cur, t_acc = d_new, t_acc + dur
        if t_acc > tt[-1]:
            break

    def desired(t):
        for s in segs:
            if t < s["t1"]:
                break
        a = np.clip((t - s["t0"]) / (s["t1"] - s["t0"]), 0, 1)
        a = 0.5 - 0.5 * math.cos(math.pi * a)
        d = s["d0"] + (s["d1"] - s["d0"]) * a
        tau = t - s["t0"]
        if s["kind"] == "straight":
            psi, dpsi = 0.0, 0.0
        elif s["kind"] == "away":  # swing the heading ~75 deg off the board and back
            Tt = s["t1"] - s["t0"]
            psi = s["sgn"] * 1.3 * math.sin(math.pi * tau / Tt) ** 2
            dpsi = s["sgn"] * 1.3 * 2 * math.sin(math.pi * tau / Tt) * math.cos(math.pi * tau / Tt) * math.pi / Tt
        elif s["kind"] == "arc":
            ramp = min(1.0, tau / 0.8)
            aa = s.get("arc", 0.2)
            psi, dpsi = s["sgn"] * aa * ramp, (s["sgn"] * aa / 0.8 if tau < 0.8 else 0.0)
        else:
            w = 2 * np.pi / s["P"]
            amp = s["A"] if s["kind"] == "spin" else 0.7 * s["A"]
            psi, dpsi = s["sgn"] * amp * math.sin(w * tau), s["sgn"] * amp * w * math.cos(w * tau)
        return d, psi, dpsi, s["phi_des"]

    X = np.zeros((n, 3))
    V = np.zeros((n, 2))
    v = om = 0.0
    beta_prev = math.atan2(Bc[1] - P[1], Bc[0] - P[0])
    ang_n = math.atan2(normal_out[1], normal_out[0])
    for i in range(n):
        t = tt[i]
        X[i] = (P[0], P[1], th)
        V[i] = (v, om)
        rel = Bc - P
        rho = float(np.hypot(*rel))
        beta = math.atan2(rel[1], rel[0])
        dbeta = wrap(beta - beta_prev) / dt if i else 0.0
        beta_prev = beta
        phi = wrap(math.atan2(-rel[1], -rel[0]) - ang_n)
        psi = wrap(th + myaw - beta)
        d_des, psi_des, dpsi_des, phi_des = desired(t)
        if side:  # drive along base x = sideways to the line of sight: sweep phi, heading trims the distance
            seg_i = next((k for k, s in enumerate(segs) if t < s["t1"]), len(segs) - 1)
            phi_sw = (0.45 if seg_i % 2 else -0.45) + phi_des * 0.3
            v_cmd = float(np.clip(SC.get("side_k", 1.2) * (phi - phi_sw) * (-float(np.sign(math.sin(myaw)))), -0.4, 0.4))
            corr = float(np.clip(SC.get("side_kd", 0.8) * (rho - d_des) * np.sign(v_cmd) * SC.get("side_ds", 1.0) * (-float(np.sign(math.sin(myaw))))
                                 * min(1.0, abs(v_cmd) / 0.1), -0.3, 0.3))
        else:
            if p.get("fast"):
                v_cmd = float(np.clip(2.0 * (rho - d_des), -0.8, 0.8))
            else:
                v_cmd = float(np.clip(0.9 * (rho - d_des), -0.5, 0.5))
            v_cmd *= cy  # rear camera: approaching the board means driving backwards
            # steer the heading offset so that the lateral drift pulls phi back to phi_des
            corr = float(np.clip(1.5 * (phi - phi_des) * np.sign(v_cmd * cy) * min(1.0, abs(v_cmd) / 0.1), -0.15, 0.15))
        psi_t = psi_des + corr
        if p.get("fast"):
            om_cmd = float(np.clip(dbeta + dpsi_des + 3.0 * wrap(psi_t - psi), -1.55, 1.55))
            a_v = np.clip((v_cmd - v) / 0.12, -2.0, 2.0)
            a_w = np.clip((om_cmd - om) / 0.10, -6.0, 6.0)
        else:
            om_cmd = float(np.clip(dbeta + dpsi_des + 3.0 * wrap(psi_t - psi), -1.05, 1.05))
            # actuator: first-order lag + acceleration limits
            a_v = np.clip((v_cmd - v) / 0.15, -1.2, 1.2)
            a_w = np.clip((om_cmd - om) / 0.12, -4.0, 4.0)
        if (SC["park_start"] > 0 and t < SC["park_start"]) or (SC["park_end"] > 0 and t > p["duration"] - SC["park_end"]):  # parked (brakes on)
            a_v = np.clip((0.0 - v) / 0.15, -1.2, 1.2)
            a_w = np.clip((0.0 - om) / 0.12, -4.0, 4.0)
            if abs(v) < 2e-3 and abs(om) < 5e-3:
                v, om, a_v, a_w = 0.0, 0.0, 0.0, 0.0
        v += a_v * dt
        om += a_w * dt
        # exact unicycle step
        if abs(om) > 1e-9:
            P = P + np.array([(math.sin(th + om * dt) - math.sin(th)) * v / om,
                              (-math.cos(th + om * dt) + math.cos(th)) * v / om])
        else:
            P = P + v * dt * np.array([math.cos(th), math.sin(th)])
        th += om * dt
    X[:, 2] = np.unwrap(X[:, 2])
    return tt, X, V, segs


def vib_matrix(rp):
    """Base tilt (roll about base x, pitch about base y, radians) about the base origin on the floor."""
    T = np.eye(4)
    T[:3, :3] = Rot.from_euler("YX", [rp[1], rp[0]]).as_matrix()
    return T


def board_in_view(p, T_world_board, X, margin=3.0, vib=None):
    """Per base pose: are all 44 circles (centre +- radius) inside the image?"""
    pts = board_points()
    out = np.zeros(len(X), bool)
    for k, x in enumerate(X):
        c, s = math.cos(x[2]), math.sin(x[2])
        T_wb = np.array([[c, -s, 0, x[0]], [s, c, 0, x[1]], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        if vib is not None:
            T_wb = T_wb @ vib_matrix(vib[k])
        T_cb = np.linalg.inv(T_wb @ p["T_base_cam"]) @ T_world_board
        pc = pts @ T_cb[:3, :3].T + T_cb[:3, 3]
        if (pc[:, 2] < 0.2).any():
            continue
        uv, _ = cv2.projectPoints(pts, cv2.Rodrigues(T_cb[:3, :3])[0], T_cb[:3, 3], p["K"], p["D"])
        uv = uv.reshape(-1, 2)
        rad = p["K"][0, 0] * B_DIAM / 2 / pc[:, 2]
        m = margin + rad
        out[k] = bool(((uv[:, 0] >= m) & (uv[:, 0] <= W - 1 - m) & (uv[:, 1] >= m) & (uv[:, 1] <= H - 1 - m)).all())
    return out


# ----------------------------------------------------------------------------- wheels
def wheel_measurements(p, rng, tt, V):
    r, b = p["r_eff"], p["b_eff"]
    dt = tt[1] - tt[0]
    v, om = V[:, 0], V[:, 1]
    wl = (v - om * b / 2) / r
    wr = (v + om * b / 2) / r
    if SC["wheel_asym"]:  # left wheels' effective radius r (1 + a/2), right r (1 - a/2) (a tyre low on one side)
        wl = (v - om * b / 2) / (r * (1 + SC["wheel_asym"] / 2))
        wr = (v + om * b / 2) / (r * (1 - SC["wheel_asym"] / 2))

    def ou(sigma, tau):
        a = math.exp(-dt / tau)
        e = rng.normal(0, sigma * math.sqrt(1 - a * a), len(tt))
        out = np.empty(len(tt))
        x = rng.normal(0, sigma)
        for i in range(len(tt)):  # cheap: 20k steps
            x = a * x + e[i]
            out[i] = x
        return out

    # slip: slowly varying multiplicative error per side + extra skid noise that grows with turning
    sl_a = ou(0.012, 0.6)
    sl_b = ou(0.03, 0.3)
    sl = sl_a + np.abs(om) * sl_b
    sr_a = ou(0.012, 0.6)
    sr_b = ou(0.03, 0.3)
    sr = sr_a + np.abs(om) * sr_b
    if SC["diff_drive"]:  # no skid: the turning slip is a fifth (the same draws, scaled)
        sl, sr = sl_a + np.abs(om) * 0.2 * sl_b, sr_a + np.abs(om) * 0.2 * sr_b
    nl, nr = rng.normal(0, 0.05, len(tt)), rng.normal(0, 0.05, len(tt))
    if SC["park_start"] or SC["park_end"]:  # a standing wheel does not turn (no noise while parked)
        mv = np.clip((np.abs(v) + 0.3 * np.abs(om)) / 0.02, 0, 1)
        nl, nr = nl * mv, nr * mv
    wl_m = wl * (1 + sl) + nl
    wr_m = wr * (1 + sr) + nr
    ql = np.cumsum(wl_m) * dt + rng.uniform(-50, 50)
    qr = np.cumsum(wr_m) * dt + rng.uniform(-50, 50)
    # joint samples at ~50 Hz (true sampling times), stamped with jitter
    ts = np.arange(0.0, p["duration"], 0.02)
    ts = ts + rng.normal(0, 0.0004, ts.size)  # true sampling instants, not exactly periodic
    ts = np.sort(ts)
    stamps = ts + rng.normal(0, 0.0007, ts.size)
    stamps = np.maximum.accumulate(stamps + 1e-6 * np.arange(ts.size))
    QL, QR = np.interp(ts, tt, ql), np.interp(ts, tt, qr)
    WL, WR = np.interp(ts, tt, wl_m), np.interp(ts, tt, wr_m)
    # front/rear of one side: belt-coupled, a tiny independent play
    play = rng.normal(0, 0.002, (ts.size, 4))
    pos = np.stack([QL + play[:, 0], QL + play[:, 1], QR + play[:, 2], QR + play[:, 3]], 1)
    vel = np.stack([WL, WL, WR, WR], 1) + rng.normal(0, 0.02, (ts.size, 4))
    if SC["js_rate"]:  # joint states at a lower rate (every k-th 50 Hz sample)
        k = max(1, int(round(50.0 / SC["js_rate"])))
        ts, stamps, pos, vel = ts[::k], stamps[::k], pos[::k], vel[::k]
    if SC["js_jitter"]:  # extra gaussian stamp jitter (kept monotonic)
        jr = np.random.default_rng([p["seed"], 2024])
        stamps = np.maximum.accumulate(stamps + jr.normal(0, SC["js_jitter"], stamps.size) + 1e-6 * np.arange(stamps.size))
    hw = p.get("harsh_wheels")
    if hw:
        hr = hw["rng"]
        if hw.get("ticks"):  # encoder quantization of every joint position (and velocity from tick counts)
            q = 2 * np.pi / hw["ticks"]
            pos = np.round(pos / q) * q
            dpos = np.diff(pos, axis=0, prepend=pos[:1])
            dts = np.diff(ts, prepend=ts[0] - (ts[1] - ts[0]))[:, None]
            vel = np.round(dpos / q) * q / np.maximum(dts, 1e-3)
        if hw.get("jitter_s"):  # extra stamping jitter: one-sided (late) exponential, made zero-mean
            j = hr.exponential(hw["jitter_s"], ts.size) - hw["jitter_s"]
            stamps = np.maximum.accumulate(stamps + j + 1e-6 * np.arange(ts.size))
        keep = np.ones(ts.size, bool)
        if hw.get("drop_frac"):
            keep &= hr.random(ts.size) >= hw["drop_frac"]
        if hw.get("stall"):  # recorder stall: no wheel message sampled in [t0, t1) (odometry clock)
            t0, t1 = hw["stall"]
            keep &= ~((ts >= t0) & (ts < t1))
        stamps, pos, vel = stamps[keep], pos[keep], vel[keep]
    return stamps, pos, vel


# ----------------------------------------------------------------------------- scene
class Scene:
    def __init__(self, p, rng):
        self.p = p
        K, D = p["K"], p["D"]
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        pts = np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2)
        nrm = cv2.undistortPointsIter(pts, K, D, None, None,
                                      (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)).reshape(-1, 2)
        rays = np.concatenate([nrm, np.ones((nrm.shape[0], 1))], 1)
        self.rays_c = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        self.rc = [np.ascontiguousarray(self.rays_c[:, k], dtype=np.float32) for k in range(3)]
        self.f = float(K[0, 0])
        # board pose in world
        by = math.radians(p["board_yaw"])
        zb = np.array([math.cos(by), math.sin(by), 0.0])     # into the board, away from the robot
        yb = np.array([0.0, 0.0, -1.0])                      # down
        xb = np.cross(yb, zb)                                # right as seen from the front
        R_wb = np.stack([xb, yb, zb], 1)
        sc = SC["board_scale"]  # the printed board's true size relative to the board file (1 = as nominal)
        self.bs, self.bd = B_S * sc, B_DIAM * sc
        gc = np.array([(2 * (B_COLS - 1) + 1) * self.bs / 2, (B_ROWS - 1) * self.bs / 2, 0.0])  # grid centre, board frame
        centre_w = np.array([0.0, 0.0, p["board_centre_h"]])
        t_wb = centre_w - R_wb @ gc
        self.T_world_board = np.eye(4)
        self.T_world_board[:3, :3], self.T_world_board[:3, 3] = R_wb, t_wb
        self.bw_half, self.bh_half = 0.26 * sc, 0.34 * sc  # white backing (A2 print on a foam board), 0.52 x 0.68 m
        self.gc = gc
        self.T_world_board0 = self.T_world_board.copy()
        self.extra_boards = []  # further boards of the same pattern (drawn first, the main board on top)
        if SC["second_board"] is not None:  # (DY, DX, DYAW): a second, identical board beside the first
            dy, dx, dyaw = SC["second_board"]
            T2 = np.eye(4)
            T2[:3, :3] = Rot.from_euler("z", dyaw, degrees=True).as_matrix() @ R_wb
            T2[:3, 3] = centre_w + np.array([dx, dy, 0.0]) - T2[:3, :3] @ gc
            self.extra_boards.append(T2)
        self.T_bumped = None
        if SC["board_bump"] is not None:  # (T, DX, DYAW[, DN]): board shifted along its x / normal, yawed about its centre
            bt, bdx, byaw = SC["board_bump"][:3]
            bdn = SC["board_bump"][3] if len(SC["board_bump"]) > 3 else 0.0
            Rb = Rot.from_euler("z", byaw, degrees=True).as_matrix() @ R_wb
            Tb = np.eye(4)
            Tb[:3, :3] = Rb
            Tb[:3, 3] = centre_w + bdx * xb + bdn * zb - Rb @ gc
            self.T_bumped, self.bump_t = Tb, float(bt)
        self.t_now = None
        self.R_wb, self.centre_w = R_wb, centre_w
        self.white, self.black = 0.85, 0.07
        # room textures in one atlas (1 cm texels)
        rm = p["room"]
        self.rm = rm
        self.res = 0.01
        self.pad = 4
        ymax = rm["ymax"]
        surf = [  # (name, u-range, v-range)
            ("front", (-ymax, ymax), (0, rm["zmax"])),
            ("back", (-ymax, ymax), (0, rm["zmax"])),
            ("left", (rm["xmin"], rm["xmax"]), (0, rm["zmax"])),
            ("right", (rm["xmin"], rm["xmax"]), (0, rm["zmax"])),
            ("floor", (rm["xmin"], rm["xmax"]), (-ymax, ymax)),
            ("ceil", (rm["xmin"], rm["xmax"]), (-ymax, ymax)),
        ]
        texs, self.u0, self.v0, self.row_off = [], [], [], []
        row = 0
        for name, (ua, ub), (va, vb) in surf:
            tw, th_ = int((ub - ua) / self.res) + 2 * self.pad, int((vb - va) / self.res) + 2 * self.pad
            tex = self._texture(rng, tw, th_, name)
            texs.append(tex)
            self.u0.append(ua)
            self.v0.append(va)
            self.row_off.append(row)
            row += th_ + 2
        aw = max(t.shape[1] for t in texs)
        atlas = np.zeros((row, aw), np.float32)
        for tex, r0 in zip(texs, self.row_off):
            atlas[r0:r0 + tex.shape[0], : tex.shape[1]] = tex
        self.atlas = atlas
        self.u0, self.v0, self.row_off = map(lambda a: np.array(a, np.float32), (self.u0, self.v0, self.row_off))

    def drifted_board(self, t):
        """--board-drift DYAW,DPITCH: the board turns linearly (0 at world t = 0, full at the end) about the vertical
        through its centre and leans back about its bottom edge (top away from the robot)."""
        dyaw, dpitch = SC["board_drift"]
        a = float(np.clip(t / self.p["duration"], 0, 1))
        R_wb, gc = self.R_wb, self.gc
        Ry = Rot.from_euler("z", a * dyaw, degrees=True).as_matrix()
        Rp = Rot.from_rotvec(-math.radians(a * dpitch) * R_wb[:, 0]).as_matrix()  # about the board's x axis, top away
        bottom = self.centre_w + R_wb @ np.array([0.0, self.bh_half, 0.0])  # bottom edge centre (board y is down)
        R = Ry @ Rp @ R_wb
        c = Ry @ (Rp @ (self.centre_w - bottom) + bottom - self.centre_w) + self.centre_w
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, c - R @ gc
        return T

    def _texture(self, rng, tw, th, name):
        tex = np.full((th, tw), 0.22 if name != "floor" else 0.28, np.float32)
        for cell, amp in ((200, 0.08), (60, 0.04), (15, 0.02), (4, 0.008)):
            small = rng.random((max(2, th // cell), max(2, tw // cell))).astype(np.float32) - 0.5
            tex += amp * cv2.resize(small, (tw, th), interpolation=cv2.INTER_CUBIC)
        if name == "floor":  # tiles with darker grout every 0.6 m
            g = int(0.6 / self.res)
            tex[:, ::g] -= 0.05
            tex[::g, :] -= 0.05
            n_rect = 15
        else:
            n_rect = 10 if name != "ceil" else 3
        for _ in range(n_rect):  # posters, furniture, doors: darker or lighter patches with hard edges
            rw, rh = rng.integers(10, 120), rng.integers(10, 150)
            x0, y0 = rng.integers(0, max(1, tw - rw)), rng.integers(0, max(1, th - rh))
            tex[y0:y0 + rh, x0:x0 + rw] = rng.uniform(0.12, 0.36)
        tex = cv2.GaussianBlur(tex, (0, 0), 1.0)
        return np.clip(tex, 0.03, 0.65)

    def camera_pose(self, X, rp=None):
        """T_world_cam for base pose (x, y, theta) [and base roll/pitch rp, radians]."""
        c, s = math.cos(X[2]), math.sin(X[2])
        T_wb = np.array([[c, -s, 0, X[0]], [s, c, 0, X[1]], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        if rp is not None:
            T_wb = T_wb @ vib_matrix(rp)
        return T_wb @ self.p["T_base_cam"]

    def render(self, T_wc):
        f32 = np.float32
        R, C = T_wc[:3, :3].astype(f32), T_wc[:3, 3]
        rx, ry, rz = self.rc
        wx = R[0, 0] * rx + R[0, 1] * ry + R[0, 2] * rz
        wy = R[1, 0] * rx + R[1, 1] * ry + R[1, 2] * rz
        wz = R[2, 0] * rx + R[2, 1] * ry + R[2, 2] * rz
        rm = self.rm
        big = f32(1e6)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            px, py, pz = wx > 0, wy > 0, wz > 0
            tx = np.where(px, f32(rm["xmax"] - C[0]), f32(rm["xmin"] - C[0])) / wx
            ty = np.where(py, f32(rm["ymax"] - C[1]), f32(-rm["ymax"] - C[1])) / wy
            tz = np.where(pz, f32(rm["zmax"] - C[2]), f32(-C[2])) / wz
        np.nan_to_num(tx, copy=False, nan=big, posinf=big, neginf=big)
        np.nan_to_num(ty, copy=False, nan=big, posinf=big, neginf=big)
        np.nan_to_num(tz, copy=False, nan=big, posinf=big, neginf=big)
        axx = (tx <= ty) & (tx <= tz)
        axy = ~axx & (ty <= tz)
        axz = ~axx & ~axy
        t_room = np.minimum(np.minimum(tx, ty), tz)
        hx, hy, hz = f32(C[0]) + wx * t_room, f32(C[1]) + wy * t_room, f32(C[2]) + wz * t_room
        if getattr(self, "keep_hit", False):
            self.last_hit = (hx, hy, hz)
            self.last_board = np.zeros(hx.size, np.float32)
        # surface id: 0 front(x+) 1 back(x-) 2 left(y+) 3 right(y-) 4 floor 5 ceiling
        sid = np.where(axx, np.where(px, 0, 1), np.where(axy, np.where(py, 2, 3), np.where(pz, 5, 4)))
        uu = np.where(axx, hy, hx)
        vv = np.where(axz, hy, hz)
        mx = (uu - self.u0[sid]) * f32(1 / self.res) + f32(self.pad)
        my = (vv - self.v0[sid]) * f32(1 / self.res) + f32(self.pad) + self.row_off[sid]
        I_room = cv2.remap(self.atlas, mx.reshape(H, W), my.reshape(H, W), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE).ravel()
        I = I_room
        for T2 in self.extra_boards:
            I = self._board(I, T2, C, wx, wy, wz, t_room)
        I = self._board(I, self.T_world_board, C, wx, wy, wz, t_room)
        if SC["walker"] is not None and self.t_now is not None:
            I = self._walker(I, C, wx, wy, wz, t_room)
        img = I.reshape(H, W)
        return cv2.GaussianBlur(img, (0, 0), 0.55)  # lens PSF

    def _walker(self, I, C, wx, wy, wz, t_room):
        """A person (0.45 m wide, 1.75 m tall dark slab facing the robot) walking across in front of the board."""
        f32 = np.float32
        t0, t1, xw = SC["walker"]
        if not t0 <= self.t_now <= t1:
            return I
        yw = -2.0 + 4.0 * (self.t_now - t0) / (t1 - t0)  # from y = -2 to +2 m at world x = xw
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            s = f32(xw - C[0]) / wx
        hy, hz = f32(C[1]) + wy * s, f32(C[2]) + wz * s
        m = (wx != 0) & (s > 0) & (s < t_room) & (np.abs(hy - f32(yw)) < 0.225) & (hz > 0) & (hz < 1.75)
        if not m.any():
            return I
        I = I.copy()
        k = np.nonzero(m)[0]
        stripe = (np.floor((hz[k] + 0.3 * hy[k]) / f32(0.12)) % 2).astype(f32)
        I[k] = f32(0.10) + f32(0.06) * stripe + f32(0.25) * (hz[k] > 1.5)
        return I

    def _board(self, I_cur, Tb, C, wx, wy, wz, t_room):
        f32 = np.float32
        # board plane
        nb, Ob, xb, yb = Tb[:3, 2], Tb[:3, 3], Tb[:3, 0], Tb[:3, 1]
        rn = f32(nb[0]) * wx + f32(nb[1]) * wy + f32(nb[2]) * wz
        q = C - Ob
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            sb = f32(-(q @ nb)) / rn
        valid = (rn > 0) & (sb > 0) & (sb < t_room)
        I = I_cur
        if valid.any():
            k = np.nonzero(valid)[0]
            s_, wxk, wyk, wzk = sb[k], wx[k], wy[k], wz[k]
            bu = f32(q @ xb) + s_ * (f32(xb[0]) * wxk + f32(xb[1]) * wyk + f32(xb[2]) * wzk)
            bv = f32(q @ yb) + s_ * (f32(yb[0]) * wxk + f32(yb[1]) * wyk + f32(yb[2]) * wzk)
            fp = s_ / (f32(self.f) * np.maximum(rn[k], f32(0.25)))  # metres per pixel on the board (rough)
            du = f32(self.bw_half) - np.abs(bu - f32(self.gc[0]))
            dv = f32(self.bh_half) - np.abs(bv - f32(self.gc[1]))
            alpha = np.clip(f32(0.5) + np.minimum(du, dv) / fp, 0, 1)
            i = np.clip(np.rint(bv * f32(1 / self.bs)), 0, B_ROWS - 1)
            odd = i % 2
            j = np.clip(np.rint((bu * f32(1 / self.bs) - odd) * f32(0.5)), 0, B_COLS - 1)
            ex = bu - (2 * j + odd) * f32(self.bs)
            ey = bv - i * f32(self.bs)
            dc = np.sqrt(ex * ex + ey * ey)
            cov = np.clip(f32(0.5) - (dc - f32(self.bd / 2)) / fp, 0, 1)
            I_board = f32(self.white) + f32(self.black - self.white) * cov
            I = I_cur.copy()
            I[k] = alpha * I_board + (1 - alpha) * I_cur[k]
            if getattr(self, "keep_hit", False):
                self.last_board[k] = np.maximum(self.last_board[k], alpha)
        return I


# ----------------------------------------------------------------------------- DVS
class DVS:
    def __init__(self, p, rng):
        self.rng = rng
        n = W * H
        self.C_on = (p["C"] * (1 + p["C_mismatch"] * rng.standard_normal(n))).clip(0.05)
        self.C_off = (p["C"] * (1 + p["C_mismatch"] * rng.standard_normal(n))).clip(0.05)
        self.refr = p["refractory"]
        self.tau_b = p["tau_bright"]
        self.hl = p.get("harsh_latency")  # (tau at I=0.85, tau_min, tau_max) or None
        self.ref = None
        self.Lf = None
        self.last = np.full(n, -1.0)

    def step(self, I, t_prev, t_cur):
        """Feed the intensity image at t_cur; returns events (t, idx, pol) in (t_prev, t_cur]."""
        I = I.ravel().astype(np.float64)
        dt = t_cur - t_prev
        Lin = np.log(I + 0.02)
        # shot/read noise, larger when dim
        Lin = Lin + self.rng.standard_normal(I.size) * np.clip(0.012 * np.sqrt(0.4 / np.maximum(I, 0.01)), 0.008, 0.05)
        if self.Lf is None:
            self.Lf = Lin.copy()
            self.ref = Lin.copy() + self.rng.uniform(-0.1, 0.1, I.size)
            return np.empty(0), np.empty(0, np.int64), np.empty(0, np.int8)
        if self.hl is None:
            tau = np.clip(self.tau_b * (0.85 / np.maximum(I, 0.01)), 0.15e-3, 4e-3)  # dim pixels respond later
        else:  # harsh: photoreceptor bandwidth ~ photocurrent; I is the absolute (dimmed, flickering) intensity
            tau = np.clip(self.hl[0] * (0.85 / np.maximum(I, 0.002)), self.hl[1], self.hl[2])
        L0 = self.Lf
        L1 = L0 + (1 - np.exp(-dt / tau)) * (Lin - L0)
        self.Lf = L1
        out_t, out_i, out_p = [], [], []
        for pol, Cth in ((1, self.C_on), (-1, self.C_off)):
            d = (L1 - self.ref) * pol
            nev = np.floor(d / Cth).astype(np.int64)
            idx = np.nonzero(nev > 0)[0]
            if idx.size == 0:
                continue
            ne = nev[idx]
            ref0 = self.ref[idx]
            slope = (L1[idx] - L0[idx])
            Ci = Cth[idx]
            self.ref[idx] = ref0 + pol * ne * Ci
            last = self.last[idx]
            for m in range(1, int(ne.max()) + 1):
                sel = np.nonzero(ne >= m)[0]
                lev = ref0[sel] + pol * m * Ci[sel]
                with np.errstate(divide="ignore", invalid="ignore"):
                    frac = (lev - L0[idx[sel]]) / slope[sel]
                frac = np.where(np.isfinite(frac), np.clip(frac, 0, 1), 1.0)
                tm = t_prev + frac * dt
                ok = tm >= last[sel] + self.refr
                ks = sel[ok]
                last[ks] = tm[ok]
                out_t.append(tm[ok])
                out_i.append(idx[ks])
                out_p.append(np.full(ks.size, pol, np.int8))
            self.last[idx] = last
        if not out_t:
            return np.empty(0), np.empty(0, np.int64), np.empty(0, np.int8)
        return np.concatenate(out_t), np.concatenate(out_i), np.concatenate(out_p)


# ----------------------------------------------------------------------------- CDR for EventArray
def encode_event_array(stamp_ns: int, t_ns: np.ndarray, x, y, pol, frame_id="dvs") -> bytes:
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    fid = frame_id.encode() + b"\0"
    head = bytearray(b"\x00\x01\x00\x00")
    head += np.array([sec], "<i4").tobytes() + np.array([nsec], "<u4").tobytes()
    head += np.array([len(fid)], "<u4").tobytes() + fid
    while (len(head) - 4) % 4:
        head += b"\0"
    head += np.array([H, W, len(t_ns)], "<u4").tobytes()
    n = len(t_ns)
    if n == 0:
        return bytes(head)
    # stream offset of the first event is a multiple of 4: per event x,y (4), sec, nsec (8), pol (1), pad
    # event k>=1 starts at 14 + 16 (k-1) relative to the first: x@0 y@2 [pad 2] sec@4.. from a 4-aligned x
    # simpler: build first event (13 bytes) then (n-1) records of 16 bytes: pad1, x, y, pad2, sec, nsec, pol
    s, ns = np.divmod(t_ns.astype(np.int64), 1_000_000_000)
    rec0 = np.zeros(1, dtype=np.dtype([("x", "<u2"), ("y", "<u2"), ("s", "<i4"), ("n", "<u4"), ("p", "u1")]))
    rec0["x"], rec0["y"], rec0["s"], rec0["n"], rec0["p"] = x[0], y[0], s[0], ns[0], pol[0] > 0
    dt = np.dtype([("pad1", "u1"), ("x", "<u2"), ("y", "<u2"), ("pad2", "<u2"), ("s", "<i4"), ("n", "<u4"),
                   ("p", "u1")])
    assert dt.itemsize == 16
    rest = np.zeros(n - 1, dt)
    rest["x"], rest["y"], rest["s"], rest["n"], rest["p"] = x[1:], y[1:], s[1:], ns[1:], pol[1:] > 0
    return bytes(head) + rec0.tobytes() + rest.tobytes()


def self_test_cdr():
    from mcap_ros2._dynamic import serialize_dynamic
    enc = serialize_dynamic("dvs_msgs/msg/EventArray", EVENT_ARRAY_DEF)["dvs_msgs/msg/EventArray"]
    rng = np.random.default_rng(0)
    for n in (0, 1, 2, 3, 17):
        t = rng.integers(0, 10**18, n)
        x, y, pl = rng.integers(0, W, n), rng.integers(0, H, n), rng.choice([-1, 1], n)
        ref = enc({"header": {"stamp": {"sec": 1700000000, "nanosec": 5}, "frame_id": "dvs"}, "height": H,
                   "width": W, "events": [{"x": int(x[k]), "y": int(y[k]), "ts": {"sec": int(t[k] // 10**9),
                                          "nanosec": int(t[k] % 10**9)}, "polarity": bool(pl[k] > 0)}
                                          for k in range(n)]})
        mine = encode_event_array(1700000000 * 10**9 + 5, t, x, y, pl)
        assert bytes(ref) == mine, (n, bytes(ref).hex(), mine.hex())



# ----------------------------------------------------------------------------- harsh conditions
HARSH_EFFECTS = ("dim", "noise", "flicker", "distortion", "intrinsics", "fast", "vibration", "stall", "quant")


def harsh_params(p: dict, seed: int, level: int, off=()) -> dict:
    """Level 1 (realistic-bad) / 2 (very bad) effects. Each effect draws from its own RNG stream
    (seed, level, effect), so switching one off leaves the others as they were; the level-0 streams
    are never touched. Modifies p (D, K_info, fast, harsh_latency, harsh_wheels); returns h."""
    h: dict = {"level": int(level), "off": sorted(off)}
    p["K_info"] = p["K"].copy()
    if level <= 0:
        return h
    L2 = level >= 2

    def R(k):
        return np.random.default_rng([seed, 7919, level, k])

    def on(e):
        return e not in off

    if on("dim"):  # dimmer room + intensity-dependent photoreceptor latency
        r = R(1)
        h["illum"] = float(r.uniform(0.35, 0.5) if not L2 else r.uniform(0.12, 0.18))
        h["tau_at_I085_s"] = float(r.uniform(0.08e-3, 0.12e-3))
        h["tau_max_s"] = 10e-3
        p["harsh_latency"] = (h["tau_at_I085_s"], 0.08e-3, h["tau_max_s"])
        lat = lambda I: float(np.clip(h["tau_at_I085_s"] * 0.85 / max(I * h["illum"], 0.002), 0.08e-3, 10e-3))
        h["tau_board_white_ms"] = 1e3 * lat(0.85)
        h["tau_board_black_ms"] = 1e3 * lat(0.07)
        h["tau_wall_ms"] = 1e3 * lat(0.22)
    if on("noise"):  # background activity + hot pixels (some polarity-biased)
        r = R(2)
        h["ba_total_hz"] = float(r.uniform(0.5, 1.5) if not L2 else r.uniform(1.0, 5.0))
        h["ba_extra_hz"] = max(0.0, h["ba_total_hz"] - p["ba_rate"])
        frac = r.uniform(0.0005, 0.001) if not L2 else r.uniform(0.001, 0.002)
        n = int(round(frac * W * H))
        h["hot_idx"] = r.choice(W * H, n, replace=False)
        h["hot_rate"] = r.uniform(100, 500 if not L2 else 1000, n)
        b = r.random(n)
        h["hot_p_on"] = np.where(b < 0.2, 0.98, np.where(b < 0.4, 0.02, r.uniform(0.4, 0.8, n)))
        h["noise_rng"] = R(12)
    if on("flicker"):  # 100 Hz lamp: a spot on the wall behind the board (+ a whole-image gradient at level 2)
        r = R(3)
        rm = p["room"]
        h["spot_centre_w"] = [float(rm["xmax"]), float(r.choice([-1, 1]) * r.uniform(0.6, 1.8)),
                              float(r.uniform(0.5, 1.6))]
        h["spot_sigma_m"] = float(r.uniform(0.35, 0.6))
        h["spot_gain"] = float(r.uniform(1.0, 2.0))
        h["spot_mod"] = float(r.uniform(0.2, 0.3))
        h["flicker_hz"] = float(100.0 * (1 + r.normal(0, 1e-4)))
        h["flicker_phase"] = float(r.uniform(0, 2 * np.pi))
        if L2:
            h["grad_mod"] = float(r.uniform(0.10, 0.15))
            h["grad_dir_rad"] = float(r.uniform(0, 2 * np.pi))
    if on("distortion"):  # stronger barrel distortion; the CameraInfo carries the true coefficients
        r = R(4)
        p["D"] = np.array([r.uniform(-0.35, -0.25), r.uniform(0.06, 0.12), r.normal(0, 5e-4),
                           r.normal(0, 5e-4), 0.0])
    if L2 and on("intrinsics"):  # a user's slightly wrong calibration in the CameraInfo
        r = R(5)
        s = r.choice([-1, 1]) * r.uniform(0.01, 0.02)
        Ki = p["K"].copy()
        Ki[0, 0] *= 1 + s
        Ki[1, 1] *= 1 + s + r.normal(0, 0.002)
        Ki[0, 2] += r.uniform(-2, 2)
        Ki[1, 2] += r.uniform(-2, 2)
        p["K_info"] = Ki
    if L2 and on("fast"):
        p["fast"] = True
    if on("vibration"):
        h["vib_std_moving_deg"] = 0.2 if not L2 else 0.35
        h["vib_rng"] = R(6)
    hw = {}
    if L2 and on("stall"):
        r = R(7)
        t0 = float(r.uniform(0.35, 0.65) * p["duration"])
        h["stall_s"] = [t0, t0 + float(r.uniform(0.45, 0.6))]
        hw["stall"] = tuple(h["stall_s"])
    if on("quant"):
        hw.update(ticks=4096 if not L2 else 1024, jitter_s=1.5e-3 if not L2 else 4e-3,
                  drop_frac=0.005 if not L2 else 0.02)
    if hw:
        hw["rng"] = R(8)
        p["harsh_wheels"] = hw
        h["wheels"] = {k: v for k, v in hw.items() if k != "rng"}
    return h


def vibration_series(h, tt, V):
    """Base roll/pitch (rad) at a few Hz, stronger while moving, exactly zero-mean; unknown to odometry."""
    from scipy.signal import butter, sosfiltfilt
    r = h["vib_rng"]
    dt = tt[1] - tt[0]
    sos = butter(2, [1.5, 7.0], btype="bandpass", fs=1 / dt, output="sos")
    env = 0.25 + 0.75 * np.minimum(1.0, (np.abs(V[:, 0]) + 0.3 * np.abs(V[:, 1])) / 0.4)
    out = np.zeros((tt.size, 2))
    for k in range(2):
        x = sosfiltfilt(sos, r.standard_normal(tt.size))
        x = x / x.std() * env
        mv = env > 0.7
        x *= math.radians(h["vib_std_moving_deg"]) / (x[mv].std() if mv.sum() > 100 else x.std())
        out[:, k] = x - x.mean()
    return out


def apply_light(scene, h, img, t):
    """Absolute intensity: room illumination level, flickering lamp spot and gradient (world time t)."""
    I = img.ravel()
    light = np.ones(I.size, np.float32)
    if "spot_gain" in h:
        hx, hy, hz = scene.last_hit
        c = h["spot_centre_w"]
        d2 = (hx - c[0]) ** 2 + (hy - c[1]) ** 2 + (hz - c[2]) ** 2
        s = np.exp(-d2 / (2 * h["spot_sigma_m"] ** 2)) * (1 - scene.last_board)
        ph = 2 * np.pi * h["flicker_hz"] * t + h["flicker_phase"]
        light = light + np.float32(h["spot_gain"]) * s * np.float32(1 + h["spot_mod"] * math.cos(ph))
        if "grad_mod" in h:
            if not hasattr(scene, "grad_w"):
                u, v = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
                a = h["grad_dir_rad"]
                g = 0.5 + ((u - W / 2) * math.cos(a) + (v - H / 2) * math.sin(a)) / np.hypot(W, H)
                scene.grad_w = np.clip(g, 0, 1).ravel().astype(np.float32)
            light = light * (1 + np.float32(h["grad_mod"] * math.cos(ph)) * scene.grad_w)
    return (I * light * np.float32(h.get("illum", 1.0))).reshape(img.shape)

# ----------------------------------------------------------------------------- main
SC_DEFAULT: dict = {}


def generate(seed: int, out: Path, duration: float, dt_render: float = 1e-3, packet: float = 0.005, td=None,
             harsh: int = 0, harsh_off=()):
    t_start = time.time()
    self_test_cdr()
    SC_DEFAULT.update(dict(park_start=0.0, park_end=0.0, mount_yaw=0.0, mount_pitch=0.0, mount_roll=0.0, cam_z=None,
                      far=False, extend_plan=False, js_rate=None, js_jitter=0.0, lookaway=False,
                      board_bump=None, board_scale=1.0, gentle=None, diff_drive=False, second_board=None, walker=None,
                      board_drift=None, cinfo_nodist=False, cinfo_focal=1.0, wheel_asym=0.0))
    p = make_params(seed, duration)
    if td is not None:
        p["td"] = float(td)
    h = harsh_params(p, seed, harsh, harsh_off)
    rng = np.random.default_rng(seed + 1000)
    tt, X, V, segs = simulate_trajectory(p, rng, dt_render)
    vib = vibration_series(h, tt, V) if "vib_rng" in h else None
    stamps, jpos, jvel = wheel_measurements(p, rng, tt, V)
    scene = Scene(p, rng)
    lit = harsh > 0 and ("illum" in h or "spot_gain" in h)
    scene.keep_hit = "spot_gain" in h
    dvs = DVS(p, rng)
    td = p["td"]
    K, D = p["K"], p["D"]
    K_info = p["K_info"]
    if SC["cinfo_focal"] != 1.0:  # the CameraInfo's focal lengths off by a factor (a user's wrong intrinsics)
        K_info = K_info.copy()
        K_info[0, 0] *= SC["cinfo_focal"]
        K_info[1, 1] *= SC["cinfo_focal"]
    D_info = np.zeros(5) if SC["cinfo_nodist"] else D  # a driver's default CameraInfo with no distortion
    out.parent.mkdir(parents=True, exist_ok=True)
    w = Writer(str(out))
    s_ev = w.register_msgdef("dvs_msgs/msg/EventArray", EVENT_ARRAY_DEF)
    s_js = w.register_msgdef("sensor_msgs/msg/JointState", JOINT_DEF)
    s_ci = w.register_msgdef("sensor_msgs/msg/CameraInfo", CINFO_DEF)
    # events are pre-encoded (numpy CDR, checked byte-for-byte against mcap_ros2's encoder above)
    ev_chan = w._writer.register_channel(topic="/dvs/events", message_encoding="cdr", schema_id=s_ev.id)

    def stamp(ns):
        return {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}

    # queue of non-event messages (log_time, kind, payload)
    queue = []
    names = ["front_left_wheel", "rear_left_wheel", "front_right_wheel", "rear_right_wheel"]
    if SC["diff_drive"]:  # two wheels
        names = ["left_wheel_joint", "right_wheel_joint"]
        jpos, jvel = jpos[:, [0, 2]], jvel[:, [0, 2]]
    for k in range(stamps.size):
        ns = EPOCH_NS + int(round(stamps[k] * 1e9))
        queue.append((ns, "js", {"header": {"stamp": stamp(ns), "frame_id": ""}, "name": names,
                                 "position": [float(a) for a in jpos[k]], "velocity": [float(a) for a in jvel[k]],
                                 "effort": []}))
    Pm = np.zeros((3, 4))
    Pm[:3, :3] = K_info
    for tc in np.arange(0.05, duration, 1.0):  # camera info at 1 Hz on the camera clock
        ns = EPOCH_NS + int(round((tc) * 1e9))
        queue.append((ns, "ci", {"header": {"stamp": stamp(ns), "frame_id": "dvs_optical"}, "height": H, "width": W,
                                 "distortion_model": "plumb_bob", "d": [float(a) for a in D_info],
                                 "k": [float(a) for a in K_info.ravel()], "r": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
                                 "p": [float(a) for a in Pm.ravel()], "binning_x": 0, "binning_y": 0,
                                 "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0,
                                         "do_rectify": False}}))
    queue.sort(key=lambda q: q[0])
    qi = 0

    def flush_queue(upto_ns):
        nonlocal qi
        while qi < len(queue) and queue[qi][0] <= upto_ns:
            ns, kind, msg = queue[qi]
            w.write_message("/joint_states" if kind == "js" else "/dvs/camera_info",
                            s_js if kind == "js" else s_ci, msg, log_time=ns, publish_time=ns)
            qi += 1

    # hot pixels
    hot_idx = rng.choice(W * H, p["n_hot"], replace=False)
    hot_rate = rng.uniform(50, 600, p["n_hot"])
    # camera time window: events with world time in [tw0, tw1] i.e. camera stamps cover [~0, duration]
    tw0, tw1 = td, duration + td
    i0 = int(np.searchsorted(tt, tw0)) - 1
    i1 = int(np.searchsorted(tt, tw1)) + 1
    chunk = 200
    n_events = 0
    pending = None  # leftover events (t_cam_ns, x, y, p) not yet packetised
    pkt_ns = int(packet * 1e9)
    next_pkt = EPOCH_NS  # packet boundaries on the camera clock
    render_time = 0.0
    for c0 in range(i0, i1, chunk):
        c1 = min(c0 + chunk, i1)
        ts_l, ix_l, p_l = [], [], []
        for i in range(c0, c1):
            r0 = time.time()
            if SC["board_drift"] is not None:
                scene.T_world_board = scene.drifted_board(float(tt[i]))
            if SC["walker"] is not None or scene.T_bumped is not None:
                scene.t_now = float(tt[i])
                if scene.T_bumped is not None and tt[i] >= scene.bump_t:  # the board is bumped and stays there
                    scene.T_world_board = scene.T_bumped
            img = scene.render(scene.camera_pose(X[i], None if vib is None else vib[i]))
            if lit:
                img = apply_light(scene, h, img, tt[i])
            render_time += time.time() - r0
            et, ei, ep = dvs.step(img, tt[i - 1], tt[i])
            if et.size:
                ts_l.append(et)
                ix_l.append(ei)
                p_l.append(ep)
        # background activity and hot pixels over the chunk's world-time span
        ta, tb = tt[c0 - 1], tt[c1 - 1]
        nba = rng.poisson(p["ba_rate"] * W * H * (tb - ta))
        ts_l.append(rng.uniform(ta, tb, nba))
        ix_l.append(rng.integers(0, W * H, nba))
        p_l.append(np.where(rng.random(nba) < 0.7, 1, -1).astype(np.int8))
        for hi, hr in zip(hot_idx, hot_rate):
            nh = rng.poisson(hr * (tb - ta))
            ts_l.append(rng.uniform(ta, tb, nh))
            ix_l.append(np.full(nh, hi))
            p_l.append(np.where(rng.random(nh) < 0.8, 1, -1).astype(np.int8))
        if "noise_rng" in h:  # harsh: extra background activity and many more hot pixels
            hr = h["noise_rng"]
            nba = hr.poisson(h["ba_extra_hz"] * W * H * (tb - ta))
            ts_l.append(hr.uniform(ta, tb, nba))
            ix_l.append(hr.integers(0, W * H, nba))
            p_l.append(np.where(hr.random(nba) < 0.55, 1, -1).astype(np.int8))
            nh = hr.poisson(h["hot_rate"] * (tb - ta))
            hix = np.repeat(h["hot_idx"], nh)
            ts_l.append(hr.uniform(ta, tb, hix.size))
            ix_l.append(hix)
            p_l.append(np.where(hr.random(hix.size) < np.repeat(h["hot_p_on"], nh), 1, -1).astype(np.int8))
        et, ei, ep = np.concatenate(ts_l), np.concatenate(ix_l), np.concatenate(p_l)
        keep = (et >= tw0) & (et < tw1)
        et, ei, ep = et[keep], ei[keep], ep[keep]
        o = np.argsort(et, kind="stable")
        et, ei, ep = et[o], ei[o], ep[o]
        tcam = EPOCH_NS + np.round((et - td) * 1e9).astype(np.int64)  # camera clock
        ex, ey = (ei % W).astype(np.uint16), (ei // W).astype(np.uint16)
        if pending is not None:
            tcam, ex, ey, ep = (np.concatenate([pending[0], tcam]), np.concatenate([pending[1], ex]),
                                np.concatenate([pending[2], ey]), np.concatenate([pending[3], ep]))
        # packets: [next_pkt, next_pkt + pkt_ns); all complete packets before the chunk end are written
        t_end = EPOCH_NS + int(round((tb - td) * 1e9)) if c1 < i1 else np.iinfo(np.int64).max
        final = c1 >= i1
        while True:
            hi_ns = next_pkt + pkt_ns
            if (not final and hi_ns > t_end) or (final and tcam.size == 0):
                break
            k = int(np.searchsorted(tcam, hi_ns))
            if k > 0:
                st = int(tcam[0])
                data = encode_event_array(st, tcam[:k], ex[:k], ey[:k], ep[:k])
                flush_queue(st)
                w._writer.add_message(channel_id=ev_chan, log_time=st, publish_time=st, sequence=0, data=data)
                n_events += k
                tcam, ex, ey, ep = tcam[k:], ex[k:], ey[k:], ep[k:]
            next_pkt = hi_ns
        pending = (tcam, ex, ey, ep)
        print(f"  seed {seed}: world t={tt[c1 - 1]:.2f}s events so far {n_events}  ({time.time() - t_start:.0f}s,"
              f" render {render_time:.0f}s)", flush=True)
    flush_queue(np.iinfo(np.int64).max)
    w.finish()

    # truth + trajectory
    truth = {
        "generator": "indep/gen.py",
        "seed": seed,
        "T_base_cam": p["T_base_cam"].tolist(),
        "mount_rpy_deg_about_base_xyz": p["mount_rpy_deg"].tolist(),
        "td_s": td,
        "td_convention": "camera sample stamped t_cam belongs to odometry time t_cam + td",
        "wheel_radius_eff": p["r_eff"],
        "track_width_eff": p["b_eff"],
        "K": p["K"].tolist(),
        "D": p["D"].tolist(),
        "T_world_board": scene.T_world_board0.tolist(),
        "contrast": p["C"], "contrast_mismatch": p["C_mismatch"], "refractory_s": p["refractory"],
        "ba_rate_hz": p["ba_rate"], "n_hot": p["n_hot"],
        "duration_s": duration,
        "n_events": int(n_events),
        "events_per_s": n_events / duration,
        "epoch_ns": EPOCH_NS,
        "segments": [str(s["kind"]) for s in segs],
    }
    if any(SC[k] != v for k, v in SC_DEFAULT.items()):
        truth["scenario"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in SC.items()}
    if scene.T_bumped is not None:
        truth["T_world_board_after_bump"] = scene.T_bumped.tolist()
        truth["board_bump_t_world_s"] = scene.bump_t
    if SC["board_drift"] is not None:
        truth["T_world_board_at_end"] = scene.drifted_board(duration).tolist()
    if scene.extra_boards:
        truth["T_world_board_second"] = scene.extra_boards[0].tolist()
    if harsh > 0:
        hh = {k: v for k, v in h.items() if not k.endswith("_rng") and k not in ("hot_idx", "hot_rate", "hot_p_on")}
        if "hot_idx" in h:
            hh["n_hot_harsh"] = int(h["hot_idx"].size)
            hh["hot_fraction"] = h["hot_idx"].size / (W * H)
            hh["hot_rate_hz_mean"] = float(h["hot_rate"].mean())
            hh["n_hot_polarity_biased"] = int((np.abs(h["hot_p_on"] - 0.5) > 0.4).sum())
        hh["K_camerainfo"] = K_info.tolist()
        hh["K_camerainfo_vs_true_focal_ratio"] = [float(K_info[0, 0] / K[0, 0]), float(K_info[1, 1] / K[1, 1])]
        if vib is not None:
            hh["vib_roll_pitch_std_deg"] = np.degrees(vib.std(0)).tolist()
            hh["vib_roll_pitch_maxabs_deg"] = np.degrees(np.abs(vib).max(0)).tolist()
        if "stall_s" in h:
            hh["stall_note"] = ("no /joint_states message sampled in [stall_s[0], stall_s[1]) s of odometry time "
                                "(absolute ns: epoch_ns + s*1e9)")
            hh["stall_abs_ns"] = [EPOCH_NS + int(h["stall_s"][0] * 1e9), EPOCH_NS + int(h["stall_s"][1] * 1e9)]
        hh["v_max_abs"] = float(np.abs(V[:, 0]).max())
        hh["omega_max_abs"] = float(np.abs(V[:, 1]).max())
        hh["n_joint_msgs"] = int(stamps.size)
        truth["harsh"] = hh
    base = out.with_suffix("")
    Path(str(base) + ".indep_truth.yaml").write_text(yaml.safe_dump(truth, sort_keys=False))
    extra = {} if harsh <= 0 else dict(K_info=K_info, harsh=harsh, **({} if vib is None else {"vib": vib}))
    np.savez(str(base) + ".indep_traj.npz", tt=tt, X=X, V=V, T_world_board=scene.T_world_board0,
             T_base_cam=p["T_base_cam"], K=K, D=D, td=td, epoch_ns=EPOCH_NS, **extra)
    print(f"seed {seed}: {n_events} events ({n_events / duration:.0f}/s), {time.time() - t_start:.0f}s")
    return truth


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("seed", type=int)
    ap.add_argument("--out", default=None)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--td", type=float, default=None, help="override the seed's clock offset (s)")
    ap.add_argument("--harsh", type=int, default=0, help="0 clean (default), 1 realistic-bad, 2 very bad")
    ap.add_argument("--harsh-off", default="", help="comma list of effects to switch off: " + ",".join(HARSH_EFFECTS))
    ap.add_argument("--park-start", type=float, default=0.0, help="parked for the first S seconds")
    ap.add_argument("--park-end", type=float, default=0.0, help="parked for the last S seconds")
    ap.add_argument("--mount-yaw", type=float, default=0.0, help="extra camera yaw about base z (deg)")
    ap.add_argument("--mount-pitch", type=float, default=0.0, help="extra camera pitch about base y (deg, + = down)")
    ap.add_argument("--mount-roll", type=float, default=0.0, help="extra camera roll about base x (deg)")
    ap.add_argument("--cam-z", type=float, default=None, help="nominal camera height (m), default 0.25")
    ap.add_argument("--far", action="store_true", help="board at 2.5-3.8 m")
    ap.add_argument("--extend-plan", action="store_true", help="enough segments for long recordings")
    ap.add_argument("--js-rate", type=float, default=None, help="joint state rate (Hz, divides 50)")
    ap.add_argument("--js-jitter", type=float, default=0.0, help="extra joint stamp jitter sigma (s)")
    ap.add_argument("--lookaway", action="store_true", help="two segments turning the camera off the board")
    ap.add_argument("--board-bump", default=None,
                    help="T,DX,DYAW[,DN]: at world time T s the board shifts DX m along its x axis (and DN m along its "
                         "normal, away from the robot) and turns DYAW deg about the vertical through its centre, and stays")
    ap.add_argument("--board-scale", type=float, default=1.0,
                    help="true size of the printed board relative to the board file (e.g. 0.94: printed 'fit to page')")
    ap.add_argument("--gentle", type=float, default=None,
                    help="low yaw excitation: no spins; turning amplitudes and lateral targets scaled by this factor")
    ap.add_argument("--diff-drive", action="store_true",
                    help="two-wheel differential drive: effective track = nominal (+-1 %%), turning slip a fifth, two joints")
    ap.add_argument("--second-board", default=None,
                    help="DY,DX,DYAW: a second identical board, its centre DY m (world y) and DX m (farther) from the first's, yawed DYAW deg")
    ap.add_argument("--walker", default=None,
                    help="T0,T1,X: a person (dark 0.45 x 1.75 m) walks across at world x = X (board at 0, robot at x < 0) from T0 to T1 s")
    ap.add_argument("--board-drift", default=None,
                    help="DYAW,DPITCH: over the recording the board turns DYAW deg about the vertical through its centre "
                         "and leans back DPITCH deg about its bottom edge, linearly (an easel slowly giving way)")
    ap.add_argument("--cinfo-nodist", action="store_true", help="CameraInfo distortion coefficients all zero (the lens keeps its own)")
    ap.add_argument("--cinfo-focal", type=float, default=1.0, help="CameraInfo focal lengths times this factor")
    ap.add_argument("--wheel-asym", type=float, default=0.0,
                    help="left/right effective wheel radius differ: left r (1 + A/2), right r (1 - A/2)")
    a = ap.parse_args()
    fl = lambda v: None if v is None else tuple(float(x) for x in v.split(","))
    SC.update(board_bump=fl(a.board_bump), board_scale=a.board_scale, gentle=a.gentle, diff_drive=a.diff_drive,
              second_board=fl(a.second_board), walker=fl(a.walker), board_drift=fl(a.board_drift),
              cinfo_nodist=a.cinfo_nodist, cinfo_focal=a.cinfo_focal, wheel_asym=a.wheel_asym)
    SC.update(park_start=a.park_start, park_end=a.park_end, mount_yaw=a.mount_yaw, mount_pitch=a.mount_pitch,
              mount_roll=a.mount_roll, cam_z=a.cam_z, far=a.far, extend_plan=a.extend_plan, js_rate=a.js_rate,
              js_jitter=a.js_jitter, lookaway=a.lookaway)
    off = tuple(e for e in a.harsh_off.split(",") if e)
    assert all(e in HARSH_EFFECTS for e in off), off
    out = Path(a.out or (f"{os.environ.get('BASE', 'out/independent')}/rec_{a.seed}.mcap" if a.harsh <= 0 else f"{os.environ.get('BASE', 'out/independent')}/rec_h{a.seed}.mcap"))
    generate(a.seed, out, a.duration, td=a.td, harsh=a.harsh, harsh_off=off)
