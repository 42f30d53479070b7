import json

import numpy as np
import pytest

from plsgraph.core.geometry import is_rotation
from plsgraph.errors import InputError
from plsgraph.sim.paper import METHODS, Protocol, centering_study, reproduce_paper
from plsgraph.sim.routes import PLANAR_ROUTES, ROUTES, make_trials, route_samples


@pytest.mark.parametrize("route", ROUTES)
@pytest.mark.parametrize("quantity", ["position", "velocity"])
def test_route_samples_shape_and_excitation(route, quantity):
    P = route_samples(route, n=100, scale=2.0, quantity=quantity)
    assert P.shape == (100, 3) and np.all(np.isfinite(P))
    sv = np.linalg.svd(P, compute_uv=False)
    if route == "6dof":
        assert sv[2] > 0.1 * sv[0]
    else:
        assert np.all(P[:, 2] == 0.0)  # ground-constrained: no z motion at all
        assert sv[1] > 0.1 * sv[0]  # but two excited directions


def test_route_scale_and_speed():
    P = route_samples("circle", n=200, scale=3.0)
    assert np.allclose(np.linalg.norm(P, axis=1), 3.0)
    for route in ("circle", "v_shape", "z_shape", "s_shape"):
        V = route_samples(route, n=200, scale=1.5, quantity="velocity")
        assert np.allclose(np.linalg.norm(V, axis=1), 1.5)  # constant speed on the planar routes


def test_trials_follow_the_protocol_exactly_without_noise():
    for side in ("camera", "base"):
        for noise_model in ("paper", "independent"):
            ts = make_trials("circle", count=5, seed=3, sigma=0.0, planar_side=side, noise_model=noise_model)
            assert all(is_rotation(R) for R in ts.R_gt)
            assert np.allclose(ts.Y, ts.X @ np.swapaxes(ts.R_gt, 1, 2), atol=1e-12)  # Y = X R_gt^T
            zero_side = ts.X if side == "camera" else ts.Y
            assert np.allclose(zero_side[..., 2], 0.0, atol=1e-12)


def test_trials_reproducible_and_noise_level():
    a = make_trials("z_shape", count=50, seed=7)
    b = make_trials("z_shape", count=50, seed=7)
    c = make_trials("z_shape", count=50, seed=8)
    assert np.array_equal(a.X, b.X) and np.array_equal(a.R_gt, b.R_gt)
    assert not np.array_equal(a.X, c.X)
    clean = route_samples("z_shape")
    assert abs(np.std(a.X - clean) - 0.10) < 0.005  # sigma = 0.10 on X
    resid = a.Y - (clean @ np.swapaxes(a.R_gt, 1, 2))  # independent model: Y noise on the clean motion
    assert abs(np.std(resid) - 0.10) < 0.005
    p = make_trials("z_shape", count=50, seed=7, noise_model="paper")
    assert np.array_equal(p.X, a.X)
    assert abs(np.std(p.Y - p.X @ np.swapaxes(p.R_gt, 1, 2)) - 0.10) < 0.005  # paper: Y = X_noisy R^T + eps


def test_make_trials_rejects_bad_arguments():
    with pytest.raises(InputError):
        make_trials("spiral")
    with pytest.raises(InputError):
        make_trials("circle", noise_model="gaussian")
    with pytest.raises(InputError):
        make_trials("circle", planar_side="left")
    with pytest.raises(InputError):
        route_samples("circle", quantity="acceleration")
    with pytest.raises(InputError):
        route_samples("circle", scale=-1.0)


def test_quick_tables_ranking_files_and_overwrite(tmp_path):
    calls = []
    res = reproduce_paper(tmp_path, quick=True, progress=lambda d, t: calls.append((d, t)))
    assert calls[-1][0] == calls[-1][1] == 6
    data = json.loads((tmp_path / "paper_tables.json").read_text())
    assert set(data["table1"]) == {"6dof", "planar"} and set(data["table2"]) == set(PLANAR_ROUTES)
    for table in ("table1", "table2"):
        for route, per_method in data[table].items():
            for m in METHODS:
                s = per_method[m]
                assert {"mean_deg", "std_deg", "n_trials"} <= set(s)
                assert s["n_trials"] + s["n_failed"] == 20, (route, m)
    t1, t2 = res["table1"], res["table2"]
    # Qualitative ranking of the paper: with full 6-DoF motion everyone is accurate...
    for m in METHODS:
        assert t1["6dof"][m]["mean_deg"] < 5.0
    # ...under ground constraints CCA breaks down while PLS (paper-exact and default) and Procrustes do not.
    for route in ("planar",) + PLANAR_ROUTES:
        r = t1.get(route) or t2[route]
        assert r["cca"]["mean_deg"] > 5.0 * r["pls"]["mean_deg"], route
        assert r["pls_default"]["mean_deg"] < 5.0 and r["procrustes"]["mean_deg"] < 5.0
    for route in PLANAR_ROUTES:
        assert t2[route]["reduction_pct"] > 80.0
    md = (tmp_path / "paper_tables.md").read_text()
    assert md == res["markdown"] and "Table II" in md and "48.94" in md
    with pytest.raises(InputError, match="already exist"):
        reproduce_paper(tmp_path, quick=True)
    reproduce_paper(tmp_path, quick=True, overwrite=True)


def test_centring_loses_the_signal_of_forward_motion():
    """V-shape velocities are two constant headings: after removing the mean only one direction is left."""
    res = centering_study(trials=4, seed=0, base=Protocol())
    v = res["v_shape"]
    assert v["pls_default"]["n_failed"] == 0 and v["pls_default"]["mean_deg"] < 5.0
    centred = v["pls_default_centred"]
    assert centred["n_failed"] > 0 or centred["mean_deg"] > 10.0


def test_exact_zero_axis_matches_wheel_odometry():
    ts = make_trials("s_shape", count=3, planar_side="base", exact_zero_axis=True)
    assert np.all(ts.Y[..., 2] == 0.0) and np.std(ts.X) > 0.1
    with pytest.raises(InputError, match="independent"):
        make_trials("s_shape", count=3, noise_model="paper", exact_zero_axis=True)
