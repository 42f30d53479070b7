"""Batch API: determinism per item, isolation of failures, any executor."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from refine_cases import rotation_error_base_axes, sim_case

from plsgraph.errors import InputError
from plsgraph.refine.batch import RefineJob, item_seed, refine_job, refine_many


def noisy_mean(item, seed):
    """A stand-in trial: its answer depends only on the item and its seed."""
    if item == "boom":
        raise ValueError("this item is broken")
    rng = np.random.default_rng(seed)
    return float(item) + rng.normal()


def test_seeds_are_per_item_and_reproducible():
    a = [item_seed(7, i) for i in range(5)]
    assert a == [item_seed(7, i) for i in range(5)]
    assert len(set(a)) == 5 and a != [item_seed(8, i) for i in range(5)]


def test_results_do_not_depend_on_executor_or_worker_count():
    items = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    with ThreadPoolExecutor(1) as one, ThreadPoolExecutor(4) as four:
        r1 = refine_many(items, noisy_mean, one, base_seed=3)
        r4 = refine_many(items, noisy_mean, four, base_seed=3)
    assert [r.value for r in r1] == [r.value for r in r4]
    assert [r.index for r in r4] == list(range(6))
    # Different base seeds give different draws.
    with ThreadPoolExecutor(2) as ex:
        r5 = refine_many(items, noisy_mean, ex, base_seed=4)
    assert [r.value for r in r5] != [r.value for r in r1]


def test_a_failing_item_does_not_stop_the_others():
    items = {"a": 1.0, "bad": "boom", "c": 3.0}
    seen = []
    with ThreadPoolExecutor(2) as ex:
        res = refine_many(items, noisy_mean, ex, progress=lambda d, n: seen.append((d, n)))
    assert [r.name for r in res] == ["a", "bad", "c"]
    assert [r.ok for r in res] == [True, False, True]
    assert res[1].error_type == "ValueError" and "broken" in res[1].error and "Traceback" in res[1].traceback
    assert seen[-1] == (3, 3)


def test_empty_and_bad_arguments():
    assert refine_many([], noisy_mean) == []
    with pytest.raises(InputError):
        refine_many([1], "not callable")


def test_process_pool_refines_recordings_and_records_errors():
    case = sim_case("rich", duration=8.0, seed=5)
    good = RefineJob(case.track, case.base, case.rec.camera, case.seed_T, case.seed_td)
    bad = RefineJob(case.track, case.base, case.rec.camera, np.eye(3) * 2, case.seed_td)  # not a rotation
    res = refine_many([good, bad], refine_job, max_workers=2)
    assert res[0].ok and res[0].value.converged
    r = res[0].value
    d = np.degrees(rotation_error_base_axes(r.R_base_cam, case.rec.T_base_cam[:3, :3]))
    assert np.all(np.abs(d) < 4 * r.sigma_rot_deg + 0.05)
    assert not res[1].ok and res[1].error_type == "InputError"
