"""Whether worker processes started with "spawn" can be used from where the library was called.

A process started with the "spawn" method (the front end's and batch's workers: safe with the threads the calling
process may have) imports the calling script again, as ``__mp_main__``. A script that calls plsgraph at its top
level, outside ``if __name__ == "__main__":``, would then calibrate again inside every worker, which Python stops
with a "bootstrapping phase" error and a broken pool. :func:`spawn_would_rerun_main` tells that case apart, so that
the work is done in the calling process instead (the same result, more slowly) with a warning that says how to get
the workers back.
"""

from __future__ import annotations

import ast
import functools
import logging
import os
import sys
from typing import Any

log = logging.getLogger(__name__)


@functools.lru_cache(maxsize=8)
def _guarded_lines(path: str) -> tuple[tuple[int, int], ...]:
    """Line ranges of the top-level ``if __name__ == "__main__":`` blocks of the script at ``path``."""
    try:
        with open(path, encoding="utf-8") as f:
            tree = ast.parse(f.read(), filename=path)
    except (OSError, SyntaxError, UnicodeDecodeError, ValueError):
        return ((0, sys.maxsize),)  # unreadable: assumed guarded (nothing changes)
    out = []
    for node in tree.body:
        if isinstance(node, ast.If) and _is_main_test(node.test):
            out.append((node.lineno, node.end_lineno or node.lineno))
    return tuple(out)


def _is_main_test(test: ast.expr) -> bool:
    if not (isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], ast.Eq)):
        return False
    sides = [test.left, test.comparators[0]]
    names = [s for s in sides if isinstance(s, ast.Name) and s.id == "__name__"]
    consts = [s for s in sides if isinstance(s, ast.Constant) and s.value == "__main__"]
    return len(names) == 1 and len(consts) == 1


def spawn_would_rerun_main() -> bool:
    """True when this call comes from the top level of a script run as ``__main__`` outside its
    ``if __name__ == "__main__":`` block: a spawned worker would run that call again. False for the ``plsgraph``
    command, interactive sessions, notebooks and calls made under the guard or from a function that
    the guarded block calls."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if not path:  # an interactive session, python -c, a notebook: nothing to run again
        return False
    script = os.path.abspath(path)
    import threading

    frames = [sys._getframe(1)]
    if threading.current_thread() is not threading.main_thread():
        # Called from a thread (batch's fallback when the script is unguarded): the script's top-level call, if any,
        # is on the main thread's stack, which waits for this one.
        main_frame = sys._current_frames().get(threading.main_thread().ident)
        if main_frame is not None:
            frames.append(main_frame)
    return any(_unguarded_call(f, script) for f in frames)


def _unguarded_call(frame, script: str) -> bool:
    """Whether the stack from ``frame`` down holds a call from the top level of ``script`` outside its guard."""
    while frame is not None:
        # The script's own top level (a spawned worker's bootstrap is a "<module>" frame named __main__ too, but
        # of other code: its tasks come from functions, not from the script's top level).
        if frame.f_code.co_name == "<module>" and frame.f_globals.get("__name__") == "__main__" \
                and os.path.abspath(frame.f_code.co_filename) == script:
            line = frame.f_lineno
            return not any(a <= line <= b for a, b in _guarded_lines(script))
        frame = frame.f_back
    return False


_WARNED: set[str] = set()


def warn_in_process(what: str) -> None:
    """Say once per process and ``what`` that the work runs here because of :func:`spawn_would_rerun_main`."""
    if what in _WARNED:
        return
    _WARNED.add(what)
    log.warning("%s runs in this process, without worker processes: plsgraph was called at the top level of the "
                "script %s; put the calls under 'if __name__ == \"__main__\":' to use the workers (a worker process "
                "imports the script again)", what, getattr(sys.modules.get("__main__"), "__file__", "?"))


def end_with_parent(parent_pid: int | None = None, poll_s: float = 0.5) -> None:
    """Have this process end when its parent ends: a worker whose calibrating process was killed by its pid alone
    (``kill PID``, a supervisor's timeout, an out-of-memory kill) must not go on calibrating, writing into a folder
    nobody waits for, and holding the caller's pipes open. A daemon thread looks every ``poll_s`` whether the parent
    (``parent_pid``; by default the parent now) is still this process's parent, and ends the process when not: tied
    to the parent process, not to the thread that started this one (Linux's PR_SET_PDEATHSIG is, and a pool started
    from a thread that has ended lost its workers with it).

    Also gives SIGTERM and SIGHUP back their default action here: a forked child inherits the command's handler,
    which Python runs only between bytecodes, so a child in a long C call would outlive its terminate()."""
    import signal
    import threading
    import time

    for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is not None and callable(signal.getsignal(sig)):
            try:
                signal.signal(sig, signal.SIG_DFL)
            except (ValueError, OSError):  # not the main thread: leave it
                pass
    parent = os.getppid() if parent_pid is None else int(parent_pid)
    if os.getppid() != parent:  # the parent died before this process got here
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()


def pool_worker_start(parent_pid: int, ignore_interrupt: bool = False) -> None:
    """A pool worker's initializer: it ends with its parent (:func:`end_with_parent`); with ``ignore_interrupt`` it
    also leaves Ctrl-C to the parent, for a pool its parent kills on an interrupt (a batch's): a terminal's Ctrl-C
    reaches every process of the group, and a worker waiting for work printed a KeyboardInterrupt traceback. Pools
    that are shut down instead (which waits for running tasks) keep Ctrl-C, so that their tasks stop at once."""
    import signal

    end_with_parent(parent_pid)
    if ignore_interrupt:
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        except (ValueError, OSError):  # not the main thread: leave it
            pass


def worker_initializer(ignore_interrupt: bool | None = None) -> tuple[Any, tuple]:
    """(initializer, initargs) for a process pool whose workers end with this process (:func:`pool_worker_start`).
    ``ignore_interrupt``: the workers leave Ctrl-C to this process; by default they do so when this process ignores it
    itself (a batch's worker, whose front end's workers would otherwise print tracebacks on a batch's Ctrl-C)."""
    import signal

    if ignore_interrupt is None:
        try:
            ignore_interrupt = signal.getsignal(signal.SIGINT) == signal.SIG_IGN
        except (ValueError, OSError):
            ignore_interrupt = False
    return pool_worker_start, (os.getpid(), bool(ignore_interrupt))


def interrupt_behind(exc: BaseException) -> BaseException | None:
    """The interrupt (Ctrl-C's KeyboardInterrupt, or SIGTERM's and SIGHUP's ending) that ``exc`` stands for, if any:
    an interrupt raised while a compiled module initialises comes out as that module's ImportError ("initialization
    failed", the interrupt as its cause), which an ``except Exception`` would take for the module's own failure."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, KeyboardInterrupt):
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


def reraise_interrupt(exc: BaseException) -> None:
    """Raise the interrupt ``exc`` stands for (:func:`interrupt_behind`), if any: for the ``except Exception`` of work
    that must not cost the result but may import a compiled module (GTSAM, matplotlib)."""
    stop = interrupt_behind(exc)
    if stop is not None:
        raise stop from None
