"""Worker processes from a script that calls plsgraph at its top level (a spawned worker imports the script again)."""

import subprocess
import sys
import textwrap
import time

from realdata import SAMPLE

STREAMED = """
from plsgraph.core.board import load_board
from plsgraph.frontend.track import camera_track_from_event_chunks
from plsgraph.io.events_reader import iter_event_chunks
from plsgraph.io.recording import read_recording

def track():
    camera = read_recording({sample!r}, with_events=False).camera
    chunks = (c for c in iter_event_chunks({sample!r}, chunk_events=100_000) if c.t_first < c.t_first + 1)
    t = camera_track_from_event_chunks(chunks, camera, load_board("acircles_4x11_a2"), kind="count", span_s=1.0,
                                       history_s=0.5, workers=2)
    print("poses", len(t), flush=True)
"""


def _run(tmp_path, body: str):
    script = tmp_path / "user_script.py"
    script.write_text(textwrap.dedent(body))
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)


def test_a_script_that_calls_at_its_top_level_is_served_in_its_own_process(tmp_path):
    # Before: the README's example saved as a script ended in "bootstrapping phase" errors and a BrokenProcessPool:
    # each spawned worker ran the script's calibration again.
    p = _run(tmp_path, STREAMED.format(sample=str(SAMPLE)) + "\ntrack()\n")
    assert p.returncode == 0, p.stderr[-2000:]
    assert "poses" in p.stdout and "bootstrapping" not in p.stderr and "BrokenProcessPool" not in p.stderr
    assert "runs in this process, without worker processes" in p.stderr
    assert "if __name__ == \"__main__\":" in p.stderr  # the warning says how to get the workers back


def test_the_guard_and_functions_it_calls_keep_the_workers(tmp_path):
    body = """
    from plsgraph.core.processes import spawn_would_rerun_main

    def inner():
        return spawn_would_rerun_main()

    print("top", spawn_would_rerun_main(), flush=True)
    if __name__ == "__main__":
        print("guard", spawn_would_rerun_main(), inner(), flush=True)
    """
    p = _run(tmp_path, body)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["top", "True", "guard", "False", "False"]
    p = subprocess.run([sys.executable, "-c", "from plsgraph.core.processes import spawn_would_rerun_main as s; "
                        "print(s())"], capture_output=True, text=True, timeout=120)
    assert p.stdout.strip() == "False"  # python -c: no script to run again
    guarded = STREAMED.format(sample=str(SAMPLE)) + "\nif __name__ == '__main__':\n    track()\n"
    p = _run(tmp_path, guarded)
    assert p.returncode == 0 and "poses" in p.stdout, p.stderr[-2000:]
    assert "without worker processes" not in p.stderr


def test_a_spawned_worker_of_a_guarded_script_may_start_workers_itself(tmp_path):
    # A batch worker (spawned) runs the front end, whose own workers it may start: the worker's bootstrap is a
    # "<module>" frame named __main__ too, but not the script's top level. Before this was told apart, every batch
    # worker's front end ran without its workers.
    body = """
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    def probe():
        from plsgraph.core.processes import spawn_would_rerun_main
        return spawn_would_rerun_main()

    if __name__ == "__main__":
        with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as ex:
            print("spawned", ex.submit(probe).result(), flush=True)
    """
    p = _run(tmp_path, body)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["spawned", "False"]


def test_worker_processes_end_with_a_parent_killed_by_its_pid(tmp_path):
    """A review: `kill -9 PID` of a calibration (a supervisor's timeout, an out-of-memory kill) left its front end's
    workers running with parent 1, holding the caller's pipes open (a harness reading the output hung) and a batch's
    worker went on calibrating into the folder."""
    import os
    import signal
    import time

    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent("""
        import multiprocessing as mp, time
        from concurrent.futures import ProcessPoolExecutor
        from plsgraph.core.processes import worker_initializer

        if __name__ == "__main__":
            init, args = worker_initializer()
            pool = ProcessPoolExecutor(2, mp_context=mp.get_context("spawn"), initializer=init, initargs=args)
            for f in [pool.submit(time.sleep, 0.2) for _ in range(2)]:
                f.result()
            print(" ".join(str(p) for p in pool._processes), flush=True)
            time.sleep(120)
    """))
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        workers = [int(p) for p in proc.stdout.readline().split()]
        assert len(workers) == 2
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)

        def alive(pid):
            try:
                with open(f"/proc/{pid}/stat") as f:
                    return f.read().split(")")[-1].split()[0] != "Z"  # a zombie has ended
            except OSError:
                return False

        deadline = time.monotonic() + 10
        while any(alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(alive(p) for p in workers)
    finally:
        proc.kill()


def test_a_pool_first_used_from_a_thread_that_has_ended_keeps_its_workers():
    """A review: with PR_SET_PDEATHSIG (tied to the thread that starts a worker) a pool first used from a thread that
    then ended (a web server's request thread) lost its workers, and every later item failed."""
    import threading

    from plsgraph.refine.batch import default_executor

    ex = default_executor(2, 2)
    try:
        t = threading.Thread(target=lambda: list(ex.map(abs, [-1, -2])))
        t.start()
        t.join()
        time.sleep(1.5)  # longer than the workers' watch interval
        assert list(ex.map(abs, [-3, -4])) == [3, 4]
    finally:
        ex.shutdown(wait=True)


def test_a_thread_of_an_unguarded_script_sees_the_scripts_top_level_call(tmp_path):
    """A review: batch's fallback for an unguarded script runs the recordings in a thread, whose own stack does not
    show the script's top-level call: the front end then spawned workers that ran the script again."""
    body = """
        import threading
        from plsgraph.core.processes import spawn_would_rerun_main

        def check():
            out = []
            t = threading.Thread(target=lambda: out.append(spawn_would_rerun_main()))
            t.start()
            t.join()
            return out[0], spawn_would_rerun_main()

        {call}
    """
    unguarded = _run(tmp_path, body.replace("{call}", "print('seen', *check())"))
    assert "seen True True" in unguarded.stdout, unguarded.stderr
    guarded = _run(tmp_path, body.replace("{call}", "if __name__ == '__main__':\n            print('seen', *check())"))
    assert "seen False False" in guarded.stdout, guarded.stderr


def test_pool_workers_leave_ctrl_c_to_their_parent(tmp_path):
    """A review: Ctrl-C on a batch printed a KeyboardInterrupt traceback from each worker waiting for work (a terminal's
    Ctrl-C reaches every process of the group; the command stops its pools itself)."""
    import os
    import signal
    import time

    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent("""
        import multiprocessing as mp, time
        from concurrent.futures import ProcessPoolExecutor
        from plsgraph.core.processes import worker_initializer

        if __name__ == "__main__":
            init, args = worker_initializer(ignore_interrupt=True)  # as a batch's pool
            pool = ProcessPoolExecutor(2, mp_context=mp.get_context("spawn"), initializer=init, initargs=args)
            for f in [pool.submit(time.sleep, 0.2) for _ in range(2)]:
                f.result()
            print(" ".join(str(p) for p in pool._processes), flush=True)
            input()  # until the test says
            print(sum(f.result() for f in [pool.submit(abs, -3) for _ in range(4)]), flush=True)
    """))
    proc = subprocess.Popen([sys.executable, str(script)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        workers = [int(p) for p in proc.stdout.readline().split()]
        for pid in workers:  # idle, waiting for work
            os.kill(pid, signal.SIGINT)
        time.sleep(1.0)
        out, err = proc.communicate("\n", timeout=30)
        assert out.strip() == "12" and "Traceback" not in err and "KeyboardInterrupt" not in err, err
    finally:
        proc.kill()


def test_a_pool_that_is_shut_down_on_ctrl_c_stops_its_running_tasks_at_once(tmp_path):
    """A review: with every pool worker ignoring Ctrl-C, a pool shut down on an interrupt (the front end's, an API
    refine_many's) waited for its running tasks (12 s of 15 s). Only a batch's pool, which its parent kills on an
    interrupt, leaves Ctrl-C to the parent; a pool whose parent ignores Ctrl-C (a batch's worker) does so too."""
    import os
    import signal
    import time

    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent("""
        import multiprocessing as mp, signal, sys, time
        from concurrent.futures import ProcessPoolExecutor
        from plsgraph.core.processes import worker_initializer

        if __name__ == "__main__":
            # As from a terminal (a background job of a script, as CI may run the suite, starts with Ctrl-C ignored).
            signal.signal(signal.SIGINT, signal.default_int_handler)
            print(worker_initializer()[1][1], flush=True)  # by default: as this process (Ctrl-C not ignored)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            print(worker_initializer()[1][1], flush=True)  # this process ignores it: so do its workers
            signal.signal(signal.SIGINT, signal.default_int_handler)
            init, args = worker_initializer()
            pool = ProcessPoolExecutor(2, mp_context=mp.get_context("spawn"), initializer=init, initargs=args)
            try:
                futs = [pool.submit(time.sleep, 20) for _ in range(2)]
                time.sleep(0.5)
                print("running", flush=True)
                [f.result() for f in futs]
            except KeyboardInterrupt:
                t0 = time.monotonic()
                pool.shutdown(wait=True, cancel_futures=True)
                print(f"stopped {time.monotonic() - t0:.1f}", flush=True)
    """))
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path, start_new_session=True)
    try:
        assert proc.stdout.readline().strip() == "False" and proc.stdout.readline().strip() == "True"
        deadline = time.monotonic() + 60
        while proc.stdout.readline().strip() != "running" and time.monotonic() < deadline:
            pass
        time.sleep(2.0)  # the workers are in their tasks
        os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C: the whole group
        out, _ = proc.communicate(timeout=30)
        assert out.startswith("stopped") and float(out.split()[1]) < 5.0, out
    finally:
        proc.kill()
