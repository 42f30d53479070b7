"""Refine many recordings or simulated trials in parallel through a concurrent.futures executor.

``refine_many(items, fn)`` calls ``fn(item, seed)`` for every item, each with its own seed derived
from ``(base_seed, index)``: the outcome of an item does not depend on the executor, the number of
workers or the order in which they finish. One failing item never stops the others: its error type,
message and traceback are recorded in its :class:`BatchItemResult`.

``fn`` and the items must be picklable for the default ProcessPoolExecutor (a module-level function,
data made of numpy arrays and dataclasses). :func:`refine_job` is such a function for
:class:`RefineJob` items.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import sys
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.camera import CameraModel
from ..core.tracks import BaseTrack, CameraTrack
from ..errors import InputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BatchItemResult:
    """Outcome of one item: ``value`` when ``ok``, otherwise ``error_type`` / ``error`` / ``traceback``."""

    index: int
    name: str
    seed: int
    ok: bool
    value: Any = None
    error_type: str | None = None
    error: str | None = None
    traceback: str | None = None
    seconds: float = float("nan")


def item_seed(base_seed: int, index: int) -> int:
    """The seed of item ``index``: independent streams per item, reproducible from ``base_seed``."""
    return int(np.random.SeedSequence([int(base_seed), int(index)]).generate_state(1, dtype=np.uint32)[0])


def _run_one(fn: Callable[[Any, int], Any], item: Any, seed: int) -> tuple:
    """Runs in the worker: never raises, so an item's failure travels back as data."""
    t0 = time.perf_counter()
    try:
        value = fn(item, seed)
        return True, value, None, None, None, time.perf_counter() - t0
    except Exception as exc:  # noqa: BLE001 - recording every failure is the point of a batch
        from ..core.processes import reraise_interrupt

        reraise_interrupt(exc)  # an interrupt inside an import is not the item's failure
        return False, None, type(exc).__name__, str(exc), traceback.format_exc(), time.perf_counter() - t0


def default_executor(n_items: int, max_workers: int | None = None, ignore_interrupt: bool = False) -> Executor:
    """A ProcessPoolExecutor with the "spawn" start method (safe with threads and GTSAM in the parent); one thread of
    this process instead when called at a script's unguarded top level, where a spawned worker would run the script
    again (:func:`plsgraph.core.processes.spawn_would_rerun_main`). ``ignore_interrupt``: the workers leave Ctrl-C to
    this process, which must then stop them itself on an interrupt (:func:`stop_workers`), as a batch does."""
    from concurrent.futures import ThreadPoolExecutor

    from ..core.processes import spawn_would_rerun_main, warn_in_process

    if spawn_would_rerun_main():
        warn_in_process("the batch")
        return ThreadPoolExecutor(max_workers=1)
    from ..core.processes import worker_initializer

    workers = max_workers or min(n_items, os.cpu_count() or 1)
    init, args = worker_initializer(ignore_interrupt)  # a batch killed by its pid alone takes its workers with it
    # A batch stopped by Ctrl-C kills its workers (stop_workers); the semaphores of their own front-end pools are
    # then released by multiprocessing's resource tracker, which says so with a warning meant for a leaking program.
    # The option reaches the tracker, a process of its own started with this interpreter's -W options.
    quiet = "ignore:resource_tracker:UserWarning"
    if quiet not in sys.warnoptions:
        sys.warnoptions.append(quiet)
    return ProcessPoolExecutor(max_workers=max(1, workers), mp_context=multiprocessing.get_context("spawn"),
                               initializer=init, initargs=args)


def refine_many(
    items: Sequence[Any] | Mapping[str, Any],
    fn: Callable[[Any, int], Any],
    executor: Executor | None = None,
    *,
    base_seed: int = 0,
    max_workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[BatchItemResult]:
    """Run ``fn(item, seed)`` for every item through ``executor`` and return the outcomes in item order.

    ``items``: a sequence (names are the indices) or a mapping name -> item. ``executor``: any
    concurrent.futures.Executor; by default a ProcessPoolExecutor (spawn) with ``max_workers`` workers,
    created and shut down here. A caller-supplied executor is left running. If the executor itself
    breaks (a worker killed, an unpicklable item), the affected items are recorded as failed.
    """
    if not callable(fn):
        raise InputError("refine_many: fn must be callable as fn(item, seed)")
    if isinstance(items, Mapping):
        names = [str(k) for k in items]
        values = list(items.values())
    else:
        values = list(items)
        names = [str(i) for i in range(len(values))]
    n = len(values)
    if n == 0:
        return []
    seeds = [item_seed(base_seed, i) for i in range(n)]
    own = executor is None
    ex = default_executor(n, max_workers) if own else executor
    out: list[BatchItemResult | None] = [None] * n
    done = 0
    try:
        futures = {}
        for i in range(n):
            try:
                futures[ex.submit(_run_one, fn, values[i], seeds[i])] = i
            except Exception as exc:  # noqa: BLE001 - e.g. a broken pool refuses new work
                out[i] = BatchItemResult(i, names[i], seeds[i], False, None, type(exc).__name__, str(exc))
                done += 1
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                ok, value, etype, msg, tb, secs = fut.result()
                out[i] = BatchItemResult(i, names[i], seeds[i], ok, value, etype, msg, tb, secs)
            except Exception as exc:  # noqa: BLE001 - pickling errors, dead workers
                out[i] = BatchItemResult(i, names[i], seeds[i], False, None, type(exc).__name__, str(exc))
            if not out[i].ok:
                log.warning("batch item %s failed: %s: %s", names[i], out[i].error_type, out[i].error)
            done += 1
            if progress is not None:
                progress(done, n)
    finally:
        if own:
            ex.shutdown(wait=True, cancel_futures=True)
    return [r for r in out if r is not None]


def stop_workers(executor: Any) -> None:
    """Kill a process pool's workers now (an interrupt: the items they were on stop, and one a worker had queued never
    starts). Their own workers end with them (plsgraph.core.processes.end_with_parent)."""
    procs = list((getattr(executor, "_processes", None) or {}).values())
    for proc in procs:
        try:
            proc.kill()
        except (OSError, AttributeError, ValueError):
            pass
    for proc in procs:
        try:
            proc.join(timeout=5)
        except (OSError, AttributeError, ValueError, AssertionError):
            pass


def rerun_broken(items: Sequence[Any], results: list[BatchItemResult], fn: Callable[[Any, int], Any]
                 ) -> list[BatchItemResult]:
    """``results`` with every outcome of a broken process pool (a worker killed, by the kernel's out-of-memory
    killer or a signal: the pool then fails every item it had not finished, not only the killed one's) replaced by
    running that item again, alone in a fresh process. An item whose worker is killed again stays failed."""
    out = list(results)
    for k, r in enumerate(results):
        if r.ok or r.error_type != "BrokenProcessPool":
            continue
        alone = default_executor(1, 1, ignore_interrupt=True)  # stopped below on an interrupt
        try:
            ok, value, etype, msg, tb, secs = alone.submit(_run_one, fn, items[k], r.seed).result()
            out[k] = BatchItemResult(r.index, r.name, r.seed, ok, value, etype, msg, tb, secs)
        except Exception as exc:  # noqa: BLE001 - killed again (a broken pool), or it could not be sent
            out[k] = BatchItemResult(r.index, r.name, r.seed, False, None, type(exc).__name__, str(exc))
        except BaseException:  # interrupted (Ctrl-C, SIGTERM): the item being run again stops now, not when done
            stop_workers(alone)
            raise
        finally:
            alone.shutdown(wait=True, cancel_futures=True)
    return out


@dataclass(frozen=True)
class RefineJob:
    """Everything :func:`plsgraph.refine.graph.refine` needs for one recording (picklable)."""

    camera_track: CameraTrack
    base_track: BaseTrack
    camera: CameraModel
    seed_T_base_cam: np.ndarray
    seed_td: float
    options: Any = None  # plsgraph.refine.graph.RefinementOptions or None


def refine_job(job: RefineJob, seed: int = 0):
    """Worker function for :func:`refine_many`: refine one recording (the refinement uses no randomness)."""
    from .graph import refine

    return refine(job.camera_track, job.base_track, job.camera, job.seed_T_base_cam, job.seed_td, job.options)
