"""Batch API: determinism per item, isolation of failures, any executor."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from refine_cases import rotation_error_base_axes, sim_case

from plsgraph.errors import InputError
from plsgraph.refine.batch import BatchItemResult, RefineJob, item_seed, refine_job, refine_many


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


def dies_once(item, seed):
    """A worker killed while on this item the first time (the kernel's out-of-memory killer), fine the second."""
    import os
    import signal
    from pathlib import Path

    marker, value = item
    if marker is not None and not Path(marker).exists():
        Path(marker).write_text("killed once")
        os.kill(os.getpid(), signal.SIGKILL)
    return value


def test_a_killed_worker_fails_only_its_own_item_once_the_broken_ones_run_again(tmp_path):
    """A review: one batch worker killed (an out-of-memory kill) broke the pool, and every recording it had not
    finished was reported failed with 'BrokenProcessPool', also those that never started."""
    from plsgraph.refine.batch import default_executor, rerun_broken

    items = [(None, 1), (str(tmp_path / "marker"), 2), (None, 3), (None, 4)]
    ex = default_executor(len(items), 2)
    try:
        res = refine_many(items, dies_once, ex)
    finally:
        ex.shutdown(wait=True, cancel_futures=True)
    assert any(r.error_type == "BrokenProcessPool" for r in res)
    again = rerun_broken(items, res, dies_once)
    assert [r.ok for r in again] == [True] * 4 and [r.value for r in again] == [1, 2, 3, 4]
    assert [r.seed for r in again] == [r.seed for r in res]
    # Killed again, alone: that item stays failed, as a broken pool's.
    (tmp_path / "marker").unlink()
    first = [BatchItemResult(0, "0", 7, False, None, "BrokenProcessPool", "killed")]
    res2 = rerun_broken([(str(tmp_path / "marker"), 2)], first, dies_once)
    assert not res2[0].ok and res2[0].error_type == "BrokenProcessPool" and res2[0].seed == 7
