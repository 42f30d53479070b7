import numpy as np
import pytest

from plsgraph.calib.solvers import CCA_COND_WARN, RotationResult, excitation, hand_eye, solve
from plsgraph.core.geometry import inv_T, is_rotation, random_rotation_zyx, se3_exp, so3_log
from plsgraph.errors import DegenerateMotionError, InputError, InsufficientDataError

# Every solver configuration the tests exercise; (name, solve kwargs).
CONFIGS = [
    ("pls", {"method": "pls"}),
    ("pls_centred", {"method": "pls", "center": True}),
    ("pls_polar", {"method": "pls", "rotation": "polar"}),
    ("pls_column", {"method": "pls", "scale": "column"}),
    ("pls_none", {"method": "pls", "scale": "none"}),
    ("pls_paper", {"method": "pls", "paper": True}),
    ("cca", {"method": "cca"}),
    ("cca_centred", {"method": "cca", "center": True}),
    ("procrustes", {"method": "procrustes"}),
    ("procrustes_centred", {"method": "procrustes", "center": True}),
]
IDS = [c[0] for c in CONFIGS]


def angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle between two rotations via the log map: accurate near zero, where arccos of the trace is not."""
    return float(np.degrees(np.linalg.norm(so3_log(R_a @ R_b.T))))


def motion_3d(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    # A forward bias as a driving robot has, plus motion along every axis.
    return rng.normal(size=(n, 3)) * [1.0, 0.7, 0.5] + [0.8, 0.0, 0.0]


def planar(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    P = rng.normal(size=(n, 3)) * [1.0, 0.6, 0.0] + [0.5, 0.0, 0.0]
    P[:, 2] = 0.0
    return P


@pytest.mark.parametrize("name,kw", CONFIGS, ids=IDS)
def test_noise_free_3d_recovery(name, kw):
    rng = np.random.default_rng(1)
    w = rng.uniform(0.2, 2.0, size=200)
    for _ in range(4):
        R = random_rotation_zyx(rng)
        X = motion_3d(rng)
        for weights in (None, w):
            res = solve(X, X @ R.T, weights=weights, **kw)
            assert isinstance(res, RotationResult)
            assert is_rotation(res.R_base_cam, 1e-10)
            assert angle_deg(res.R_base_cam, R) < 1e-6
            assert res.warnings == [] or name == "pls_paper"


@pytest.mark.parametrize("side", ["camera", "base"])
@pytest.mark.parametrize("kw", [{"method": "pls"}, {"method": "procrustes"}, {"method": "pls", "rotation": "polar"}])
def test_noise_free_planar_recovery_either_side(side, kw):
    rng = np.random.default_rng(2)
    for _ in range(4):
        R = random_rotation_zyx(rng)
        P = planar(rng)
        # Camera side: X = [x1, x2, 0] as the paper writes; base side: the odometry's z is zero, as on a real robot.
        X, Y = (P, P @ R.T) if side == "camera" else (P @ R, P)
        res = solve(X, Y, **kw)
        assert is_rotation(res.R_base_cam, 1e-10)
        assert angle_deg(res.R_base_cam, R) < 1e-6
        assert any("planar" in w for w in res.warnings)


def test_planar_with_arbitrary_zero_axis():
    """The unexcited axis need not be z: rotate a planar motion so its normal points anywhere."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        R, Q = random_rotation_zyx(rng), random_rotation_zyx(rng)
        X = planar(rng) @ Q.T
        for method in ("pls", "procrustes"):
            assert angle_deg(solve(X, X @ R.T, method).R_base_cam, R) < 1e-6


def test_paper_pls_only_works_with_zero_axis_on_camera_z():
    rng = np.random.default_rng(4)
    R = random_rotation_zyx(rng)
    P = planar(rng)
    res = solve(P, P @ R.T, "pls", paper=True)
    assert angle_deg(res.R_base_cam, R) < 1e-6
    # Zero axis on the base side: the paper's rows 1-2 construction is not the rotation (documented pitfall).
    res = solve(P @ R, P, "pls", paper=True)
    assert angle_deg(res.R_base_cam, R) > 1.0
    assert angle_deg(solve(P @ R, P, "pls").R_base_cam, R) < 1e-6


def test_cca_planar_singular_refuses_and_near_singular_is_reported():
    rng = np.random.default_rng(5)
    R = random_rotation_zyx(rng)
    P = planar(rng, 400)
    with pytest.raises(DegenerateMotionError, match="whitening"):
        solve(P, P @ R.T, "cca")
    X = P + rng.normal(scale=[0.0, 0.0, 0.005], size=P.shape)  # barely excited z: near-singular S_xx
    Y = X @ R.T + rng.normal(scale=0.005, size=X.shape)
    res = solve(X, Y, "cca")
    assert is_rotation(res.R_base_cam, 1e-10)
    assert res.diagnostics["cov_x_condition"] > CCA_COND_WARN
    assert any("ill-conditioned" in w for w in res.warnings)
    assert res.diagnostics["canonical_correlations"].shape == (3,)
    # PLS and Procrustes on the same data stay accurate.
    for method in ("pls", "procrustes"):
        assert angle_deg(solve(X, Y, method).R_base_cam, R) < 1.0


def test_cca_flags_noise_canonical_pair_on_planar_motion():
    """Both sensors measure the same planar motion with their own noise: CCA's third pair is pure noise."""
    rng = np.random.default_rng(20)
    R = random_rotation_zyx(rng)
    P = planar(rng, 300)
    X = P + rng.normal(scale=0.1, size=P.shape)
    Y = P @ R.T + rng.normal(scale=0.1, size=P.shape)
    res = solve(X, Y, "cca")
    assert res.diagnostics["canonical_correlations"][2] < 0.5
    assert any("canonical correlation" in w for w in res.warnings)
    assert angle_deg(solve(X, Y, "pls").R_base_cam, R) < 3.0


@pytest.mark.parametrize("name,kw", CONFIGS, ids=IDS)
def test_refuses_when_sensors_share_one_direction(name, kw):
    """Each side looks excited (noise on every axis) but only one motion direction is common to both."""
    rng = np.random.default_rng(21)
    R = random_rotation_zyx(rng)
    clean = np.outer(rng.normal(size=400), [0.6, 0.8, 0.0])
    X = clean + rng.normal(scale=0.25, size=clean.shape)
    Y = clean @ R.T + rng.normal(scale=0.25, size=clean.shape)
    assert excitation(X).kind == "full"
    with pytest.raises(DegenerateMotionError, match="one direction"):
        solve(X, Y, **kw)


@pytest.mark.parametrize("name,kw", [c for c in CONFIGS if c[0] not in ("pls_paper", "pls_column")], ids=lambda c: c)
def test_rotation_equivariance_with_noise(name, kw):
    """Re-expressing either sensor's frame changes the estimate by exactly that rotation (noise included)."""
    rng = np.random.default_rng(6)
    R = random_rotation_zyx(rng)
    X = motion_3d(rng)
    Y = X @ R.T + rng.normal(scale=0.1, size=X.shape)
    base = solve(X, Y, **kw).R_base_cam
    Q1, Q2 = random_rotation_zyx(rng), random_rotation_zyx(rng)
    # x' = Q1 x and y' = Q2 y  =>  R' = Q2 R Q1^T
    moved = solve(X @ Q1.T, Y @ Q2.T, **kw).R_base_cam
    assert angle_deg(moved, Q2 @ base @ Q1.T) < 1e-8


@pytest.mark.parametrize("name,kw", CONFIGS, ids=IDS)
def test_scale_invariance_and_proper_rotation_with_noise(name, kw):
    rng = np.random.default_rng(7)
    R = random_rotation_zyx(rng)
    X = motion_3d(rng)
    Y = X @ R.T + rng.normal(scale=0.2, size=X.shape)
    a = solve(X, Y, **kw)
    b = solve(3.7 * X, 0.02 * Y, **kw)  # units (m vs mm, px) must not matter
    for res in (a, b):
        assert is_rotation(res.R_base_cam, 1e-10)
    assert angle_deg(a.R_base_cam, b.R_base_cam) < 1e-8
    assert angle_deg(a.R_base_cam, R) < 5.0


def test_paper_mode_keeps_raw_matrix_and_warns():
    rng = np.random.default_rng(8)
    R = random_rotation_zyx(rng)
    X = motion_3d(rng)
    Y = X @ R.T + rng.normal(scale=0.3, size=X.shape)
    res = solve(X, Y, "pls", paper=True)
    assert is_rotation(res.R_base_cam, 1e-10)
    assert not is_rotation(res.R_raw, 1e-6)  # the paper's r2 is not orthogonalized against r1
    assert np.allclose(np.linalg.norm(res.R_raw, axis=0), 1.0)
    assert any("not orthonormal" in w for w in res.warnings)
    assert res.diagnostics["n_components"] == 3


@pytest.mark.parametrize("method", ["pls", "cca", "procrustes"])
def test_centring_equals_solving_centred_data(method):
    """Centring through the second moments must agree with subtracting the means, even for a large mean."""
    rng = np.random.default_rng(19)
    R = random_rotation_zyx(rng)
    X = motion_3d(rng)
    Y = X @ R.T + rng.normal(scale=0.1, size=X.shape)
    for offset in (0.0, 1e3, 1e5):
        Xo, Yo = X + offset, Y - offset
        a = solve(Xo, Yo, method, center=True).R_base_cam
        b = solve(Xo - Xo.mean(0), Yo - Yo.mean(0), method).R_base_cam
        assert angle_deg(a, b) < 1e-6
    assert np.allclose(excitation(X + 1e5, center=True).singular_values, excitation(X - X.mean(0)).singular_values)


def test_weights_equal_dropping_rows():
    rng = np.random.default_rng(9)
    R = random_rotation_zyx(rng)
    X = motion_3d(rng)
    Y = X @ R.T + rng.normal(scale=0.1, size=X.shape)
    Y[:20] = rng.normal(scale=5.0, size=(20, 3))  # outliers
    w = np.ones(len(X))
    w[:20] = 0.0
    for method in ("pls", "cca", "procrustes"):
        a = solve(X, Y, method, weights=w).R_base_cam
        b = solve(X[20:], Y[20:], method).R_base_cam
        assert angle_deg(a, b) < 1e-8


def _nipals_reference(Xs: np.ndarray, Ys: np.ndarray, K: int) -> np.ndarray:
    """Textbook NIPALS on the data matrices (explicit deflation of E), to check the 3 x 3 Gram formulation."""
    E = Xs.copy()
    W, P, T = [], [], []
    for _ in range(K):
        lam, vec = np.linalg.eigh(E.T @ Ys @ Ys.T @ E)
        w = vec[:, -1]
        t = E @ w
        p = E.T @ t / (t @ t)
        E = E - np.outer(t, p)
        W.append(w), P.append(p), T.append(t)
    W, P, T = np.array(W).T, np.array(P).T, np.array(T).T
    C = np.linalg.pinv(T) @ Ys
    return W @ np.linalg.inv(P.T @ W) @ C


@pytest.mark.parametrize("K", [2, 3])
def test_pls_regression_matches_explicit_nipals(K):
    rng = np.random.default_rng(10)
    R = random_rotation_zyx(rng)
    X = motion_3d(rng)
    Y = X @ R.T + rng.normal(scale=0.3, size=X.shape)
    res = solve(X, Y, "pls", n_components=K, scale="column", center=True, rotation="polar")
    Xc, Yc = X - X.mean(0), Y - Y.mean(0)
    sx, sy = Xc.std(0) + 1e-10, Yc.std(0) + 1e-10
    B = _nipals_reference(Xc / sx, Yc / sy, K)
    assert np.allclose(res.diagnostics["regression_matrix"], (B / sx[:, None]) * sy, atol=1e-10)
    assert res.diagnostics["n_components"] == K


def test_default_components_follow_excitation():
    rng = np.random.default_rng(11)
    R = random_rotation_zyx(rng)
    X = motion_3d(rng)
    assert solve(X, X @ R.T + rng.normal(scale=0.05, size=X.shape)).diagnostics["n_components"] == 3
    P = planar(rng)
    Xp = P + rng.normal(scale=0.05, size=P.shape)
    Yp = P @ R.T + rng.normal(scale=0.05, size=P.shape)
    assert solve(Xp, Yp).diagnostics["n_components"] == 2


def test_excitation_classes_and_values():
    rng = np.random.default_rng(12)
    X = rng.normal(size=(500, 3)) * [3.0, 2.0, 1.0]
    e = excitation(X)
    assert e.kind == "full" and e.rank == 3
    # Singular values are RMS amplitudes along the principal axes.
    assert np.allclose(e.singular_values**2, np.sort(np.linalg.eigvalsh(X.T @ X / len(X)))[::-1])
    assert np.isclose(e.condition_number, e.singular_values[0] / e.singular_values[2])
    assert excitation(planar(rng)).kind == "planar"
    d = np.array([1.0, 2.0, -0.5])
    assert excitation(np.outer(rng.normal(size=100), d)).kind == "line"
    assert excitation(np.zeros((10, 3))).kind == "none"
    # A constant forward velocity is a line about the origin, nothing at all about its mean.
    fwd = np.tile([1.0, 0.0, 0.0], (50, 1))
    assert excitation(fwd).kind == "line"
    assert excitation(fwd, center=True).kind == "none"


@pytest.mark.parametrize("method", ["pls", "cca", "procrustes"])
def test_bad_inputs_raise_typed_errors(method):
    rng = np.random.default_rng(13)
    R = random_rotation_zyx(rng)
    X = motion_3d(rng, 50)
    Y = X @ R.T
    Xn = X.copy()
    Xn[7, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        solve(Xn, Y, method)
    Yi = Y.copy()
    Yi[3, 0] = np.inf
    with pytest.raises(InputError, match="NaN or inf"):
        solve(X, Yi, method)
    with pytest.raises(InputError, match="paired"):
        solve(X, Y[:-1], method)
    with pytest.raises(InputError, match="n x 3"):
        solve(X[:, :2], Y[:, :2], method)
    with pytest.raises(InsufficientDataError):
        solve(X[:1], Y[:1], method)
    with pytest.raises(InputError, match="weights"):
        solve(X, Y, method, weights=-np.ones(len(X)))
    with pytest.raises(InputError, match="weights"):
        solve(X, Y, method, weights=np.ones(3))
    with pytest.raises(DegenerateMotionError, match="zero"):
        solve(np.zeros_like(X), np.zeros_like(Y), method)
    line = np.outer(rng.normal(size=len(X)), [0.3, 1.0, 0.2])
    with pytest.raises(DegenerateMotionError, match="collinear"):
        solve(line, line @ R.T, method)
    with pytest.raises(InputError):
        solve(X, Y, method, bogus=1)


def test_centring_refuses_constant_forward_motion():
    """Driving straight at constant speed with a few sideways wiggles: the mean is the signal."""
    rng = np.random.default_rng(14)
    R = random_rotation_zyx(rng)
    X = np.tile([1.0, 0.0, 0.0], (100, 1))
    X[::2, 1] = 0.5  # sideways component, so raw motion spans two directions
    Y = X @ R.T
    assert angle_deg(solve(X, Y, "pls").R_base_cam, R) < 1e-6
    with pytest.raises(DegenerateMotionError, match="center=False"):
        solve(X, Y, "pls", center=True)


def test_unknown_method_and_option_values():
    X = motion_3d(np.random.default_rng(15), 20)
    with pytest.raises(InputError, match="unknown method"):
        solve(X, X, "svd")
    for K in (1, 4):
        with pytest.raises(InputError, match="n_components"):
            solve(X, X, "pls", n_components=K)
    with pytest.raises(InputError, match="scale"):
        solve(X, X, "pls", scale="robust")
    with pytest.raises(InputError, match="rotation"):
        solve(X, X, "pls", rotation="qr")


def _hand_eye_poses(rng, planar_motion: bool, n: int = 25):
    T_base_cam = se3_exp(np.concatenate([rng.normal(size=3), rng.normal(scale=0.2, size=3)]))
    xi = rng.normal(size=(n, 6))
    if planar_motion:
        xi[:, [0, 1, 5]] = 0.0  # yaw and floor translation only
    T_world_base = se3_exp(xi)
    T_world_board = se3_exp(rng.normal(size=6))
    return T_world_base, inv_T(T_world_board) @ T_world_base @ T_base_cam, T_base_cam


@pytest.mark.parametrize("method", ["tsai", "park", "horaud", "andreff", "daniilidis"])
def test_hand_eye_noise_free_6dof(method):
    rng = np.random.default_rng(16)
    Twb, Tbc, X = _hand_eye_poses(rng, planar_motion=False)
    res = hand_eye(Twb, Tbc, method)
    assert is_rotation(res.R_base_cam, 1e-10)
    assert angle_deg(res.R_base_cam, X[:3, :3]) < 1e-6
    assert np.allclose(res.t_base_cam, X[:3, 3], atol=1e-6)
    assert res.method == f"hand_eye_{method}" and res.warnings == []


def test_hand_eye_planar_is_flagged_or_refused():
    rng = np.random.default_rng(17)
    Twb, Tbc, _ = _hand_eye_poses(rng, planar_motion=True)
    for method in ("tsai", "park", "horaud", "andreff", "daniilidis"):
        try:
            res = hand_eye(Twb, Tbc, method)
        except DegenerateMotionError:
            continue
        assert any("one axis" in w for w in res.warnings)
        assert is_rotation(res.R_base_cam, 1e-8)


def test_hand_eye_bad_inputs():
    rng = np.random.default_rng(18)
    Twb, Tbc, _ = _hand_eye_poses(rng, planar_motion=False, n=6)
    with pytest.raises(InputError, match="same instants"):
        hand_eye(Twb, Tbc[:-1])
    bad = Tbc.copy()
    bad[2, 0, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        hand_eye(Twb, bad)
    with pytest.raises(InsufficientDataError):
        hand_eye(Twb[:2], Tbc[:2])
    with pytest.raises(InputError, match="unknown hand-eye"):
        hand_eye(Twb, Tbc, "shah")
    still = np.repeat(np.eye(4)[None], 6, axis=0)
    with pytest.raises(DegenerateMotionError, match="no rotation"):
        hand_eye(still, still)


def _plain(v) -> bool:
    if isinstance(v, dict):
        return all(isinstance(k, str) and _plain(x) for k, x in v.items())
    if isinstance(v, list | tuple):
        return all(_plain(x) for x in v)
    return isinstance(v, np.ndarray | float | int | str | bool | np.floating | np.integer)


def test_diagnostics_are_plain_data_for_reports():
    rng = np.random.default_rng(22)
    R = random_rotation_zyx(rng)
    X = motion_3d(rng)
    Y = X @ R.T + rng.normal(scale=0.1, size=X.shape)
    results = [solve(X, Y, **kw) for _, kw in CONFIGS]
    Twb, Tbc, _ = _hand_eye_poses(rng, planar_motion=False)
    results.append(hand_eye(Twb, Tbc))
    for res in results:
        assert _plain(res.diagnostics), res.method
        assert all(isinstance(w, str) for w in res.warnings)


def test_random_inputs_give_a_rotation_or_a_typed_error():
    """Property: whatever finite data come in, the answer is a proper rotation or a PlsgraphError, never junk."""
    from plsgraph.errors import PlsgraphError

    rng = np.random.default_rng(23)
    for _ in range(60):
        n = int(rng.integers(1, 40))
        X = rng.normal(size=(n, 3)) * rng.uniform(0, 2, size=3) * (rng.uniform() < 0.8)
        Y = (
            rng.normal(size=(n, 3)) * rng.uniform(0, 2, size=3)
            if rng.uniform() < 0.5
            else X @ random_rotation_zyx(rng).T
        )
        for _, kw in CONFIGS:
            try:
                res = solve(X, Y, **kw)
            except PlsgraphError:
                continue
            assert is_rotation(res.R_base_cam, 1e-9)


def test_opencv_prints_nothing_of_its_own_during_the_hand_eye_comparisons(monkeypatch):
    """Before: a failing Tsai printed OpenCV's '[ERROR:0@3.858] ... Hand-eye calibration failed!' on stderr of a run
    that ended with exit 0. Its logging is silenced for the call (the failure is told by the result) and restored."""
    import cv2

    from plsgraph.core.geometry import make_T, so3_exp

    rng = np.random.default_rng(0)
    Tw = np.stack([make_T(so3_exp([0.3 * a, 0.2 * b, c]), [x, y, 0.1 * z]) for a, b, c, x, y, z in
                   rng.normal(size=(30, 6))])
    X = make_T(so3_exp([0.1, -1.5, 0.2]), [0.2, 0.05, 0.3])
    Tbc = np.stack([T @ X for T in Tw])
    before = cv2.utils.logging.getLogLevel()
    seen = []
    real = cv2.calibrateHandEye

    def spy(*args, **kw):
        seen.append(cv2.utils.logging.getLogLevel())
        return real(*args, **kw)

    monkeypatch.setattr(cv2, "calibrateHandEye", spy)
    hand_eye(Tw, Tbc, method="tsai")
    assert seen == [cv2.utils.logging.LOG_LEVEL_SILENT] and cv2.utils.logging.getLogLevel() == before


def test_hand_eye_on_a_floor_leaves_the_height_unknown_and_keeps_the_floor_position():
    rng = np.random.default_rng(17)
    Twb, Tbc, X = _hand_eye_poses(rng, planar_motion=True, n=40)
    solved = 0
    for method in ("tsai", "park", "horaud", "andreff", "daniilidis"):
        try:
            res = hand_eye(Twb, Tbc, method)
        except DegenerateMotionError:
            continue
        assert np.isnan(res.t_base_cam[2])  # OpenCV's number along the turn axis is not an answer
        assert any("height is not determined" in w for w in res.warnings)
        if angle_deg(res.R_base_cam, X[:3, :3]) < 1e-4:
            assert np.allclose(res.t_base_cam[:2], X[:2, 3], atol=1e-3)
            solved += 1
    assert solved >= 1
