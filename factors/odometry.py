"""Odometry between-factors with a covariance from the differential-drive error model.

Wheel odometry errors grow like a random walk along the path: for an edge that travelled ``d``
metres and turned ``a`` radians (absolute values, summed along the full-rate odometry between the
two knots)

    sigma_x^2   = sigma_per_metre^2 * d + floor_m^2                        (along the motion)
    sigma_yaw^2 = yaw_per_radian^2 * a + yaw_per_metre^2 * d + floor_rad^2   (heading)
    sigma_y^2   = d^2 sigma_yaw^2 / 3 + lateral_per_metre^2 * d + floor_m^2  (across the motion)
    cov(y, yaw) = d sigma_yaw^2 / 2

The lateral terms are those of a heading error that grows linearly along the arc (the wheels
cannot slide sideways, so the robot only drifts sideways by driving with a wrong heading), plus a
small skid term. Keeping the lateral sigma small matters: it is what ties the heading of the base
to its direction of travel and so makes the camera yaw observable.

z, roll and pitch get the along-track and heading sigmas: the ground constraint is the separate
planar prior (factors.planar), so the between-factor does not need to encode it. The floors keep the
covariance positive definite when the robot stands still.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from .errors import FactorInputError as InputError


@dataclass(frozen=True)
class OdometryNoise:
    """Differential-drive noise. Units: m/sqrt(m), rad/sqrt(rad), rad/sqrt(m), m/sqrt(m), m, rad.

    The defaults describe good wheel odometry on a hard floor: distance about 3x tighter than heading, which
    slips most (the simulation's 0.5 % wheel slip is covered). Too loose a model lets the base trajectory
    float and leaves td with local minima; too tight a heading model turns slip into yaw bias
    (docs/refinement.md).
    """

    sigma_per_metre: float = 0.003
    yaw_per_radian: float = 0.01
    yaw_per_metre: float = 0.02
    lateral_per_metre: float = 0.0006
    floor_m: float = 1e-4
    floor_rad: float = 1e-4
    # Roll and pitch of an edge: (rad/sqrt(rad) turned, rad/sqrt(m), floor rad). Wheels say nothing about them: they
    # are how much the floor's slope changes between knots, about 0.6 deg over a metre of travel (a floor undulating
    # by half a degree over a metre or two), whatever the wheels slip. None takes the heading's terms (yaw_per_radian,
    # yaw_per_metre, floor_rad), as before it was measured (docs/refinement.md, "The floor's tilt between knots").
    tilt: tuple[float, float, float] | None = (0.0, 0.01, 1e-4)

    def __post_init__(self) -> None:
        vals = (self.sigma_per_metre, self.yaw_per_radian, self.yaw_per_metre, self.lateral_per_metre, self.floor_m,
                self.floor_rad, *(() if self.tilt is None else tuple(self.tilt)))
        if not all(np.isfinite(v) and v >= 0 for v in vals) or self.floor_m <= 0 or self.floor_rad <= 0 \
                or (self.tilt is not None and (len(self.tilt) != 3 or self.tilt[2] <= 0)):
            raise InputError("odometry noise: sigmas must be finite and >= 0, floors > 0")


def odometry_covariance(distance, angle, noise: OdometryNoise | None = None) -> np.ndarray:
    """Covariance(s) (..., 6, 6) of relative base motions in Pose3 tangent order (rot xyz, trans xyz), base axes.

    ``distance`` (m) and ``angle`` (rad) are the path length and the absolute angle turned per edge.
    """
    noise = noise or OdometryNoise()
    d = np.abs(np.asarray(distance, dtype=float))
    a = np.abs(np.asarray(angle, dtype=float))
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(a))):
        raise InputError("odometry covariance: distance and angle must be finite")
    d, a = np.broadcast_arrays(d, a)
    var_x = noise.sigma_per_metre**2 * d + noise.floor_m**2
    var_yaw = noise.yaw_per_radian**2 * a + noise.yaw_per_metre**2 * d + noise.floor_rad**2
    var_y = d**2 * var_yaw / 3.0 + noise.lateral_per_metre**2 * d + noise.floor_m**2
    var_tilt = var_yaw if noise.tilt is None else noise.tilt[0]**2 * a + noise.tilt[1]**2 * d + noise.tilt[2]**2
    cov = np.zeros(d.shape + (6, 6))
    cov[..., 0, 0] = var_tilt  # roll
    cov[..., 1, 1] = var_tilt  # pitch
    cov[..., 2, 2] = var_yaw
    cov[..., 3, 3] = var_x
    cov[..., 4, 4] = var_y
    cov[..., 5, 5] = var_x  # z
    cov[..., 2, 4] = cov[..., 4, 2] = d * var_yaw / 2.0
    return cov


def path_increments(t: np.ndarray, T_world_base: np.ndarray, knot_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Path length (m) and absolute angle turned (rad) between consecutive knots, from full-rate odometry.

    ``knot_index`` are increasing indices into the odometry samples.
    """
    T = np.asarray(T_world_base, dtype=float)
    step_d = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=-1)
    R = T[:, :3, :3]
    cos_step = (np.einsum("nij,nij->n", R[:-1], R[1:]) - 1.0) / 2.0
    step_a = np.arccos(np.clip(cos_step, -1.0, 1.0))
    cd = np.concatenate([[0.0], np.cumsum(step_d)])
    ca = np.concatenate([[0.0], np.cumsum(step_a)])
    k = np.asarray(knot_index)
    return np.diff(cd[k]), np.diff(ca[k])


def make_odometry_factors(
    keys, T_knots: np.ndarray, distance: np.ndarray, angle: np.ndarray, noise: OdometryNoise | None = None,
    extra_cov: np.ndarray | None = None,
) -> list[gtsam.BetweenFactorPose3]:
    """Between-factors between consecutive knot keys, measured relative motion from the odometry poses.
    ``extra_cov`` (edges, 6, 6) is added to each edge's covariance (e.g. an edge across a bridged gap)."""
    T_knots = np.asarray(T_knots, dtype=float)
    rel = np.linalg.inv(T_knots[:-1]) @ T_knots[1:]
    cov = odometry_covariance(distance, angle, noise)
    if extra_cov is not None:
        cov = cov + extra_cov
    out = []
    for i in range(len(rel)):
        nm = gtsam.noiseModel.Gaussian.Covariance(cov[i])
        out.append(gtsam.BetweenFactorPose3(int(keys[i]), int(keys[i + 1]), gtsam.Pose3(rel[i]), nm))
    return out


# ------------------------------------------------------------------------------------- odometry intrinsics
# A wrong wheel radius scales every arc length, a wrong (effective) track width every heading change: the
# odometry a robot with effective radius r and track b reports, integrated with the nominal r0 and b0, has arc
# lengths ds0 = ds / s_v and heading changes dth0 = dth / s_w with s_v = r / r0 and s_w = (r / b) / (r0 / b0).
# ScaledOdometry rebuilds the motion of each edge for given (s_v, s_w) from the nominal odometry's steps.


def _rot2(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


@dataclass(frozen=True)
class PlanarSteps:
    """The steps of a planar odometry track, in a form that can be rescaled.

    Step j goes from sample j to j + 1: heading change ``dth`` (n - 1,) and chord ``chord`` (n - 1, 2), the
    displacement expressed in the frame of the step's mid heading (for an arc: along x, of length
    ds sinc(dth / 2)). Scaling the arc length by s_v and the heading change by s_w scales the chord by s_v and
    turns it with the mid heading (second-order effects of the chord's sinc are below 1e-4 relative per step).
    """

    dth: np.ndarray
    chord: np.ndarray

    @classmethod
    def from_poses(cls, T_world_base: np.ndarray) -> PlanarSteps:
        T = np.asarray(T_world_base, dtype=float)
        th = np.unwrap(np.arctan2(T[:, 1, 0], T[:, 0, 0]))
        dth = np.diff(th)
        mid = th[:-1] + 0.5 * dth
        dp = np.diff(T[:, :2, 3], axis=0)
        chord = np.einsum("nji,nj->ni", _rot2(mid), dp)  # R(mid)^T dp
        return cls(dth, chord)

    def poses(self, T0: np.ndarray, s_v: float = 1.0, s_w: float = 1.0) -> np.ndarray:
        """The whole track (n, 4, 4) rescaled, starting at pose ``T0`` (its heading and position are kept)."""
        th0 = float(np.arctan2(T0[1, 0], T0[0, 0]))
        th = th0 + s_w * np.r_[0.0, np.cumsum(self.dth)]
        mid = th[:-1] + 0.5 * s_w * self.dth
        dp = s_v * np.einsum("nij,nj->ni", _rot2(mid), self.chord)
        p = T0[:2, 3] + np.r_[np.zeros((1, 2)), np.cumsum(dp, axis=0)]
        n = th.size
        out = np.zeros((n, 4, 4))
        out[:, :2, :2] = _rot2(th)
        out[:, 2, 2] = 1.0
        out[:, 3, 3] = 1.0
        out[:, :2, 3] = p
        out[:, 2, 3] = T0[2, 3]
        return out


def scaled_edge_motion(steps: PlanarSteps, lo: int, hi: int, s_v: float, s_w: float):
    """Relative motion of the samples ``lo`` -> ``hi`` (4 x 4) for scales (s_v, s_w), and its derivative (6, 2)
    in the right-perturbation tangent of that motion (rot xyz, trans xyz)."""
    dth = steps.dth[lo:hi]
    ph = np.r_[0.0, np.cumsum(dth)][:-1] + 0.5 * dth  # mid headings relative to sample lo (nominal)
    c = steps.chord[lo:hi]
    Rm = _rot2(s_w * ph)
    rc = np.einsum("nij,nj->ni", Rm, c)
    p = s_v * rc.sum(axis=0)
    dp_dv = rc.sum(axis=0)
    dp_dw = s_v * np.sum(ph[:, None] * np.stack([-rc[:, 1], rc[:, 0]], axis=1), axis=0)
    th = s_w * float(np.sum(dth))
    M = np.eye(4)
    M[:2, :2] = _rot2(np.array(th))
    M[:2, 3] = p
    # Right perturbation: d(rotation) = d(th) about z; d(translation) in the body frame = R(th)^T dp.
    Rt = M[:2, :2].T
    D = np.zeros((6, 2))
    D[3:5, 0] = Rt @ dp_dv
    D[3:5, 1] = Rt @ dp_dw
    D[2, 1] = float(np.sum(dth))
    return M, D


class EdgeMotions:
    """:func:`scaled_edge_motion` of every edge ``knot_index[i] -> knot_index[i + 1]`` at once, for the scales the
    graph asks about last: during one linearization every odometry factor reads the same (s_v, s_w), so the edges'
    motions are computed in one vectorized pass and each factor takes its own.

    With the nominal heading Theta_j before step j and the step's mid heading phi_j = Theta_j + dth_j / 2, an edge
    from sample lo sums R(s_w (phi_j - Theta_lo)) c_j = R(-s_w Theta_lo) g_j over its steps, g_j = R(s_w phi_j) c_j,
    so prefix sums of g_j (and of phi_j g_j for the derivative) give every edge's sums by differences.
    """

    def __init__(self, steps: PlanarSteps, knot_index: np.ndarray) -> None:
        k = np.asarray(knot_index, dtype=int)
        self.lo, self.hi = k[:-1], k[1:]
        dth = np.asarray(steps.dth, dtype=float)
        theta = np.r_[0.0, np.cumsum(dth)]  # nominal heading before each step (and after the last)
        self._theta_lo = theta[self.lo]
        self._dtheta = theta[self.hi] - theta[self.lo]  # the edge's nominal heading change
        self._phi = theta[:-1] + 0.5 * dth
        self._chord = np.asarray(steps.chord, dtype=float)
        self._key: tuple[float, float] | None = None
        self._M = self._D = None

    @property
    def heading_change(self) -> np.ndarray:
        """Every edge's nominal heading change (rad, at turn scale 1)."""
        return self._dtheta

    def at(self, s_v: float, s_w: float) -> tuple[np.ndarray, np.ndarray]:
        """Every edge's motion (E, 4, 4) and its derivative (E, 6, 2) (as :func:`scaled_edge_motion`)."""
        key = (float(s_v), float(s_w))
        if key == self._key:
            return self._M, self._D
        g = np.einsum("nij,nj->ni", _rot2(s_w * self._phi), self._chord)
        perp = np.stack([-g[:, 1], g[:, 0]], axis=1)
        G = np.r_[np.zeros((1, 2)), np.cumsum(g, axis=0)]
        P = np.r_[np.zeros((1, 2)), np.cumsum(perp, axis=0)]
        Q = np.r_[np.zeros((1, 2)), np.cumsum(self._phi[:, None] * perp, axis=0)]
        back = _rot2(-s_w * self._theta_lo)  # (E, 2, 2)
        rc_sum = np.einsum("nij,nj->ni", back, G[self.hi] - G[self.lo])
        q = (Q[self.hi] - Q[self.lo]) - self._theta_lo[:, None] * (P[self.hi] - P[self.lo])  # sum (phi - Theta_lo) perp
        w_sum = np.einsum("nij,nj->ni", back, q)
        th = s_w * self._dtheta
        R = _rot2(th)
        E = self.lo.size
        M = np.zeros((E, 4, 4))
        M[:, :2, :2] = R
        M[:, 2, 2] = M[:, 3, 3] = 1.0
        M[:, :2, 3] = s_v * rc_sum
        Rt = np.swapaxes(R, 1, 2)
        D = np.zeros((E, 6, 2))
        D[:, 3:5, 0] = np.einsum("nij,nj->ni", Rt, rc_sum)
        D[:, 3:5, 1] = np.einsum("nij,nj->ni", Rt, s_v * w_sum)
        D[:, 2, 1] = self._dtheta
        self._key, self._M, self._D = key, M, D
        return M, D


def make_scaled_odometry_factors(
    keys, scale_key: int, steps: PlanarSteps, knot_index: np.ndarray, distance: np.ndarray, angle: np.ndarray,
    noise: OdometryNoise | None = None, noise_scale: float | None = None, extra_cov: np.ndarray | None = None,
) -> list[gtsam.CustomFactor]:
    """Between-factors between consecutive knots whose measured motion is the odometry rescaled by the
    2-vector at ``scale_key`` = (s_v, s_w) (arc-length and heading-change factors, see :class:`PlanarSteps`).

    Error as GTSAM's BetweenFactorPose3: ``Log(M(s)^-1 X_a^-1 X_b)``. With ``noise_scale`` = s_v0, the arc-length
    scale the noise model (``distance``, ``angle``) was computed at, the translation error is divided by
    s_v / s_v0: the noise is then that of the measured odometry, not of the rescaled motion, so a smaller scale
    cannot shrink the noise along with the motion (a least-squares scale fitted to a noisy regressor comes out
    low by about the regressor's relative variance). ``None`` (the default) gives the plain error.
    ``extra_cov`` (edges, 6, 6) is added to each edge's covariance (e.g. an edge across a bridged gap).
    """
    cov = odometry_covariance(distance, angle, noise)
    if extra_cov is not None:
        cov = cov + extra_cov
    k = np.asarray(knot_index, dtype=int)
    edges = EdgeMotions(steps, k)  # shared: computed once per (s_v, s_w) for all the factors
    out = []
    ref = None if noise_scale is None else float(noise_scale)
    for i in range(k.size - 1):

        def error(this, values, H, i=i):
            Xa = values.atPose3(this.keys()[0])
            Xb = values.atPose3(this.keys()[1])
            s = values.atVector(this.keys()[2])
            Ms, Ds = edges.at(float(s[0]), float(s[1]))
            M, D = Ms[i], Ds[i]
            Z = Xa.between(Xb)
            E = gtsam.Pose3(M).between(Z)
            e = gtsam.Pose3.Logmap(E)
            if ref is not None:
                rv = float(s[0]) / ref
                w = np.array([1.0, 1.0, 1.0, 1.0 / rv, 1.0 / rv, 1.0 / rv])
            if H is not None:
                Jinv = gtsam.Pose3.LogmapDerivative(E)
                H[0] = -Jinv @ Z.inverse().AdjointMap()
                H[1] = Jinv
                H[2] = -Jinv @ E.inverse().AdjointMap() @ D
                if ref is not None:
                    H[0] = w[:, None] * H[0]
                    H[1] = w[:, None] * H[1]
                    Hs = w[:, None] * H[2]
                    Hs[3:, 0] -= e[3:] / (rv * float(s[0]))  # d(1 / rv) / d s_v = -1 / (rv^2 s_v0) = -1 / (rv s_v)
                    H[2] = Hs
            return e if ref is None else w * e

        nm = gtsam.noiseModel.Gaussian.Covariance(cov[i])
        out.append(gtsam.CustomFactor(nm, [int(keys[i]), int(keys[i + 1]), int(scale_key)], error))
    return out
