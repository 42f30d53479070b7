"""The report's figures drawn in a second Python process, off the calibration's critical path.

Importing matplotlib and drawing the first figure take about a second, the figures themselves as much again: all of it
after the refinement, when nothing else is left to do. :class:`FigureWorker` starts a process when a calibration starts
(when a processor is free for it: :func:`processor_free`) and waits. Told to (:meth:`FigureWorker.warm`, once the front
end is done and the rest of the calibration leaves a processor idle), it loads matplotlib and draws a throw-away figure
(fonts, caches), then waits again. (Warming up at once would take a second of processor time from the front end's worker
processes, which keep both processors of a small machine busy.) When the result is known, :meth:`FigureWorker.send`
hands it the few arrays the figures show (:func:`plsgraph.report.figures.figure_inputs`) and the folder to draw into;
the worker forks, so that two processes draw half of the figures each, while the calling process writes calibration.yaml
and the robot files. The folder is the run's staging folder, so the whole-folder semantics of
:mod:`plsgraph.report.output` hold: the figures are there before the folder is moved into place, or the folder is not
moved at all.

Anything wrong with the worker (it cannot start, dies, hangs, answers nonsense) makes :meth:`FigureWorker.result` return
None, and the caller draws the figures itself as before: the worker can cost time, never figures or numbers.

The figure that needs only the final tracks (the event frames: :data:`EARLY`) can be drawn while the closed form and the
refinement run (:meth:`FigureWorker.early`, right after the warm-up): into a subfolder of the run's folder, moved into
it with the others once all are drawn, removed if the worker does not finish. The figures that need only the refined
extrinsic, time offset and board pose (:data:`SPECULATIVE`) can be drawn as soon as the refinement's solve ends
(:meth:`FigureWorker.speculate`), while its second opinions are still solved (one of them beside, in a process of its
own, which leaves a processor idle once the marginals are done): into a second subfolder, kept only if the final
result's inputs to those figures are the same to the byte (else they are drawn again with the rest).

Protocol: the parent writes the line ``warm``, then jobs, each an 8-byte little-endian length and a pickle
``(out_dir, inputs, which, final, keep)``, and closes stdin after the final one; the worker warms up when it reads the
line, draws a job that is not final (early or speculative figures) into its ``out_dir`` at once, draws the final job's
figures (``which``: indices into figures.FIGURES, None for all) in two processes, moves the figures of the earlier jobs
whose folders the final job lists in ``keep`` into its folder (and removes the others), and writes one pickle
``(images, failures)`` (as :func:`~plsgraph.report.figures.render_figures` returns them, for all the figures) to its
stdout and exits. End of input before the line or before a final job means:
nothing to draw, exit.
"""

from __future__ import annotations

import logging
import os
import pickle
import signal
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

#: How much lower the worker's scheduling priority is than the calibration's (os.nice).
NICE = 10
# Longest wait for the figures once the job is sent; then they are drawn in the calling process instead.
RENDER_TIMEOUT_S = 120.0
# The worker's code: the same plsgraph as the caller's (its folder goes first on the path, see _env). ``python -c``
# puts the working folder ahead of that: dropped, or a plsgraph folder there (another checkout) would be imported.
_BOOT = ("import sys; sys.path[:1] = [p for p in sys.path[:1] if p]; "
         "from plsgraph.report.figure_worker import serve; serve()")
# The line that tells the worker to warm up; the jobs follow it.
_WARM = b"warm\n"
#: Indices into figures.FIGURES of the figures that can be drawn before the calibration ends: the event frames (they
#: show the final tracks' detections on the recording's events). The coverage strip cannot: it counts windows of a
#: still robot with the refined time offset.
EARLY = (6,)
#: The index into figures.FIGURES of the event frames (the one figure that reads Run.event_frames).
EVENT_FRAMES_FIGURE = 6
#: The subfolder of the run's folder the early figures are drawn into.
EARLY_DIR = ".figures-early"
#: Indices into figures.FIGURES of the figures drawn once the refinement's solve ends (:meth:`FigureWorker.speculate`):
#: all but the observability bars (they show the marginals and the second opinions, known last) and the early ones.
SPECULATIVE = (0, 1, 2, 4, 5)
#: The subfolder of the run's folder the speculative figures are drawn into.
SPECULATIVE_DIR = ".figures-speculative"


def _without_unread(inputs: Any, which: Any) -> Any:
    """``inputs`` without the event frames' images when the figures ``which`` (None: all) do not include the event
    frames: megabytes that would be pickled and sent for nothing."""
    if which is not None and EVENT_FRAMES_FIGURE not in which and getattr(inputs, "event_frames", None) is not None:
        from types import SimpleNamespace

        return SimpleNamespace(**{**vars(inputs), "event_frames": None})
    return inputs


def _key(inputs: Any) -> bytes:
    """What the speculative figures read of ``inputs`` (figures.figure_inputs): all of it but the observability,
    pickled. Equal keys draw equal speculative figures."""
    from types import SimpleNamespace

    ref = inputs.refinement
    fields = {**vars(inputs), "event_frames": None}  # the event frames' images: read by the early figure only
    if ref is not None:
        fields["refinement"] = SimpleNamespace(**{**vars(ref), "observability": None})
    return pickle.dumps(SimpleNamespace(**fields), protocol=pickle.HIGHEST_PROTOCOL)


def _frame(job: tuple) -> bytes:
    data = pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL)
    return len(data).to_bytes(8, "little") + data


def _read_frame(f) -> tuple | None:
    head = f.read(8)
    if len(head) < 8:
        return None
    n = int.from_bytes(head, "little")
    data = f.read(n)
    return pickle.loads(data) if len(data) == n else None


def _env() -> dict[str, str]:
    """The caller's environment; when this plsgraph is not an installed one (a checkout on the path, a test tree), its
    folder goes first on PYTHONPATH so that the worker imports the same code."""
    import site

    import plsgraph

    env = dict(os.environ)
    root = str(Path(plsgraph.__file__).resolve().parent.parent)
    installed = {str(Path(p).resolve()) for p in [*site.getsitepackages(), site.getusersitepackages()]}
    if root not in installed:
        env["PYTHONPATH"] = os.pathsep.join([root, *([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])])
    return env


# How long processor_free watches the processors (what this process does meanwhile counts as idle: what is busy is
# others').
# 100 ms: the kernel counts in jiffies of 10 ms, so two processors give 20 of them and one stray jiffy moves the
# reading by 0.1 processor (at 50 ms it moved it by 0.2, the whole margin of the 1.8 threshold).
IDLE_SAMPLE_S = 0.1


def _cpu_times(cpus: set[int]) -> tuple[float, float, int] | None:
    """(idle, total) jiffies summed over ``cpus`` from /proc/stat and how many of them it lists, or None where it
    cannot be read (not Linux, another format)."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    idle = total = 0.0
    seen = 0
    for line in lines:
        name, _, rest = line.partition(" ")
        if not name.startswith("cpu") or not name[3:].isdigit() or int(name[3:]) not in cpus:
            continue
        try:
            v = [float(x) for x in rest.split()]
            idle += v[3] + (v[4] if len(v) > 4 else 0.0)  # idle + iowait
        except (ValueError, IndexError):
            return None  # not the format this reads: judge by the load average instead
        total += sum(v[:8])  # user nice system idle iowait irq softirq steal (guest time is inside user)
        seen += 1
    return (idle, total, seen) if seen else None


def idle_processors(cpus: set[int], sample_s: float = IDLE_SAMPLE_S, own: bool = False) -> float | None:
    """How many of ``cpus`` stood idle over the next ``sample_s`` seconds (0 .. len(cpus)), or None if unknown.
    ``own``: this process works meanwhile (the look runs in a thread), and the processor time it takes counts as
    idle: it is the calibration's own."""
    import time

    a = _cpu_times(cpus)
    if a is None:
        return None
    c0, w0 = time.process_time(), time.monotonic()
    time.sleep(sample_s)
    b = _cpu_times(cpus)
    c1, w1 = time.process_time(), time.monotonic()
    if b is None or b[2] != a[2] or b[1] <= a[1]:  # unreadable, or a processor came or went meanwhile
        return None
    idle = len(cpus) * (b[0] - a[0]) / (b[1] - a[1])
    if own and w1 > w0:
        idle = min(float(len(cpus)), idle + (c1 - c0) / (w1 - w0))
    return idle


# A look started ahead by look_ahead() for the next processor_free(): {"look": {"thread", "started", "result"}}.
_LOOK: dict = {}
#: A look started ahead is used by a processor_free() at most this long (s) after it began.
LOOK_AHEAD_MAX_S = 5.0


def look_ahead() -> None:
    """Start :func:`processor_free`'s look now, in a thread, for the next call to take instead of looking (and
    sleeping) itself: ``plsgraph calibrate`` starts it before it imports the calibration, so the 100 ms pass while the
    imports run. Only this process's own work may run meanwhile (its processor time counts as idle; a process it
    starts would count as busy)."""
    import threading
    import time

    look: dict = {"started": time.monotonic()}

    def run() -> None:
        look["result"] = _processor_free()

    look["thread"] = threading.Thread(target=run, name="plsgraph-processor-look", daemon=True)
    _LOOK.clear()
    _LOOK["look"] = look
    look["thread"].start()


def processor_free() -> bool:
    """Is a processor free for the figure worker? The worker trades a second start-up (about a second of processor
    time: Python, numpy, matplotlib, a warm-up figure) for taking the figures off the calibration's critical path.
    That pays when a processor would otherwise idle beside the calibration, and costs time when every processor is
    already busy. One processor runs the calibration, and most of another must be left unused by everything else.

    Judged from what the processors this process may use do now (:func:`idle_processors`, a 100 ms look in which
    this process's own processor time counts as idle, or the look :func:`look_ahead` started), not from the load
    average, which still counts a minute of work that has ended (a simulation just before, the previous recording of
    a batch); the load average where /proc/stat cannot be read."""
    import time

    look = _LOOK.pop("look", None)
    if look is not None and time.monotonic() - look["started"] <= LOOK_AHEAD_MAX_S:
        look["thread"].join(2.0)
        if "result" in look:
            return look["result"]
    return _processor_free()


def _processor_free() -> bool:
    try:
        cpus = set(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = set(range(os.cpu_count() or 1))
    n = len(cpus)
    if n < 2:
        return False
    # This process's own processor time counts as idle: it is the calibration's, and numerical libraries' threads
    # keep spinning for a while after a call (OpenBLAS's did, 40 ms of every 100 right after the imports), which
    # read as a busy processor and sent the figures into the calibrating process.
    idle = idle_processors(cpus, own=True)
    if idle is not None:
        return idle >= 1.8
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):
        return True
    return n - load >= 1.0


class FigureWorker:
    """A figure-drawing process: ``start()`` early, ``send(out, run)`` once the result is known, ``result()`` when
    the figures are needed, ``close()`` always (also a context manager). One job per worker."""

    def __init__(self) -> None:
        self.proc: subprocess.Popen | None = None
        self._stderr = None
        self._thread = None
        self._reply: bytes | None = None
        self._error: BaseException | None = None
        self._warmed = False
        # The jobs sent before the final one: (writer thread, folder, which, key), key None for the early figures
        # (always kept) and _key(inputs) for the speculative ones (kept if the final inputs have the same key).
        self._jobs: list[tuple] = []

    @classmethod
    def start(cls) -> FigureWorker:
        """Start the process (it warms up on its own); a worker that cannot start is simply unavailable."""
        w = cls()
        if not sys.executable:
            return w
        try:
            w._stderr = tempfile.TemporaryFile()
            w.proc = subprocess.Popen(
                [sys.executable, "-c", _BOOT], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=w._stderr,
                env=_env(), close_fds=True, start_new_session=True,  # a Ctrl-C is the caller's to handle
            )
        except (OSError, ValueError) as exc:
            log.debug("figure worker could not start (%s); figures are drawn in this process", exc)
            w.close()
        return w

    @property
    def available(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def warm(self) -> None:
        """Let the worker load matplotlib now (once; :meth:`send` does it too if this was not called)."""
        if self._warmed or not self.available:
            return
        self._warmed = True
        try:
            self.proc.stdin.write(_WARM)
            self.proc.stdin.flush()
        except (OSError, ValueError) as exc:  # it died: send() finds it unavailable and the caller draws
            log.debug("figure worker did not take the warm-up (%s)", exc)

    def early(self, out: Path, run: Any) -> None:
        """Have the worker draw the figures :data:`EARLY` of ``run`` now, while the calibration goes on (once, before
        :meth:`send`, on the run's final tracks; the folder ``out`` is the one :meth:`send` will get)."""
        if any(job[3] is None for job in self._jobs):
            return
        self._queue(Path(out) / EARLY_DIR, run, EARLY, speculative=False)

    def speculate(self, out: Path, run: Any, refinement: Any) -> None:
        """Have the worker draw the figures :data:`SPECULATIVE` of ``run`` with ``refinement`` (its solution before
        the second opinions: T_base_cam, R_base_cam, td, T_world_board) now, while the calibration goes on (once,
        before :meth:`send`; the folder ``out`` is the one :meth:`send` will get). :meth:`send` keeps them only if the
        final result's inputs to them are the same."""
        if any(job[3] is not None for job in self._jobs):
            return
        self._queue(Path(out) / SPECULATIVE_DIR, run, SPECULATIVE, speculative=True, refinement=refinement)

    def _queue(self, folder: Path, run: Any, which: tuple, speculative: bool, refinement: Any = None) -> None:
        import threading

        from .figures import figure_inputs

        if self._thread is not None or not self.available:
            return
        try:
            inputs = _without_unread(figure_inputs(run, refinement), which)
            job = (b"" if self._warmed else _WARM) + _frame((str(folder), inputs, which, False, ()))
            key = _key(inputs) if speculative else None
        except Exception as exc:  # something that does not pickle: they are drawn with the others
            log.debug("figure inputs do not pickle (%s); these figures are drawn with the others", exc)
            return
        self._warmed = True
        stdin = self.proc.stdin
        before = self._jobs[-1][0] if self._jobs else None

        def write() -> None:  # the worker reads it once warm: the pipe holds less than the job
            try:
                if before is not None:
                    before.join(RENDER_TIMEOUT_S)  # one writer at a time, in order
                stdin.write(job)
                stdin.flush()
            except (OSError, ValueError) as exc:  # it died: result() finds out and the caller draws
                log.debug("figure worker did not take the figures sent before the result (%s)", exc)

        thread = threading.Thread(target=write, name="plsgraph-figures-early", daemon=True)
        thread.start()
        self._jobs.append((thread, folder, which, key))

    def send(self, out: Path, run: Any) -> None:
        """Hand the worker the figures of ``run`` to draw into ``out`` (those the jobs sent before did not take, or
        whose speculative inputs were not the final ones); returns at once (the job is written from a helper thread).
        Collect them with :meth:`result`."""
        import threading

        from .figures import FIGURES, figure_inputs

        if not self.available:
            self.close()
            return
        jobs = self._jobs
        if any(folder.parent != Path(out) for _, folder, _, _ in jobs):
            self.close()  # another folder than the earlier jobs': draw in this process
            return
        try:
            inputs = figure_inputs(run)
            final_key = _key(inputs) if any(key is not None for *_, key in jobs) else None
            kept = [(folder, which) for _, folder, which, key in jobs if key is None or key == final_key]
            taken = {i for _, which in kept for i in which}
            which = None if not jobs else tuple(i for i in range(len(FIGURES)) if i not in taken)
            inputs = _without_unread(inputs, which)
            job = (b"" if self._warmed else _WARM) + _frame((str(out), inputs, which, True,
                                                            tuple(str(folder) for folder, _ in kept)))
            self._warmed = True
        except Exception as exc:  # something that does not pickle: draw in this process
            log.debug("figure inputs do not pickle (%s); figures are drawn in this process", exc)
            self.close()
            return
        if len(kept) < len(jobs):
            log.debug("the speculative figures' inputs are not the result's: they are drawn again")
        proc = self.proc
        writers = [job[0] for job in jobs]

        def talk() -> None:
            try:
                for w in writers:
                    w.join(RENDER_TIMEOUT_S)  # their jobs first: one writer at a time
                self._reply = proc.communicate(job, timeout=RENDER_TIMEOUT_S)[0]
            except Exception as exc:  # reported by result()
                self._error = exc

        self._thread = threading.Thread(target=talk, name="plsgraph-figures", daemon=True)
        self._thread.start()

    def result(self) -> tuple[list[tuple[str, str]], list[tuple[str, str]]] | None:
        """What the worker drew, ``(images, failures)`` as :func:`~plsgraph.report.figures.render_figures` returns
        them, or None when it could not (then nothing it wrote is to be trusted: draw them all again)."""
        try:
            if self._thread is None:
                return None
            self._thread.join(RENDER_TIMEOUT_S + 10)
            proc = self.proc
            if self._thread.is_alive() or proc is None:
                raise RuntimeError("no answer")
            if self._error is not None:
                raise self._error
            if proc.returncode != 0:
                raise RuntimeError(f"exit {proc.returncode}: {self._last_error()}")
            images, failures = pickle.loads(self._reply)
            return [(str(c), str(f)) for c, f in images], [(str(c), str(e)) for c, e in failures]
        except Exception as exc:  # any trouble: the caller draws the figures itself
            log.debug("figure worker failed (%s); figures are drawn in this process", exc)
            return None
        finally:
            self.close()

    def _last_error(self) -> str:
        if self._stderr is None:
            return "(no message)"
        self._stderr.seek(0)
        lines = self._stderr.read().decode(errors="replace").strip().splitlines()
        return lines[-1] if lines else "(no message)"

    def close(self) -> None:
        """Stop the worker if it still runs (it then draws nothing more) and wait for it to end. Early figures it
        drew but did not move into the run's folder are removed (nothing it wrote unfinished is trusted)."""
        try:
            self._stop()
        finally:
            import shutil

            for _, folder, _, _ in self._jobs:
                shutil.rmtree(folder, ignore_errors=True)

    def _stop(self) -> None:
        proc, self.proc = self.proc, None
        if proc is not None:
            if proc.poll() is None:
                # The worker leads a session and process group of its own (start_new_session): the group holds its
                # fork drawing half of the figures too, which would go on writing into the folder otherwise.
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except (AttributeError, OSError):
                    proc.kill()
            if self._thread is not None and self._thread.is_alive():
                self._thread.join(10)  # its communicate() ends with the process
            else:
                for pipe in (proc.stdin, proc.stdout):
                    if pipe is not None:
                        try:
                            pipe.close()
                        except OSError:
                            pass
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    pass
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None

    def __enter__(self) -> FigureWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _warm_up(plt) -> None:
    """Draw and encode one small figure like the report's (text, a log axis, tight layout): loads the fonts and
    fills matplotlib's caches before the real figures are asked for."""
    import io

    from .figures import DPI

    fig, (a, b) = plt.subplots(1, 2, figsize=(3, 2), dpi=DPI)
    a.plot([0, 1], [1, 2], ".-", label="x")
    a.legend(fontsize=7)
    a.set_title("warm-up")
    b.bar([0, 1], [0.01, 10.0])
    b.set_yscale("log")
    b.set_xticks([0, 1], ["a", "b"], rotation=30, fontsize=8)
    fig.tight_layout()
    fig.savefig(io.BytesIO(), format="png", dpi=40)
    plt.close(fig)


# The figures split over two processes when the worker forks (indices into figures.FIGURES, about equal drawing
# time each): trajectories, observability and the event frames here, the others in the fork. Without the early
# figures (the event frames, drawn already): trajectories, the time-offset curve and observability here (0.34 s on the
# 20 s benchmark recording), the residuals, the methods and the coverage strip in the fork (0.41 s).
_HERE = (0, 3, 6)
_HERE_LATE = (0, 2, 3)
# The speculative figures (:data:`SPECULATIVE`, drawn in two processes too): trajectories and residuals here (0.19 s),
# the time-offset curve, the methods and the coverage strip in the fork (0.20 s).
_HERE_SPECULATIVE = (0, 1)


def _split(which: Any = None) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The figures ``which`` (indices into figures.FIGURES, None for all) split into this process's and the fork's:
    :data:`_HERE` here when the early figures are among them, :data:`_HERE_SPECULATIVE` for the speculative ones,
    else :data:`_HERE_LATE`."""
    from .figures import FIGURES

    which = tuple(range(len(FIGURES))) if which is None else tuple(which)
    mine = (_HERE if set(EARLY) <= set(which) else _HERE_SPECULATIVE if set(which) == set(SPECULATIVE)
            else _HERE_LATE)
    here = tuple(i for i in which if i in mine)
    return here, tuple(i for i in which if i not in here)


def _render_in_two(out: Path, inputs: Any, which: Any = None) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """render_figures over two processes: the warm worker forks (no second start-up, matplotlib already loaded),
    each draws its share, the fork's answer comes back through a pipe. Without fork, or if the fork fails to answer,
    this process draws the rest itself. The result is in the order of figures.FIGURES, as render_figures gives it."""
    from .figures import FIGURES, render_figures

    _here, _forked = _split(which)
    if not hasattr(os, "fork") or not _here or not _forked:
        return render_figures(out, inputs, which)
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the fork: draw its share, answer, and end without running the parent's cleanup
        code = 1
        try:
            _end_with_parent()
            os.close(r)
            data = pickle.dumps(render_figures(out, inputs, _forked), protocol=pickle.HIGHEST_PROTOCOL)
            with os.fdopen(w, "wb") as f:
                f.write(data)
            code = 0
        finally:
            os._exit(code)
    os.close(w)
    images, failures = render_figures(out, inputs, _here)
    with os.fdopen(r, "rb") as f:
        data = f.read()
    _, status = os.waitpid(pid, 0)
    try:
        theirs = pickle.loads(data) if status == 0 else None
    except Exception:
        theirs = None
    if theirs is None:
        theirs = render_figures(out, inputs, _forked)
    images += theirs[0]
    failures += theirs[1]
    order = {caption: i for i, (caption, _) in enumerate(FIGURES)}
    return sorted(images, key=lambda x: order[x[0]]), sorted(failures, key=lambda x: order[x[0]])


def _end_with_parent() -> None:
    """Have this process killed when its parent ends (:func:`plsgraph.core.processes.end_with_parent`)."""
    from ..core.processes import end_with_parent

    end_with_parent()


def _set_autogroup_nice(nice: int) -> bool:
    """Set the niceness of this process's autogroup (Linux with autogroups: a process that started a session of its
    own, as the worker does, is a group of its own, and the group's niceness is what the scheduler weighs against the
    calibration's; unlike os.nice it can be set back). Whether it was set."""
    try:
        with open("/proc/sys/kernel/sched_autogroup_enabled", encoding="ascii") as f:
            if f.read().strip() != "1":
                return False
        with open("/proc/self/autogroup", "w", encoding="ascii") as f:
            f.write(str(int(nice)))
        return True
    except (OSError, ValueError):
        return False


def serve() -> None:
    """The worker process: warm up, read the jobs from stdin, draw them, answer on stdout."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the caller stops the worker; an interrupt is the caller's
    # Below the calibration's own processes: the figures drawn before the result take what processor time they leave
    # (the refinement's second opinion solved beside lost a fifth of a second to them otherwise). The final figures,
    # which the calibration waits for, are drawn at the usual priority where it can be given back.
    autogroup = _set_autogroup_nice(NICE)
    if not autogroup:
        try:
            os.nice(NICE)  # for good: only a privileged process may raise its priority again
        except (AttributeError, OSError):
            pass
    reply_fd = os.dup(1)
    os.dup2(2, 1)  # anything printed while drawing goes to stderr, not into the reply
    if sys.stdin.buffer.readline() != _WARM:
        return  # no job: the calibration ended before its figures (or the caller is not this module)
    from .figures import _plt

    try:
        _warm_up(_plt())
        # The figures' pose interpolation (Slerp) and the robot files' rotations: scipy.spatial takes 0.2 s to load,
        # which the calibrating process leaves to where it is needed; here it loads while warming, not while drawing.
        import scipy.spatial.transform  # noqa: F401
    except Exception:  # the real figures will say what is wrong
        pass
    import shutil

    from .figures import FIGURES

    drawn: list[tuple[Path, tuple]] = []  # (folder, (images, failures)) of the early jobs
    while True:
        job = _read_frame(sys.stdin.buffer)
        if job is None:
            return  # no final job: the calibration ended without figures
        out, inputs, which, final, keep = job
        if not final:
            # Two processes here too: they take what processor time the calibration leaves (see NICE), and once its
            # second opinions are solved the speculative figures have both processors.
            Path(out).mkdir(parents=True, exist_ok=True)
            drawn.append((Path(out), _render_in_two(Path(out), inputs, which)))
            continue
        if autogroup:
            _set_autogroup_nice(0)
        images, failures = _render_in_two(Path(out), inputs, which)
        for folder, (imgs, fails) in drawn:
            if str(folder) in keep:
                for _caption, name in imgs:
                    os.replace(folder / name, Path(out) / name)
                images, failures = images + imgs, failures + fails
            shutil.rmtree(folder, ignore_errors=True)
        order = {caption: i for i, (caption, _) in enumerate(FIGURES)}
        result = sorted(images, key=lambda x: order[x[0]]), sorted(failures, key=lambda x: order[x[0]])
        with os.fdopen(reply_fd, "wb") as f:
            f.write(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
        # The caller waits for this process to end, and an interpreter with matplotlib loaded takes a fifth of a
        # second to tear down: the answer is out and every file is written, so end at once.
        sys.stderr.flush()
        os._exit(0)
