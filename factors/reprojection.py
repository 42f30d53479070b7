"""Circle-grid reprojection factor: one factor per detection frame, all board points stacked.

Variables of the factor for frame i (camera time t_i):

* ``X_a``, ``X_b``: the base poses ``T_world_base`` at the two knots bracketing ``t_i + td``,
* ``C`` = ``T_base_cam``, ``B`` = ``T_world_board``,
* ``td`` (a 1-vector): the camera sample at ``t_i`` belongs to odometry time ``t_i + td``.

The base pose at ``tau = t_i + td`` is ``X(tau) = Y(s) * K(tau)`` with ``s = (tau - t_a) / (t_b - t_a)``,
``Y(s)`` = slerp of the rotations and linear interpolation of the positions of ``X_a`` and ``X_b`` (the
same scheme as :func:`plsgraph.core.geometry.interpolate_poses`), and ``K(tau)`` the detail of the full-rate
odometry between the two knots: ``K = Y_odo(s)^-1 odo(tau)``, the odometry pose at ``tau`` relative to
the same interpolation of the odometry's own poses at the knot times (identity without odometry, or
when every odometry sample is a knot). ``td`` acts through ``s`` and through ``K``: the frame slides
along the base motion, and to first order the pose moves with the odometry's body twist at ``tau``.

A board point P is predicted at ``project(C^-1 X(tau)^-1 B P)``; the residual is predicted minus
measured pixels, (u, v) per visible point. Points with NaN pixels are dropped when the factor is built.

Speed: GTSAM calls one Python callback per factor. All frames share one :class:`FrameBatch` that, on the
first call with a new set of variable values, evaluates every frame at once with numpy and then serves
each factor its slice. A factor only uses the batch result after checking that the batch was computed
from exactly the values it is asked about, so the shortcut cannot return a stale residual. A caller that
evaluates a whole graph itself (``graph.error(values)``, ``graph.linearize(values)``) can skip those checks
with :meth:`FrameBatch.evaluated_at`: inside it, every factor is served from one evaluation at ``values``.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cached_property

import gtsam
import numpy as np

from .camera import Camera as CameraModel
from .errors import FactorInputError as InputError
from .lie import inv_T, pose_adjoint, so3_exp, so3_log, so3_right_jacobian, so3_right_jacobian_inv

log = logging.getLogger(__name__)

# Points closer than this to the camera plane are clamped: the residual then is huge (the robust loss
# or the outlier rejection deals with it) instead of a division by zero.
_MIN_DEPTH = 1e-3


@dataclass(frozen=True)
class OdometryDetail:
    """Full-rate odometry ``T`` (n, 4, 4) at times ``t`` (n,), and per frame its poses at the two knots."""

    t: np.ndarray
    T: np.ndarray
    T_a: np.ndarray
    T_b: np.ndarray

    def take(self, idx) -> OdometryDetail:
        return OdometryDetail(self.t, self.T, self.T_a[idx], self.T_b[idx])


def odometry_detail(
    odo: OdometryDetail, tau: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``K(tau)`` (m, 4, 4), the odometry body twist at ``tau`` (m, 6) and ``d eta(Y_odo) / ds`` (m, 6).

    Outside the odometry span the end samples' motion is extrapolated (the same interpolation formula).
    """
    t = odo.t
    j = np.clip(np.searchsorted(t, tau, "right") - 1, 0, t.size - 2)
    dt = t[j + 1] - t[j]
    u = (tau - t[j]) / dt
    odo_tau, _, _, a_u = interpolation_jacobians(odo.T[j], odo.T[j + 1], u)
    Y_odo, _, _, a_s = interpolation_jacobians(odo.T_a, odo.T_b, s)
    K = inv_T(Y_odo) @ odo_tau
    twist_odo = a_u / dt[:, None]  # body twist of the odometry at tau
    return K, twist_odo, a_s


@dataclass(frozen=True)
class ReprojectionFrames:
    """Static data of m detection frames sharing one board and one camera.

    ``t`` (m,) camera times; ``t_a``, ``t_b`` (m,) odometry times of the bracketing knots;
    ``uv`` (m, N, 2) measured pixels (NaN = not seen); ``board_points`` (N, 3);
    ``odometry``: full-rate odometry for the detail between knots (None: K = identity).
    """

    t: np.ndarray
    t_a: np.ndarray
    t_b: np.ndarray
    uv: np.ndarray
    board_points: np.ndarray
    camera: CameraModel
    odometry: OdometryDetail | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float).ravel()
        m = t.size
        t_a = np.asarray(self.t_a, dtype=float).ravel()
        t_b = np.asarray(self.t_b, dtype=float).ravel()
        uv = np.asarray(self.uv, dtype=float)
        pts = np.asarray(self.board_points, dtype=float)
        if t_a.size != m or t_b.size != m or uv.shape[:1] != (m,) or uv.ndim != 3 or uv.shape[1:] != (len(pts), 2):
            raise InputError(f"reprojection frames: inconsistent shapes t {t.shape}, uv {uv.shape}, points {pts.shape}")
        if np.any(t_b - t_a <= 0):
            raise InputError("reprojection frames: each bracket needs t_b > t_a")
        odo = self.odometry
        if odo is not None and (odo.T_a.shape != (m, 4, 4) or odo.T_b.shape != (m, 4, 4) or odo.t.size < 2):
            raise InputError("reprojection frames: odometry detail needs >= 2 samples and knot poses per frame")
        for name, v in (("t", t), ("t_a", t_a), ("t_b", t_b), ("uv", uv), ("board_points", pts)):
            object.__setattr__(self, name, v)

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def valid(self) -> np.ndarray:
        """(m, N) True where the point was detected."""
        return np.all(np.isfinite(self.uv), axis=-1)

    def take(self, idx) -> ReprojectionFrames:
        idx = np.atleast_1d(idx)
        return ReprojectionFrames(
            self.t[idx], self.t_a[idx], self.t_b[idx], self.uv[idx], self.board_points, self.camera,
            None if self.odometry is None else self.odometry.take(idx),
        )


@dataclass(frozen=True)
class FrameEvaluation:
    """Residuals (m, N, 2) and, if asked, Jacobians (m, N, 2, 6) / (m, N, 2, 1) of m frames."""

    residual: np.ndarray
    J_a: np.ndarray | None = None
    J_b: np.ndarray | None = None
    J_cam: np.ndarray | None = None
    J_board: np.ndarray | None = None
    J_td: np.ndarray | None = None

    @cached_property
    def stacked(self) -> tuple:
        """The residual (m, 2 N) and the Jacobians (m, 2 N, k) with each frame's points stacked (views of
        contiguous arrays): one frame's block is one index away."""
        m = self.residual.shape[0]
        Js = () if self.J_a is None else (self.J_a, self.J_b, self.J_cam, self.J_board, self.J_td)
        return (np.ascontiguousarray(self.residual).reshape(m, -1),) + tuple(
            np.ascontiguousarray(J).reshape(m, -1, J.shape[-1]) for J in Js)


def interpolation_jacobians(
    Xa: np.ndarray, Xb: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Interpolated poses Y(s) (m, 4, 4) and their right-perturbation Jacobians.

    Returns ``Y``, ``A_a`` (m, 6, 6), ``A_b`` (m, 6, 6), ``a_s`` (m, 6) with
    ``Y' = Y Exp(A_a e_a + A_b e_b + a_s ds)`` to first order for ``X_a' = X_a Exp(e_a)``, same for b.
    """
    Ra, pa = Xa[:, :3, :3], Xa[:, :3, 3]
    Rb, pb = Xb[:, :3, :3], Xb[:, :3, 3]
    D = np.swapaxes(Ra, 1, 2) @ Rb
    phi = so3_log(D).reshape(-1, 3)
    sphi = s[:, None] * phi
    E = so3_exp(sphi).reshape(-1, 3, 3)
    RY = Ra @ E
    pY = (1.0 - s)[:, None] * pa + s[:, None] * pb
    Y = np.zeros_like(Xa)
    Y[:, :3, :3] = RY
    Y[:, :3, 3] = pY
    Y[:, 3, 3] = 1.0
    JJ = so3_right_jacobian(sphi) @ so3_right_jacobian_inv(phi)  # d(rotation of Y) / d(rotation of X_b), over s
    RYt = np.swapaxes(RY, 1, 2)
    m = Xa.shape[0]
    A_a = np.zeros((m, 6, 6))
    A_b = np.zeros((m, 6, 6))
    A_a[:, :3, :3] = np.swapaxes(E, 1, 2) - s[:, None, None] * (JJ @ np.swapaxes(D, 1, 2))
    A_a[:, 3:, 3:] = (1.0 - s)[:, None, None] * (RYt @ Ra)
    A_b[:, :3, :3] = s[:, None, None] * JJ
    A_b[:, 3:, 3:] = s[:, None, None] * (RYt @ Rb)
    a_s = np.concatenate([phi, np.einsum("mij,mj->mi", RYt, pb - pa)], axis=-1)
    return Y, A_a, A_b, a_s


def _project_with_jacobian(camera: CameraModel, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Same as ``camera.project(p, with_jacobian=True)``, with the 2 x 2 x 3 products written out.

    The chained einsum of CameraModel.project costs a third of a batch evaluation; the test suite
    checks that both agree.
    """
    inv_z = 1.0 / p[:, 2]
    xn = p[:, :2] * inv_z[:, None]
    xd, Jd = camera.distort_normalized(xn)
    K = camera.K
    uv = np.empty_like(xd)
    uv[:, 0] = K[0, 0] * xd[:, 0] + K[0, 1] * xd[:, 1] + K[0, 2]
    uv[:, 1] = K[1, 1] * xd[:, 1] + K[1, 2]
    # A = K2 Jd (n, 2, 2), then d uv / d p = A [[1/z, 0, -x/z], [0, 1/z, -y/z]]
    A = np.empty_like(Jd)
    A[:, 0, :] = K[0, 0] * Jd[:, 0, :] + K[0, 1] * Jd[:, 1, :]
    A[:, 1, :] = K[1, 1] * Jd[:, 1, :]
    J = np.empty((p.shape[0], 2, 3))
    J[:, :, 0] = A[:, :, 0] * inv_z[:, None]
    J[:, :, 1] = A[:, :, 1] * inv_z[:, None]
    J[:, :, 2] = -(A[:, :, 0] * xn[:, 0, None] + A[:, :, 1] * xn[:, 1, None]) * inv_z[:, None]
    return uv, J


def evaluate_frames(
    frames: ReprojectionFrames,
    Xa: np.ndarray,
    Xb: np.ndarray,
    T_base_cam: np.ndarray,
    T_world_board: np.ndarray,
    td: float,
    jacobians: bool = True,
) -> FrameEvaluation:
    """Residuals (predicted - measured pixels) of every point of every frame; NaN where not detected.

    ``Xa``, ``Xb`` (m, 4, 4) are the bracketing knot poses of each frame. Vectorized over frames and points.
    """
    h = frames.t_b - frames.t_a
    tau = frames.t + td
    s = (tau - frames.t_a) / h
    Y, A_a, A_b, a_s = interpolation_jacobians(np.asarray(Xa, float), np.asarray(Xb, float), s)
    if frames.odometry is None:
        K = np.broadcast_to(np.eye(4), Y.shape)
        twist_odo = a_s_odo = None
    else:
        K, twist_odo, a_s_odo = odometry_detail(frames.odometry, tau, s)
    X = Y @ K
    RX, pX = X[:, :3, :3], X[:, :3, 3]
    RC, pC = T_base_cam[:3, :3], T_base_cam[:3, 3]
    RB, pB = T_world_board[:3, :3], T_world_board[:3, 3]
    P = frames.board_points
    Pw = P @ RB.T + pB  # (N, 3) board points in the world
    q = (Pw[None, :, :] - pX[:, None, :]) @ RX  # in the base frame: RX^T (Pw - pX)
    pc = (q - pC) @ RC  # in the camera frame: RC^T (q - pC)
    m, n = q.shape[:2]
    pc_flat = pc.reshape(-1, 3)
    if np.any(pc_flat[:, 2] < _MIN_DEPTH):
        pc_flat = pc_flat.copy()
        pc_flat[:, 2] = np.maximum(pc_flat[:, 2], _MIN_DEPTH)
    if not jacobians:
        uv = frames.camera.project(pc_flat).reshape(m, n, 2)
        return FrameEvaluation(uv - frames.uv)
    uv, Jp = _project_with_jacobian(frames.camera, pc_flat)
    uv = uv.reshape(m, n, 2)
    Jp = Jp.reshape(m, n, 2, 3)

    # Row vector a times hat(v) is the cross product a x v: cheaper than 80k tiny matrix products.
    # d pc / d(C perturbation) = [hat(pc), -I]
    J_cam = np.concatenate([np.cross(Jp, pc[:, :, None, :]), -Jp], axis=-1)
    # d pc / d(B perturbation) = R_M [-hat(P), I], R_M = RC^T RX^T RB
    RM = RC.T @ np.swapaxes(RX, 1, 2) @ RB  # (m, 3, 3)
    JpRM = (Jp.reshape(m, 2 * n, 3) @ RM).reshape(m, n, 2, 3)
    J_board = np.concatenate([np.cross(P[None, :, None, :], JpRM), JpRM], axis=-1)
    # d pc / d(X perturbation) = RC^T [hat(q), -I]; X = Y K, so eta_X = Ad(K^-1) eta_Y + K^-1 dK
    JpRC = Jp @ RC.T
    J_X = np.concatenate([np.cross(JpRC, q[:, :, None, :]), -JpRC], axis=-1).reshape(m, 2 * n, 6)
    AdKi = pose_adjoint(inv_T(K))
    J_a = (J_X @ (AdKi @ A_a)).reshape(m, n, 2, 6)
    J_b = (J_X @ (AdKi @ A_b)).reshape(m, n, 2, 6)
    g_td = np.einsum("mij,mj->mi", AdKi, a_s) / h[:, None]  # d eta_X / d td through s
    if twist_odo is not None:
        # K = Y_odo(s)^-1 odo(tau): K^-1 dK/dtau = twist_odo - Ad(K^-1) a_s_odo / h
        g_td = g_td + twist_odo - np.einsum("mij,mj->mi", AdKi, a_s_odo) / h[:, None]
    J_td = (J_X @ g_td[:, :, None]).reshape(m, n, 2, 1)
    return FrameEvaluation(uv - frames.uv, J_a, J_b, J_cam, J_board, J_td)


class FrameBatch:
    """Evaluates all reprojection factors of a graph at once and serves them one by one.

    ``knot_index`` (m, 2) gives, per frame, the indices into ``knot_keys`` of its two bracketing knots.
    """

    def __init__(
        self,
        frames: ReprojectionFrames,
        knot_keys: np.ndarray,
        knot_index: np.ndarray,
        cam_key: int,
        board_key: int,
        td_key: int,
    ) -> None:
        self.frames = frames
        self.knot_keys = np.asarray(knot_keys, dtype=np.int64)
        self.knot_index = np.asarray(knot_index, dtype=np.int64).reshape(len(frames), 2)
        self.cam_key, self.board_key, self.td_key = int(cam_key), int(board_key), int(td_key)
        valid = frames.valid
        self._rows = [np.flatnonzero(v) for v in valid]
        self._all = [r.size == valid.shape[1] for r in self._rows]
        # Per frame, its points' rows in the stacked (2 N) residual, or None for all of them.
        self._rows2 = [None if full else (2 * r[:, None] + np.arange(2)).ravel()
                       for r, full in zip(self._rows, self._all, strict=True)]
        # Knots some frame needs; only those are read from the Values.
        self._used = np.unique(self.knot_index)
        self._state: tuple | None = None  # (knot poses, C, B, td) the cached evaluation was made from
        self._eval: FrameEvaluation | None = None
        self._hits = 0
        self._solo = 0
        self._at_values = False  # inside evaluated_at: every call is about the values the batch was evaluated at
        self.n_batch = 0  # statistics, for the benchmark
        self.n_single = 0

    def keys_of(self, i: int) -> list[int]:
        a, b = self.knot_index[i]
        return [int(self.knot_keys[a]), int(self.knot_keys[b]), self.cam_key, self.board_key, self.td_key]

    def n_valid(self, i: int) -> int:
        return int(self._rows[i].size)

    def _read_all(self, values: gtsam.Values) -> tuple:
        knots = np.zeros((self.knot_keys.size, 4, 4))
        for j in self._used:
            knots[j] = values.atPose3(int(self.knot_keys[j])).matrix()
        C = values.atPose3(self.cam_key).matrix()
        B = values.atPose3(self.board_key).matrix()
        td = float(values.atVector(self.td_key)[0])
        return knots, C, B, td

    def evaluate_all(self, values: gtsam.Values, jacobians: bool = True) -> FrameEvaluation:
        """Every frame evaluated at ``values`` (cached)."""
        state = self._read_all(values)
        knots, C, B, td = state
        ki = self.knot_index
        self._eval = evaluate_frames(self.frames, knots[ki[:, 0]], knots[ki[:, 1]], C, B, td, jacobians)
        self._state = state
        # Byte strings make the per-factor check "were these my values?" a cheap comparison.
        self._keys_bytes = (C.tobytes(), B.tobytes(), td)
        self._knot_bytes = [k.tobytes() for k in knots]
        self._hits = 0
        self.n_batch += 1
        return self._eval

    @contextmanager
    def evaluated_at(self, values: gtsam.Values, jacobians: bool) -> Iterator[None]:
        """Evaluate every frame at ``values`` now and serve the factors from it without reading their values.

        Only for a call that evaluates factors at exactly ``values`` and nothing else, e.g.
        ``with batch.evaluated_at(v, False): graph.error(v)`` or ``with batch.evaluated_at(v, True):
        graph.linearize(v)``: GTSAM hands each factor the same values, so the per-factor check that the batch
        was made from them (reading five variables per factor) would only confirm it."""
        self.evaluate_all(values, jacobians)
        self._at_values = True
        try:
            yield
        finally:
            self._at_values = False

    def _matches(self, i: int, Xa: np.ndarray, Xb: np.ndarray, C: np.ndarray, B: np.ndarray, td: float) -> bool:
        if self._state is None:
            return False
        Cb, Bb, td0 = self._keys_bytes
        a, b = self.knot_index[i]
        return (
            td == td0
            and C.tobytes() == Cb
            and B.tobytes() == Bb
            and Xa.tobytes() == self._knot_bytes[a]
            and Xb.tobytes() == self._knot_bytes[b]
        )

    def __call__(self, i: int, values: gtsam.Values, H) -> np.ndarray:
        """The GTSAM error function of frame i's factor."""
        if self._at_values and (H is None or self._eval.J_a is not None):
            self._hits += 1
            return self._serve(self._eval, i, i, H)
        a, b = self.knot_index[i]
        Xa = values.atPose3(int(self.knot_keys[a])).matrix()
        Xb = values.atPose3(int(self.knot_keys[b])).matrix()
        C = values.atPose3(self.cam_key).matrix()
        B = values.atPose3(self.board_key).matrix()
        td = float(values.atVector(self.td_key)[0])
        need_jac = H is not None
        ev = self._eval
        if self._matches(i, Xa, Xb, C, B, td) and (not need_jac or ev.J_a is not None):
            self._hits += 1
            j = i
        elif self._state is None or self._hits > 0 or self._solo >= 8:
            # A new set of values: evaluate every frame now, the other factors will ask next.
            ev = self.evaluate_all(values, need_jac)
            self._solo = 0
            j = i
        else:
            # The last batch was never used: GTSAM is asking about values one factor at a time
            # (e.g. a numerical check); evaluating just this frame is cheaper.
            self._solo += 1
            self.n_single += 1
            ev = evaluate_frames(self.frames.take(i), Xa[None], Xb[None], C, B, td, need_jac)
            j = 0
        return self._serve(ev, i, j, H)

    def _serve(self, ev: FrameEvaluation, i: int, j: int, H) -> np.ndarray:
        """Frame i's residual (and its Jacobians into ``H``) from row j of the evaluation ``ev``."""
        flat = ev.stacked
        rows = self._rows2[i]
        if rows is None:  # every point: row j of each stacked array is already one contiguous block
            if H is not None:
                H[0], H[1], H[2], H[3], H[4] = flat[1][j], flat[2][j], flat[3][j], flat[4][j], flat[5][j]
            return flat[0][j]
        if H is not None:  # the seen points' rows, gathered (a contiguous copy)
            H[0], H[1], H[2], H[3], H[4] = (flat[1][j, rows], flat[2][j, rows], flat[3][j, rows], flat[4][j, rows],
                                            flat[5][j, rows])
        return flat[0][j, rows]


def reprojection_noise(n_points: int, sigma_px: float, robust: str | None, robust_k: float) -> gtsam.noiseModel.Base:
    """Isotropic pixel noise for a frame of ``n_points`` points, optionally wrapped in a robust loss.

    GTSAM applies the robust loss to the whitened norm of the whole stacked residual, so the loss acts
    per frame. An inlier frame of n points has a whitened norm near sqrt(2 n); the threshold is therefore
    ``robust_k * sqrt(2 n)`` so that ordinary frames keep full weight and only outlier frames are
    down-weighted.
    """
    dim = 2 * n_points
    base = gtsam.noiseModel.Isotropic.Sigma(dim, float(sigma_px))
    if robust is None or robust == "none":
        return base
    k = float(robust_k) * np.sqrt(dim)
    if robust == "huber":
        est = gtsam.noiseModel.mEstimator.Huber.Create(k)
    elif robust == "cauchy":
        est = gtsam.noiseModel.mEstimator.Cauchy.Create(k)
    else:
        raise InputError(f"unknown robust loss {robust!r}; use 'huber', 'cauchy' or None")
    return gtsam.noiseModel.Robust.Create(est, base)


def make_reprojection_factors(
    batch: FrameBatch,
    sigma_px: float | np.ndarray = 0.5,
    robust: str | None = "huber",
    robust_k: float = 1.5,
) -> list[gtsam.CustomFactor]:
    """One :class:`gtsam.CustomFactor` per frame of ``batch`` (frames without points get none); ``sigma_px`` one
    pixel sigma for all frames or one per frame."""
    out = []
    sig = np.broadcast_to(np.asarray(sigma_px, dtype=float), (len(batch.frames),))
    for i in range(len(batch.frames)):
        n = batch.n_valid(i)
        if n == 0:
            continue
        noise = reprojection_noise(n, float(sig[i]), robust, robust_k)
        out.append(gtsam.CustomFactor(noise, batch.keys_of(i), lambda this, v, H, i=i: batch(i, v, H)))
    return out
