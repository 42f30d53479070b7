"""Observability report: synthetic information matrices with known null spaces, and the three motion profiles."""

import numpy as np
import pytest
from refine_cases import rotation_error_base_axes, sim_case

from plsgraph.core.geometry import make_T, se3_exp, so3_exp
from plsgraph.errors import InputError
from plsgraph.refine.graph import refine
from plsgraph.refine.observability import AXES, not_converged_report, observability_report, user_axes_jacobian

PRIOR = np.diag([0.5**-2] * 3 + [1.0**-2] * 3 + [0.05**-2])


def posterior(data_info: np.ndarray) -> np.ndarray:
    return np.linalg.inv(PRIOR + data_info)


def test_null_axis_and_null_combination_are_found():
    rng = np.random.default_rng(0)
    # Strong data on everything except: z (nothing) and the combination x - 20 * td (td traded for forward shift).
    B = rng.normal(size=(7, 7))
    info = 1e6 * B @ B.T
    null = np.zeros((7, 2))
    null[5, 0] = 1.0
    null[3, 1], null[6, 1] = 1.0, -0.05  # 5 cm of x ~ 2.5 ms of td at 20 m/s... any fixed ratio
    P = np.eye(7) - null @ np.linalg.pinv(null)
    rep = observability_report(posterior(P @ info @ P), PRIOR)
    assert rep.status("z") == "unobservable"
    assert rep.status("roll") == rep.status("pitch") == rep.status("yaw") == rep.status("y") == "observable"
    # The combination: its eigen-direction is unobservable and is named as a combination of x and td.
    combos = [d for d in rep.directions if d.status == "unobservable" and "combination" in d.description]
    assert combos and set(combos[0].composition) >= {"x", "td"}
    assert any("trade off" in m for m in rep.messages)
    assert any("camera height" in m for m in rep.messages)


def test_weak_axis_between_thresholds():
    info = np.diag([1e8] * 6 + [0.0])
    info[6, 6] = 8.0 / 0.05**2  # posterior/prior sigma = 1/3 on td
    rep = observability_report(posterior(info), PRIOR)
    assert rep.status("td") == "weak"
    assert rep.weak == ("td",)
    d = rep.to_dict()
    assert d["axes"][6]["name"] == "td" and d["axes"][6]["unit"] == "ms"
    assert "| verdict |" in rep.to_markdown()


def test_not_converged_report_refuses_to_classify():
    rep = observability_report(np.eye(7), PRIOR, converged=False)
    assert {a.status for a in rep.axes} == {"unknown"}
    assert rep.messages == not_converged_report("the optimisation did not converge").messages
    with pytest.raises(InputError):
        observability_report(np.full((7, 7), np.nan), PRIOR)


def test_user_axes_map_right_perturbation_to_base_axes():
    rng = np.random.default_rng(1)
    T = make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3))
    xi = 1e-7 * rng.normal(size=6)
    Tp = T @ se3_exp(xi)
    u = user_axes_jacobian(T[:3, :3]) @ np.r_[xi, 0.0]
    assert np.allclose(rotation_error_base_axes(Tp[:3, :3], T[:3, :3]), u[:3], atol=1e-13)
    assert np.allclose(Tp[:3, 3] - T[:3, 3], u[3:6], atol=1e-13)


@pytest.mark.parametrize(
    "motion, unobservable, observable",
    [
        # Driving straight: rotation about the driving direction and the whole lever arm are lost.
        ("straight", {"roll", "x", "y", "z"}, {"pitch", "yaw"}),
        # Turning in place: rotation about the turning axis and the height are lost.
        ("spin", {"yaw", "z"}, {"roll", "pitch", "x", "y"}),
    ],
)
def test_degenerate_motions_name_their_lost_directions(motion, unobservable, observable):
    case = sim_case(motion)
    res = refine(case.track, case.base, case.rec.camera, case.seed_T, case.seed_td)
    assert res.converged
    rep = res.observability
    # "weak" counts as not observed: what matters is that the report names the direction.
    lost = set(rep.unobservable) | set(rep.weak)
    assert lost >= unobservable, rep.to_markdown()
    assert set(rep.observable) >= observable, rep.to_markdown()
    for name in unobservable:
        assert any(a.name == name and a.message for a in rep.axes)
    # Directions held at the seed stay there: the rotation is never worse than the seed's.
    err = np.degrees(np.abs(rotation_error_base_axes(res.R_base_cam, case.rec.T_base_cam[:3, :3])))
    seed = np.degrees(np.abs(rotation_error_base_axes(case.seed_T[:3, :3], case.rec.T_base_cam[:3, :3])))
    assert np.linalg.norm(err) <= np.linalg.norm(seed) + 0.5
    assert set(AXES) == {a.name for a in rep.axes}


def test_a_direction_held_because_the_data_determine_it_too_weakly_says_so():
    # 3 s of driving: the data determine yaw to a few degrees, more than the tenth of its prior sigma the freezing
    # rule asks, so the refinement holds it at the seed. That is too little data, not data that contradict each
    # other, and the report, its note and the gate's problem say so with the data's sigma.
    import dataclasses
    from types import SimpleNamespace

    from plsgraph.gate import _refinement_problems
    from plsgraph.refine.graph import held_weakly

    case = sim_case("rich", duration=3.0)
    res = refine(case.track, case.base, case.rec.camera, case.seed_T, case.seed_td)
    yaw = next(a for a in res.observability.axes if a.name == "yaw")
    assert res.converged and yaw.status == "unobservable"
    sigma = held_weakly(res.priors["held_directions"], "yaw")
    assert sigma is not None and 0.1 * 0.5 < sigma < 0.5 * 0.5  # between the freezing and the unobservable ratios
    assert held_weakly(res.priors["held_directions"], "z") is None  # the height: not determined at all
    assert "too weakly determined" in yaw.message and f"{np.degrees(sigma):.2g} deg" in yaw.message
    assert "turning in place" not in yaw.message  # no motion advice that this drive already follows
    cf = SimpleNamespace(observable={"yaw": True, "x": True, "y": True}, R_base_cam=None)
    problems = _refinement_problems(cf, res, case.base)
    said = f"the recording determines yaw only to about {np.degrees(sigma):.2g} deg"
    assert any(p.startswith(said) for p in problems), problems
    assert not any("contradict" in p for p in problems)
    # A direction held although the data did not determine it at all keeps the contradiction's wording.
    undetermined = dataclasses.replace(res, priors={**res.priors, "held_directions": [
        {**h, "ratio": 0.9} for h in res.priors["held_directions"]]})
    assert any("contradict each other" in p for p in _refinement_problems(cf, undetermined, case.base))
