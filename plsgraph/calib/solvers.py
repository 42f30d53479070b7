"""Closed-form extrinsic rotation from paired motion samples: PLS (the paper), CCA, Procrustes, hand-eye.

Model (paper Eq. 6 and 10, row-vector convention): ``Y ~ X R_base_cam^T`` where row i of ``X`` (n x 3) is a
motion sample of the event camera expressed in the camera frame and row i of ``Y`` (n x 3) the same motion seen
by the odometry in the base frame. ``solve`` is the single entry for the vector-pair solvers; ``hand_eye`` takes
pose sequences and goes through OpenCV's ``calibrateHandEye``.

Every O(n) step is a single pass that forms 3 x 3 cross products (means, X^T X, X^T Y, Y^T Y); everything after
that is 3 x 3 algebra, so a million samples cost a few tens of milliseconds. See docs/closedform.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import inv_T, so3_log
from ..errors import DegenerateMotionError, InputError, InsufficientDataError

log = logging.getLogger(__name__)

METHODS = ("pls", "cca", "procrustes")
HAND_EYE_METHODS = ("tsai", "park", "horaud", "andreff", "daniilidis")

#: Principal motion amplitudes below this fraction of the largest count as "not excited" (see ``excitation``).
EXCITATION_REL_TOL = 0.1
#: Below this relative eigenvalue a covariance is numerically singular: whitening is undefined, CCA refuses.
_SINGULAR_REL = 1e-12
#: CCA warns when the covariance it whitens has a condition number above this.
CCA_COND_WARN = 1e3
#: CCA warns when its smallest canonical correlation is below this: that canonical pair is mostly noise.
CCA_RHO_WARN = 0.5
#: The paper's standardization constant (Eq. 11).
PAPER_EPS = 1e-10


# --------------------------------------------------------------------------------------------------- containers
@dataclass(frozen=True)
class Excitation:
    """How much a set of motion samples (n x 3) excites each direction.

    ``singular_values`` (3,) are the RMS amplitudes along the principal axes ``directions`` (3 x 3, columns),
    largest first; ``condition_number`` is largest / smallest (inf when the smallest is zero); ``rank`` counts the
    axes whose amplitude exceeds ``rel_tol`` times the largest; ``kind`` is "full" (3), "planar" (2),
    "line" (1) or "none" (0, no motion at all).
    """

    singular_values: np.ndarray
    directions: np.ndarray
    condition_number: float
    rank: int
    kind: str
    rel_tol: float

    def as_dict(self) -> dict:
        """Plain-data form (numpy arrays and Python scalars) for diagnostics and JSON reports."""
        return {
            "singular_values": self.singular_values,
            "directions": self.directions,
            "condition_number": self.condition_number,
            "rank": self.rank,
            "kind": self.kind,
            "rel_tol": self.rel_tol,
        }

    def describe(self) -> str:
        s = ", ".join(f"{v:.3g}" for v in self.singular_values)
        return f"{self.kind} (rank {self.rank}, principal RMS [{s}], condition {self.condition_number:.3g})"


@dataclass(frozen=True)
class RotationResult:
    """Result of a closed-form solver.

    ``R_base_cam`` is always a proper rotation (orthonormal, det +1). ``R_raw`` is the matrix the method produced
    before it was made a rotation (for ``pls`` with ``paper=True`` that is the paper's Eq. 20 frame, which is not
    orthonormal; the paper's error metric is evaluated on it). ``t_base_cam`` is set by ``hand_eye`` only.
    ``diagnostics`` holds the method's singular values / condition numbers / ranks; ``warnings`` says in words what
    a user should worry about (empty when nothing is suspicious).
    """

    R_base_cam: np.ndarray
    method: str
    diagnostics: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    R_raw: np.ndarray | None = None
    t_base_cam: np.ndarray | None = None


# --------------------------------------------------------------------------------------------------- validation
def _as_samples(name: str, A: np.ndarray) -> np.ndarray:
    A = np.asarray(A, dtype=float)
    if A.ndim != 2 or A.shape[1] != 3:
        raise InputError(f"{name}: expected an n x 3 array of motion samples, got shape {A.shape}")
    # Fast path: a NaN or inf anywhere makes the column sums non-finite (one BLAS pass); only then find the rows.
    bad = ~np.all(np.isfinite(A), axis=1) if not np.all(np.isfinite(np.ones(A.shape[0]) @ A)) else None
    if bad is not None and bad.any():
        rows = np.flatnonzero(bad)
        raise InputError(
            f"{name}: {rows.size} row(s) contain NaN or inf (first at row {rows[0]}); drop those samples "
            "(and the paired rows of the other sensor) before solving"
        )
    return A


def _as_weights(weights: np.ndarray | None, n: int) -> np.ndarray | None:
    if weights is None:
        return None
    w = np.asarray(weights, dtype=float)
    if w.shape != (n,):
        raise InputError(f"weights: expected shape ({n},) to match the samples, got {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise InputError("weights: must be finite and non-negative")
    if not w.sum() > 0:
        raise InputError("weights: all zero; give at least a few samples a positive weight")
    return w


def _check_pair(X: np.ndarray, Y: np.ndarray, weights: np.ndarray | None, min_samples: int, method: str):
    X = _as_samples("X (camera motion)", X)
    Y = _as_samples("Y (odometry motion)", Y)
    if X.shape[0] != Y.shape[0]:
        raise InputError(
            f"X has {X.shape[0]} samples but Y has {Y.shape[0]}; rows must be paired one to one "
            "(resample both tracks on common times first)"
        )
    w = _as_weights(weights, X.shape[0])
    n_eff = X.shape[0] if w is None else int(np.count_nonzero(w))
    if n_eff < min_samples:
        raise InsufficientDataError(
            f"method '{method}' needs at least {min_samples} paired samples with positive weight, got {n_eff}; "
            "record a longer drive or lower the decimation"
        )
    return X, Y, w


# --------------------------------------------------------------------------------------------------- moments
def _moments(X: np.ndarray, Y: np.ndarray, w: np.ndarray | None, center: bool):
    """Weighted means and the 3 x 3 blocks Sxx, Sxy, Syy of (centred if asked) X, Y, normalized by sum(w).

    Centring uses S - m m^T on the raw second moments, which avoids an n x 3 copy; when the spread is tiny next
    to the mean (cancellation would cost digits) the data are centred explicitly instead.
    """
    wsum = float(X.shape[0]) if w is None else float(w.sum())
    wv = np.ones(X.shape[0]) if w is None else w
    Xw = X if w is None else X * w[:, None]
    Yw = Y if w is None else Y * w[:, None]
    Sxx = Xw.T @ X / wsum
    Sxy = Xw.T @ Y / wsum
    Syy = Yw.T @ Y / wsum
    if not center:
        return np.zeros(3), np.zeros(3), Sxx, Sxy, Syy
    mx, my = wv @ X / wsum, wv @ Y / wsum
    Sxx_c, Sxy_c, Syy_c = Sxx - np.outer(mx, mx), Sxy - np.outer(mx, my), Syy - np.outer(my, my)
    if np.trace(Sxx_c) > 1e-6 * (mx @ mx) and np.trace(Syy_c) > 1e-6 * (my @ my):
        return mx, my, Sxx_c, Sxy_c, Syy_c
    Xc, Yc = X - mx, Y - my
    Xw = Xc if w is None else Xc * w[:, None]
    Yw = Yc if w is None else Yc * w[:, None]
    return mx, my, Xw.T @ Xc / wsum, Xw.T @ Yc / wsum, Yw.T @ Yc / wsum


def _excitation_from_second_moment(S: np.ndarray, rel_tol: float) -> Excitation:
    evals, evecs = np.linalg.eigh(0.5 * (S + S.T))
    order = np.argsort(evals)[::-1]
    sv = np.sqrt(np.clip(evals[order], 0.0, None))
    dirs = evecs[:, order]
    top = sv[0]
    # "No motion" is judged absolutely (pure zeros or rounding dust), the rest relative to the strongest axis.
    if not top > 1e-12:
        return Excitation(sv, dirs, float("inf"), 0, "none", rel_tol)
    rank = int(np.count_nonzero(sv > rel_tol * top))
    cond = float(top / sv[-1]) if sv[-1] > 0 else float("inf")
    kind = {3: "full", 2: "planar", 1: "line"}[rank]
    return Excitation(sv, dirs, cond, rank, kind, rel_tol)


def excitation(
    X: np.ndarray, weights: np.ndarray | None = None, rel_tol: float = EXCITATION_REL_TOL, center: bool = False
) -> Excitation:
    """Singular values, condition number, rank and class of motion samples ``X`` (n x 3).

    Amplitudes are RMS values about the origin (``center=False``, the default) because for velocities the mean
    motion is signal, not an offset; pass ``center=True`` to judge the spread about the mean instead.
    """
    X = _as_samples("X", X)
    if X.shape[0] == 0:
        raise InsufficientDataError("excitation: no samples")
    w = _as_weights(weights, X.shape[0])
    wsum = float(X.shape[0]) if w is None else float(w.sum())
    S = (X if w is None else X * w[:, None]).T @ X / wsum
    if center:
        m = (np.ones(X.shape[0]) if w is None else w) @ X / wsum
        S = S - np.outer(m, m)
        if not np.trace(S) > 1e-6 * (m @ m):  # cancellation: centre explicitly
            Xc = X - m
            S = (Xc if w is None else Xc * w[:, None]).T @ Xc / wsum
    return _excitation_from_second_moment(S, rel_tol)


def _excitations(Sxx: np.ndarray, Syy: np.ndarray, rel_tol: float) -> tuple[Excitation, Excitation]:
    return _excitation_from_second_moment(Sxx, rel_tol), _excitation_from_second_moment(Syy, rel_tol)


def _require_shared_motion(Sxy: np.ndarray, method: str, rel_tol: float, centred: bool) -> np.ndarray:
    """Refuse unless the two sensors share motion in at least two directions; return the cross-cov singular values.

    Each side may look excited on its own (noise is spread over every axis) while only one direction is common to
    both, e.g. V-shape velocities once their mean is removed. Covariances go as amplitude squared, hence rel_tol^2.
    """
    s = np.linalg.svd(Sxy, compute_uv=False)
    if not s[1] > rel_tol**2 * s[0]:
        raise DegenerateMotionError(
            f"{method}: the camera and odometry motions share only one direction (cross-covariance singular values "
            f"{np.array2string(s, precision=3)}); the rotation about it is unobservable. Check the pairing and time "
            "offset, then record motion in two directions (turns, curves)"
            + ("; or solve with center=False so the mean motion counts" if centred else "")
        )
    return s


def _require_two_axes(ex: Excitation, ey: Excitation, method: str, centred: bool) -> list[str]:
    """Refuse when either side is collinear or still; return warnings for weak-but-usable motion."""
    for side, e in (("camera (X)", ex), ("odometry (Y)", ey)):
        if e.kind == "none":
            raise DegenerateMotionError(
                f"{method}: the {side} motion is all zero{' after removing its mean' if centred else ''}; "
                "the rotation is unobservable. Drive the robot (forward/backward and turns) while recording"
                + ("; or solve with center=False so the mean motion counts" if centred else "")
            )
        if e.kind == "line":
            raise DegenerateMotionError(
                f"{method}: the {side} motion is (nearly) collinear: {e.describe()}. The rotation about that line "
                "is unobservable. Add motion in a second direction: turn while driving (curves, figure-eights)"
                + ("; or solve with center=False so the mean motion counts" if centred else "")
            )
    warns = []
    for side, e in (("camera (X)", ex), ("odometry (Y)", ey)):
        if e.kind == "planar":
            warns.append(
                f"{side} motion is planar: {e.describe()}; the rotation is fixed by the two excited axes and "
                "their cross product (expected for a ground robot)"
            )
    return warns


# --------------------------------------------------------------------------------------------------- solvers
def _nearest_rotation(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    U, s, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return U @ np.diag([1.0, 1.0, d]) @ Vt, s


def _procrustes(X, Y, w, center: bool, rel_tol: float) -> RotationResult:
    _, _, Sxx, Sxy, Syy = _moments(X, Y, w, center)
    ex, ey = _excitations(Sxx, Syy, rel_tol)
    warns = _require_two_axes(ex, ey, "procrustes", center)
    s = _require_shared_motion(Sxy, "procrustes", rel_tol, center)
    # Wahba: maximise tr(R^T sum w y x^T); M = Y^T W X = Sxy^T.
    M = Sxy.T
    R, _ = _nearest_rotation(M)
    diag = {
        "cross_cov_singular_values": s,
        "cross_cov_rank": int(np.count_nonzero(s > rel_tol**2 * s[0])),
        "excitation_x": ex.as_dict(),
        "excitation_y": ey.as_dict(),
        "center": center,
    }
    return RotationResult(R, "procrustes", diag, warns, R_raw=M)


def _inv_sqrt_psd(S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    evals, evecs = np.linalg.eigh(0.5 * (S + S.T))
    return (evecs / np.sqrt(evals)) @ evecs.T, (evecs * np.sqrt(evals)) @ evecs.T, evals


def _cca(X, Y, w, center: bool, rel_tol: float) -> RotationResult:
    _, _, Sxx, Sxy, Syy = _moments(X, Y, w, center)
    ex, ey = _excitations(Sxx, Syy, rel_tol)
    warns = _require_two_axes(ex, ey, "cca", center)
    s_xy = _require_shared_motion(Sxy, "cca", rel_tol, center)
    for side, S in (("camera (X)", Sxx), ("odometry (Y)", Syy)):
        ev = np.linalg.eigvalsh(S)
        if not ev[0] > _SINGULAR_REL * ev[-1]:
            raise DegenerateMotionError(
                f"cca: the {side} covariance is singular (eigenvalues {np.array2string(ev, precision=3)}), so its "
                "whitening S^(-1/2) does not exist; CCA needs motion along all three axes. Use the PLS or Procrustes "
                "solver (method='pls' / 'procrustes'; --method on the command line) for planar (ground) motion"
            )
    Wx, Sx_half, evx = _inv_sqrt_psd(Sxx)
    Wy, _, evy = _inv_sqrt_psd(Syy)
    K = Wx @ Sxy @ Wy  # whitened cross-covariance, its singular values are the canonical correlations
    U, rho, Vt = np.linalg.svd(K)
    A = Wx @ U  # canonical directions a_k of the camera side (u_k = X a_k)
    B = Wy @ Vt.T  # canonical directions b_k of the odometry side (v_k = Y b_k)
    # Noise-free Y = X R^T gives B = R A (each canonical pair is the same motion seen in two frames), so
    # R = B A^-1 = Syy^(-1/2) V U^T Sxx^(1/2); with noise it is not orthogonal and is projected onto SO(3).
    R_raw = Wy @ Vt.T @ U.T @ Sx_half
    R, _ = _nearest_rotation(R_raw)
    cond_x = float(evx[-1] / evx[0])
    cond_y = float(evy[-1] / evy[0])
    for side, c in (("camera (X)", cond_x), ("odometry (Y)", cond_y)):
        if c > CCA_COND_WARN:
            warns.append(
                f"cca: the {side} covariance is ill-conditioned (condition number {c:.3g} > {CCA_COND_WARN:.0g}); "
                "whitening amplifies the noise of the weak axis and the rotation is unreliable. Prefer 'pls'"
            )
    if rho[2] < CCA_RHO_WARN:
        warns.append(
            f"cca: the third canonical correlation is {rho[2]:.2f}: that canonical pair is noise (the motion excites "
            "only two shared directions) and the rotation built from it is unreliable. Prefer 'pls'"
        )
    diag = {
        "cross_cov_singular_values": s_xy,
        "cov_x_eigenvalues": evx[::-1],
        "cov_y_eigenvalues": evy[::-1],
        "cov_x_condition": cond_x,
        "cov_y_condition": cond_y,
        "canonical_correlations": rho,
        "canonical_directions_x": A,
        "canonical_directions_y": B,
        "excitation_x": ex.as_dict(),
        "excitation_y": ey.as_dict(),
        "center": center,
    }
    return RotationResult(R, "cca", diag, warns, R_raw=R_raw)


def _pls_regression(Sxx: np.ndarray, Sxy: np.ndarray, K: int | None, rel_tol: float):
    """NIPALS PLS (Eqs. 13-19) on 3 x 3 Gram blocks of standardized data; returns R_std and diagnostics.

    ``K`` None keeps at least two components and a third one if its covariance sqrt(lambda_3) exceeds ``rel_tol``^2
    times the first one's (covariances go as amplitude squared; ``rel_tol`` is an amplitude ratio).

    With E_k = X~ M_k every deflated block is a 3 x 3 map of X~, so t_k, p_k and E_k^T Y~ are all expressible
    through Sxx = X~^T X~ and Sxy = X~^T Y~: no n x K score matrix is ever formed.
    """
    M = np.eye(3)
    Ws, Ps, Rs, lams = [], [], [], []
    total = float(np.sum(Sxy**2))
    for _ in range(3 if K is None else K):
        G = M.T @ Sxy  # E_k^T Y~
        lam, vec = np.linalg.eigh(G @ G.T)  # Eq. 14: X~^T Y~ Y~^T X~ on the deflated block
        wk = vec[:, -1]
        # Eigenvectors have no sign; fix one so that results are reproducible.
        wk = wk * (np.sign(wk[np.argmax(np.abs(wk))]) or 1.0)
        if not (total > 0 and lam[-1] > 1e-20 * total):
            break  # nothing left to explain: a further component would be rounding noise
        if K is None and len(lams) >= 2 and not np.sqrt(lam[-1]) > rel_tol**2 * np.sqrt(lams[0]):
            break  # the remaining covariance is at noise level: regressing it only tilts the rotation
        rk = M @ wk  # t_k = E_k w_k = X~ r_k
        tt = float(rk @ Sxx @ rk)
        if not tt > 1e-14 * np.trace(Sxx):
            break
        pk = M.T @ Sxx @ rk / tt  # Eq. 17: p = E^T t / t^T t
        M = M @ (np.eye(3) - np.outer(wk, pk))  # Eq. 18: E <- E - t p^T
        Ws.append(wk)
        Ps.append(pk)
        Rs.append(rk)
        lams.append(float(lam[-1]))
    if not Ws:
        raise DegenerateMotionError(
            "pls: the camera and odometry motions have no covariance at all; check that the rows are paired "
            "(same times, correct time offset) and that the robot moved"
        )
    W, P, Rk = np.array(Ws).T, np.array(Ps).T, np.array(Rs).T
    TtT = Rk.T @ Sxx @ Rk  # T^T T
    TtY = Rk.T @ Sxy  # T^T Y~
    C = np.linalg.pinv(TtT) @ TtY  # Eq. 19: C = T^+ Y~ (T^+ = (T^T T)^+ T^T holds for any T)
    PtW = P.T @ W
    Wstar = W @ np.linalg.inv(PtW)  # W* = W (P^T W)^-1, P^T W is unit upper triangular for NIPALS
    R_std = Wstar @ C  # Eq. 20
    diag = {
        "n_components": len(Ws),
        "component_eigenvalues": np.array(lams),
        "explained_covariance": np.array(lams) / total if total > 0 else np.zeros(len(lams)),
        "scores_gram_singular_values": np.linalg.svd(TtT, compute_uv=False),
        "PtW_condition": float(np.linalg.cond(PtW)),
    }
    return R_std, diag


def _pls(
    X, Y, w, n_components, center: bool, scale: str, eps: float, rotation: str, paper: bool, rel_tol: float
) -> RotationResult:
    _, _, Sxx, Sxy, Syy = _moments(X, Y, w, center)
    ex, ey = _excitations(Sxx, Syy, rel_tol)
    warns = _require_two_axes(ex, ey, "pls", center)
    s_xy = _require_shared_motion(Sxy, "pls", rel_tol, center)
    # Standardization (Eq. 11). sigma is the std about the mean when centred, the RMS about zero otherwise.
    if scale == "column":
        sx = np.sqrt(np.clip(np.diag(Sxx), 0, None)) + eps
        sy = np.sqrt(np.clip(np.diag(Syy), 0, None)) + eps
    elif scale == "block":
        # One factor per sensor: unit-free like the paper's, but it keeps the rotation equivariance.
        sx = np.full(3, np.sqrt(np.trace(Sxx) / 3.0) + eps)
        sy = np.full(3, np.sqrt(np.trace(Syy) / 3.0) + eps)
    elif scale == "none":
        sx = sy = np.ones(3)
    else:
        raise InputError(f"pls: scale must be 'column', 'block' or 'none', got {scale!r}")
    Sxx_s = Sxx / np.outer(sx, sx)
    Sxy_s = Sxy / np.outer(sx, sy)
    K = None if n_components is None else int(n_components)
    if K is not None and K not in (2, 3):
        # One component gives a rank-1 regression, which cannot fix a rotation.
        raise InputError(f"pls: n_components must be 2 or 3 (or None for automatic), got {n_components}")
    if rotation not in ("fitted", "polar", "rows"):
        raise InputError(f"pls: rotation must be 'fitted', 'polar' or 'rows', got {rotation!r}")
    R_std, diag = _pls_regression(Sxx_s, Sxy_s, K, rel_tol)
    R_reg = (R_std / sx[:, None]) * sy[None, :]  # undo the standardization: Y ~ X R_reg, R_reg ~ R_base_cam^T
    # Fraction of Y~ variance the regression explains, from the Gram blocks alone.
    Syy_s = Syy / np.outer(sy, sy)
    resid = np.trace(Syy_s) - 2 * np.trace(R_std.T @ Sxy_s) + np.trace(R_std.T @ Sxx_s @ R_std)
    diag.update(
        {
            "cross_cov_singular_values": s_xy,
            "r2_y": float(1.0 - resid / np.trace(Syy_s)) if np.trace(Syy_s) > 0 else float("nan"),
            "regression_matrix": R_reg,
            "regression_singular_values": np.linalg.svd(R_reg, compute_uv=False),
            "excitation_x": ex.as_dict(),
            "excitation_y": ey.as_dict(),
            "center": center,
            "scale": scale,
            "rotation": rotation,
            "paper": paper,
        }
    )
    if rotation == "rows":
        # Eq. 20-21 verbatim: rows 1 and 2 of R (= columns 1, 2 of R_base_cam) normalized, third by cross product.
        r1, r2 = R_reg[0], R_reg[1]
        n1, n2 = np.linalg.norm(r1), np.linalg.norm(r2)
        c = np.cross(r1 / n1, r2 / n2)
        nc = np.linalg.norm(c)
        if not (n1 > 0 and n2 > 0 and nc > 1e-12):
            raise DegenerateMotionError(
                "pls(rotation='rows'): rows 1 and 2 of the regression matrix are zero or parallel, so the paper's "
                "cross-product frame (Eq. 20) is undefined; this happens when the degenerate axis is not the "
                "camera's z. Use paper=False"
            )
        R_raw = np.column_stack([r1 / n1, r2 / n2, c / nc])
        R, _ = _nearest_rotation(R_raw)
        dot = float(abs(r1 @ r2) / (n1 * n2))
        diag["paper_r1_r2_cos"] = dot
        if dot > 1e-6:
            warns.append(
                f"pls(rotation='rows'): the paper's frame is not orthonormal (|cos(r1, r2)| = {dot:.2g}); "
                "R_base_cam is its nearest rotation, R_raw keeps the paper's matrix"
            )
        return RotationResult(R, "pls", diag, warns, R_raw=R_raw)
    # Both remaining constructions take a nearest rotation with the determinant fix, which uses every row, so they
    # work whichever side and axis is degenerate: a rank-2 matrix still fixes the third axis through det = +1.
    # "polar" projects R_reg^T itself; "fitted" (default) is the rotation that best reproduces the PLS
    # prediction Y^ = X R_reg, i.e. the polar factor of Y^T X = R_reg^T Sxx. It weights each direction by how much
    # it was excited, where "polar" lets a barely excited, badly estimated row count as much as the others.
    M = R_reg.T if rotation == "polar" else R_reg.T @ Sxx
    R, s = _nearest_rotation(M)
    if not s[1] > rel_tol**2 * s[0]:
        raise DegenerateMotionError(
            f"pls: the regression matrix has rank < 2 (singular values {np.array2string(s, precision=3)}); the "
            "motion determines only one axis. Add turns so the robot moves in two directions"
        )
    return RotationResult(R, "pls", diag, warns, R_raw=M)


_MIN_SAMPLES = {"pls": 3, "cca": 4, "procrustes": 2}


def solve(
    X: np.ndarray,
    Y: np.ndarray,
    method: str = "pls",
    weights: np.ndarray | None = None,
    *,
    center: bool | None = None,
    rel_tol: float = EXCITATION_REL_TOL,
    **options,
) -> RotationResult:
    """Estimate ``R_base_cam`` from paired motion samples with ``Y ~ X R_base_cam^T``.

    X: n x 3 camera motion (camera frame); Y: n x 3 odometry motion (base frame), row i paired with row i;
    weights: optional (n,) non-negative per-sample weights. ``method``:

    - "pls", options: ``n_components`` 2, 3 or None (default: keep components whose covariance exceeds
      ``rel_tol``^2 of the first, i.e. 3 for 3-D motion, 2 for planar); ``scale`` "block" (default, one factor per
      sensor, rotation-equivariant) | "column" (the paper's Eq. 11) | "none"; ``rotation`` "fitted" (default,
      the rotation that best reproduces the PLS prediction) | "polar" (nearest rotation of the regression
      matrix) | "rows" (the paper's Eq. 20, only valid when the camera's z is the unexcited axis); ``eps``
      (1e-10); ``paper`` (False). ``paper=True`` is Eqs. 11-21 verbatim: centring, column standardization,
      K = 3, rows 1-2 plus cross product; the raw (non-orthonormal) frame is in ``R_raw``.
    - "cca": whitened cross-covariance, canonical directions A, B, R = B A^-1 projected onto SO(3).
    - "procrustes": Wahba / Kabsch, SVD of sum w_i y_i x_i^T with the determinant fix.

    ``center`` (default False, the paper and the CCA convention use True): remove the (weighted) mean of X and Y
    first. For velocities the mean is signal (a robot mostly drives forward), see docs/paper_tables.md.
    Raises InputError, InsufficientDataError or DegenerateMotionError; weak motion gives ``warnings``.
    """
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; choose one of {', '.join(METHODS)} (or hand_eye() for poses)")
    X, Y, w = _check_pair(X, Y, weights, _MIN_SAMPLES[method], method)
    if method == "procrustes":
        if options:
            raise InputError(f"procrustes takes no options, got {sorted(options)}")
        return _procrustes(X, Y, w, bool(center) if center is not None else False, rel_tol)
    if method == "cca":
        if options:
            raise InputError(f"cca takes no options, got {sorted(options)}")
        return _cca(X, Y, w, bool(center) if center is not None else False, rel_tol)
    paper = bool(options.pop("paper", False))
    defaults = {"n_components": 3, "scale": "column", "rotation": "rows"} if paper else {}
    n_components = options.pop("n_components", defaults.get("n_components"))
    scale = options.pop("scale", defaults.get("scale", "block"))
    rotation = options.pop("rotation", defaults.get("rotation", "fitted"))
    eps = float(options.pop("eps", PAPER_EPS))
    if options:
        raise InputError(f"pls: unknown options {sorted(options)}; known: n_components, scale, rotation, eps, paper")
    if center is None:
        center = paper
    return _pls(X, Y, w, n_components, bool(center), scale, eps, rotation, paper, rel_tol)


# --------------------------------------------------------------------------------------------------- hand-eye
def _cv2_methods() -> dict[str, int]:
    import cv2

    if not hasattr(cv2, "calibrateHandEye"):
        raise InputError(
            "this OpenCV build has no calibrateHandEye (opencv 5.0 wheels lack it); install opencv-python-headless<5"
        )
    return {
        "tsai": cv2.CALIB_HAND_EYE_TSAI,
        "park": cv2.CALIB_HAND_EYE_PARK,
        "horaud": cv2.CALIB_HAND_EYE_HORAUD,
        "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
        "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
    }


def _check_poses(name: str, T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise InputError(f"{name}: expected an (n, 4, 4) stack of poses, got shape {T.shape}")
    bad = ~np.all(np.isfinite(T), axis=(1, 2))
    if bad.any():
        raise InputError(f"{name}: {int(bad.sum())} pose(s) contain NaN or inf (first {np.flatnonzero(bad)[0]})")
    return T


def _planar_hand_eye_t(t: np.ndarray, axis: np.ndarray, method: str, warns: list[str]) -> np.ndarray:
    """The part of a hand-eye translation that motion about one ``axis`` (base frame) determines.

    A X = X B fixes nothing of t along the common rotation axis; OpenCV's solvers still return a number there,
    anywhere from zero to 1e12 m. That component is removed, and when the axis is the base's vertical (a robot on
    a floor) the height is NaN: unknown, as the planar closed form reports it.
    """
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    along = float(t @ a)
    t = t - along * a
    if abs(a[2]) > 0.95:
        t[2] = np.nan
        warns.append(
            f"hand_eye({method}): the camera height is not determined by motion on a floor (OpenCV returned "
            f"{along:.3g} m along the turn axis); it is left unknown"
        )
    else:
        warns.append(
            f"hand_eye({method}): the translation along the common turn axis {np.round(a, 3)} is not determined "
            f"(OpenCV returned {along:.3g} m there); it is set to zero"
        )
    return t


def hand_eye(
    T_world_base_seq: np.ndarray,
    T_board_cam_seq: np.ndarray,
    method: str = "andreff",
    max_poses: int = 60,
    rel_tol: float = EXCITATION_REL_TOL,
) -> RotationResult:
    """Hand-eye calibration A X = X B through ``cv2.calibrateHandEye``, for comparison with the paper's Andreff.

    ``T_world_base_seq`` (n, 4, 4) odometry poses and ``T_board_cam_seq`` (n, 4, 4) camera poses relative to the
    board, sampled at the same instants. A = T_world_base_i^-1 T_world_base_j (relative base motion),
    B = T_board_cam_i^-1 T_board_cam_j (relative camera motion), X = T_base_cam. In OpenCV's words the robot
    base is our ``world``, the gripper our ``base``, the target our ``board``, and cam2gripper our T_base_cam.
    OpenCV forms motion pairs from all pose pairs, so at most ``max_poses`` evenly spaced poses are used.
    The result carries ``t_base_cam``; for planar motion its component along the rotation axis is unobservable
    and the result's warnings say so.
    """
    methods = _cv2_methods()
    if method not in methods:
        raise InputError(f"unknown hand-eye method {method!r}; choose one of {', '.join(HAND_EYE_METHODS)}")
    Tb = _check_poses("T_world_base_seq", T_world_base_seq)
    Tc = _check_poses("T_board_cam_seq", T_board_cam_seq)
    if Tb.shape[0] != Tc.shape[0]:
        raise InputError(
            f"T_world_base_seq has {Tb.shape[0]} poses but T_board_cam_seq has {Tc.shape[0]}; sample both tracks "
            "at the same instants first"
        )
    if Tb.shape[0] < 3:
        raise InsufficientDataError(f"hand_eye needs at least 3 poses (2 motions), got {Tb.shape[0]}")
    warns: list[str] = []
    if Tb.shape[0] > max_poses:
        idx = np.unique(np.linspace(0, Tb.shape[0] - 1, max_poses).round().astype(int))
        Tb, Tc = Tb[idx], Tc[idx]
    # Excitation of the relative rotations (axis * angle, all pairs against the first pose) on both sides.
    A_rot = so3_log(np.einsum("ji,njk->nik", Tb[0, :3, :3], Tb[1:, :3, :3]))
    B_rot = so3_log(np.einsum("ji,njk->nik", Tc[0, :3, :3], Tc[1:, :3, :3]))
    ea = _excitation_from_second_moment(A_rot.T @ A_rot / len(A_rot), rel_tol)
    eb = _excitation_from_second_moment(B_rot.T @ B_rot / len(B_rot), rel_tol)
    if ea.kind == "none" or eb.kind == "none":
        raise DegenerateMotionError(
            "hand_eye: the poses contain no rotation, so A X = X B cannot fix the rotation of X; turn the robot "
            "while recording or use the velocity-based PLS solver (method='pls'; --method pls on the command line)"
        )
    if ea.rank < 2 or eb.rank < 2:
        warns.append(
            "hand_eye: all relative rotations share one axis (planar motion); A X = X B leaves the translation along "
            "that axis unobservable and the rotation relies on the translations alone. Expect a poor result"
        )
    import cv2

    T_cam_board = inv_T(Tc)
    quiet = getattr(getattr(cv2, "utils", None), "logging", None)  # OpenCV prints its own failures on stderr
    level = quiet.getLogLevel() if quiet is not None else None
    try:
        if quiet is not None:
            quiet.setLogLevel(quiet.LOG_LEVEL_SILENT)  # a failure is told below (or by the NaN check), once
        R_c, t_c = cv2.calibrateHandEye(
            list(Tb[:, :3, :3]),
            list(Tb[:, :3, 3:4]),
            list(T_cam_board[:, :3, :3]),
            list(T_cam_board[:, :3, 3:4]),
            method=methods[method],
        )
    except cv2.error as exc:  # OpenCV raises on degenerate systems (e.g. Andreff under planar motion)
        raise DegenerateMotionError(
            f"hand_eye({method}): OpenCV failed ({str(exc).strip().splitlines()[-1]}); the motion does not "
            "determine X. Add rotations about different axes or use the velocity-based PLS solver (method='pls'; "
            "--method pls on the command line)"
        ) from exc
    finally:
        if quiet is not None:
            quiet.setLogLevel(level)
    R_c = np.asarray(R_c, dtype=float)
    t_c = np.asarray(t_c, dtype=float).reshape(3)
    if not (np.all(np.isfinite(R_c)) and np.all(np.isfinite(t_c))):
        raise DegenerateMotionError(
            f"hand_eye({method}): OpenCV returned NaN; the motion does not determine X. Add rotations about "
            "different axes or use the velocity-based PLS solver (method='pls'; --method pls on the command line)"
        )
    R, s = _nearest_rotation(R_c)
    if ea.rank < 2:
        t_c = _planar_hand_eye_t(t_c, ea.directions[:, 0], method, warns)
    log.debug("hand_eye(%s) on %d poses", method, Tb.shape[0])
    diag = {
        "n_poses": int(Tb.shape[0]),
        "rotation_excitation_base": ea.as_dict(),
        "rotation_excitation_cam": eb.as_dict(),
        "opencv_R_singular_values": s,
    }
    return RotationResult(R, f"hand_eye_{method}", diag, warns, R_raw=R_c, t_base_cam=t_c)
