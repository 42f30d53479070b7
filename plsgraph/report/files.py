"""Result files: calibration.yaml (for people and robots), report.json (for scripts), report.html (+ PNGs).

Everything is written atomically (temporary file, then rename) into an output folder that must not
exist yet unless the caller passes ``force=True``: a previous result is never overwritten silently.
"""

from __future__ import annotations

import html
import json
import math
import os
import signal
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import InputError

COVARIANCE_ORDER = ["roll", "pitch", "yaw", "x", "y", "z", "td"]
COVARIANCE_NOTE = (
    "7 x 7 covariance in the base frame's axes: small rotations of the camera about the base x (roll), y (pitch) "
    "and z (yaw) axes [rad], the camera position along base x, y, z [m], and the time offset [s]; the same axes "
    "as the observability list. report.json also holds it in GTSAM's Pose3 tangent of T_base_cam (camera axes)."
)


def to_jsonable(obj: Any) -> Any:
    """Recursively convert numpy types to plain Python; non-finite floats become None (valid JSON)."""
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating | float):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def ros_static_transform(T_base_cam: np.ndarray, parent: str = "base_link", child: str = "event_camera",
                         z_known: bool = True) -> str:
    """A ready-to-paste ROS 2 static transform publisher line for T_base_cam.

    Without ``z_known`` (planar driving never observes the camera height) z is written as 0 with a shell comment
    saying it must be measured.
    """
    from scipy.spatial.transform import Rotation

    T = np.asarray(T_base_cam, dtype=float)
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    x, y, z = T[:3, 3]
    if not z_known:
        z = 0.0
    line = (
        "ros2 run tf2_ros static_transform_publisher "
        f"--x {x:.6f} --y {y:.6f} --z {z:.6f} "
        f"--qx {q[0]:.9f} --qy {q[1]:.9f} --qz {q[2]:.9f} --qw {q[3]:.9f} "
        f"--frame-id {parent} --child-frame-id {child}"
    )
    if not z_known:
        line += "  # z unknown (not observable from driving on a floor): measure the camera height and set --z"
    return line


def frames_note(parent: str, child: str) -> str:
    """What the two frames are: the camera's optical frame, and the frame the odometry moves."""
    return (f"{child} is the camera's optical frame (x right, y down, z forward, as ROS names *_optical_frame); "
            f"{parent} is the frame whose motion the wheel odometry reports (from wheel joints: the midpoint between "
            "the wheels)")


def _euler_deg(R) -> np.ndarray:
    """Euler angles about the fixed axes x, y, z (deg); at pitch +-90 deg scipy's gimbal-lock warning (the angles are
    still a valid rotation) is not the user's business."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return R.as_euler("xyz", degrees=True)


def rpy_sigma_deg(R_base_cam: np.ndarray, cov_rot: np.ndarray | None) -> list[float] | None:
    """One sigma (deg) of ``rpy_deg``, the Euler angles about the fixed axes x, y, z, from the 3 x 3 covariance of the
    small rotations about the base axes (rad; the covariance's first three rows): propagated through the Euler
    angles' derivatives, which mix those rotations wherever yaw is not zero (a camera turned 90 deg about z has its
    Euler roll moved by rotations about the base y axis). None without a covariance; NaN near pitch +-90 deg, where
    roll and yaw are not separate angles."""
    if cov_rot is None:
        return None
    cov = np.asarray(cov_rot, dtype=float)[:3, :3]
    if not np.all(np.isfinite(cov)):
        return [float("nan")] * 3
    from scipy.spatial.transform import Rotation

    R = Rotation.from_matrix(np.asarray(R_base_cam, dtype=float)[:3, :3])
    if abs(_euler_deg(R)[1]) > 89.0:
        return [float("nan")] * 3
    eps = 1e-6
    J = np.empty((3, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        hi = (Rotation.from_rotvec(d) * R).as_euler("xyz")
        lo = (Rotation.from_rotvec(-d) * R).as_euler("xyz")
        J[:, i] = (np.angle(np.exp(1j * (hi - lo)))) / (2 * eps)  # wrapped: an angle near +-180 deg
    var = np.einsum("ij,jk,ik->i", J, cov, J)
    return np.degrees(np.sqrt(np.clip(var, 0.0, None))).tolist()


def calibration_dict(
    T_base_cam: np.ndarray,
    time_offset_s: float,
    covariance: np.ndarray | None,
    observability: list[dict] | None,
    parent_frame: str = "base_link",
    child_frame: str = "event_camera",
    extra: Mapping[str, Any] | None = None,
    ok: bool = True,
    problems: list[str] | tuple[str, ...] = (),
    z_known: bool = True,
) -> dict:
    """The content of calibration.yaml (also embedded in report.json under ``calibration``).

    ``ok`` and ``problems`` come first, so whoever reads only this file sees a flagged result; a flagged one has
    no ready-to-paste transform line, only a comment saying why not to use it. Without ``z_known`` the
    translation's z is written as 0 and ``translation_z_status: unknown``."""
    T = np.asarray(T_base_cam, dtype=float).copy()
    if not z_known:
        T[2, 3] = 0.0
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    tf = ros_static_transform(T, parent_frame, child_frame, z_known) if ok else (
        "# NOT FOR USE: this result is flagged (see problems); fix the input and calibrate again")
    d: dict[str, Any] = {
        "ok": bool(ok),
        "problems": list(problems),
        "T_base_cam": T.tolist(),
        "quaternion_xyzw": q.tolist(),
        "translation_m": T[:3, 3].tolist(),
        "rpy_deg": _euler_deg(Rotation.from_matrix(T[:3, :3])).tolist(),
        "rpy_convention": "Euler angles about the fixed axes x, y, z (R = Rz(yaw) Ry(pitch) Rx(roll)), of the camera's "
                          "optical frame (x right, y down, z forward) in the base frame",
        "rpy_sigma_deg": rpy_sigma_deg(T[:3, :3], None if covariance is None else np.asarray(covariance)[:3, :3]),
        "time_offset_s": float(time_offset_s),
        "time_offset_convention": "t_odom = t_cam + time_offset_s",
        "parent_frame": parent_frame,
        "child_frame": child_frame,
        "frames_note": frames_note(parent_frame, child_frame),
        "covariance": {
            "order": COVARIANCE_ORDER,
            "note": COVARIANCE_NOTE if covariance is not None else (
                "no covariance: this result is the closed form's (no refinement), which gives none"),
            "matrix": None if covariance is None else np.asarray(covariance, dtype=float).tolist(),
        },
        "observability": list(observability or []),
        "translation_z_status": "measured" if z_known else "unknown",
        "ros_static_transform": tf,
    }
    if extra:
        d.update(extra)
    return to_jsonable(d)


def disk_message(exc: OSError, out: object = None) -> str:
    """An OSError as a user reads it: a full disk names where, and says what happened to the results."""
    import errno

    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        where = exc.filename or out
        return (f"no space left on the disk{f' of {where}' if where else ''} ({exc.strerror}): this run's result was "
                "not written, and an earlier result in that folder is kept as it was; free some space and run again")
    return str(exc)


def _atomic_write(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # mkstemp's 0600 would make results unreadable to the rest of the team
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _writable_parent(out: Path) -> Path:
    """The nearest existing folder above ``out``; InputError when it is not a folder we can write into."""
    parent = out.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(f"cannot create output folder {out}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"cannot write the output folder {out}: no write permission in {parent}; choose another "
                         "--out or fix the folder's permissions")
    return parent


#: The files plsgraph writes into a result folder (a calibration, a diagnosis, a batch's summary, the paper's tables).
#: A folder holding anything else is never replaced, --force or not: the replacement removes every file in it.
RESULT_FILES = frozenset({
    "calibration.yaml", "report.json", "report.html", "base_to_camera.urdf", "static_tf.launch.py",
    "summary.json", "summary.md", "trajectories.png", "residuals.png", "time_offset.png", "observability.png",
    "methods.png", "coverage.png", "event_frames.png", "paper_tables.md", "paper_tables.json",
    "camera_from_board_views.yaml",
})


#: The sub-folders a calibration's folder may hold: the paper's tables, which scripts/demo.sh writes into it, and the
#: calibration a run that gave none kept (plsgraph.report.output.keep_earlier_calibration).
CALIBRATION_SUBFOLDERS = frozenset({"paper_tables", "previous_calibration"})


def foreign_entries(folder: Path, depth: int = 1, subfolders: frozenset[str] | None = None) -> list[str]:
    """The entries of ``folder`` plsgraph did not write (names, sorted): anything but :data:`RESULT_FILES`, and
    sub-folders (a batch's, up to ``depth`` levels; only those named in ``subfolders`` when given) holding anything
    else."""
    out = []
    for p in sorted(folder.iterdir()):
        if p.is_symlink() or not (p.is_dir() or p.is_file()):
            out.append(p.name)
        elif p.is_file():
            if p.name not in RESULT_FILES:
                out.append(p.name)
        elif depth <= 0 or (subfolders is not None and p.name not in subfolders) or foreign_entries(p, depth - 1):
            out.append(p.name + "/")
    return out


def _names(names: list[str], most: int = 4) -> str:
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most else "")


def prepare_output_dir(out_dir: str | Path, force: bool = False, create: bool = True, whole: bool = True) -> Path:
    """Check (and with ``create`` make) ``out_dir``; refuse (InputError) if it exists and is not empty unless
    ``force``, or if it cannot be written. Callers that may still fail before writing pass ``create=False`` and
    write through :func:`staged_output`, so a refused run leaves no empty folder behind.

    ``whole``: the run replaces the folder as a whole (:func:`staged_output`). Such a folder must then hold nothing
    but an earlier plsgraph result (:func:`foreign_entries`), even with ``force``: a recording or notes kept in it
    would go with it. Nor can it be the working folder or one above it."""
    out = Path(out_dir)
    if out.exists():
        if not out.is_dir():
            raise InputError(f"output path {out} exists and is not a folder")
        if whole:
            here = Path.cwd().resolve()
            if out.resolve() == here or out.resolve() in here.parents:
                raise InputError(f"--out {out_dir!s} is the folder you are working in (or holds it); a result folder "
                                 "is replaced as a whole, so choose a folder of its own, e.g. --out calib")
        # A calibration's folder holds no other results' folders (another calibration's, a batch's): they are not
        # this run's to replace.
        foreign = foreign_entries(out, subfolders=CALIBRATION_SUBFOLDERS) if whole else []
        if foreign:
            raise InputError(f"output folder {out} holds files plsgraph did not write ({_names(foreign)}); a result "
                             "folder is replaced as a whole, so they would be lost. Choose a new or empty --out"
                             + (" (--force only replaces an earlier plsgraph result)" if force else ""))
        if any(out.iterdir()) and not force:
            raise InputError(f"output folder {out} already holds "
                             + ("a plsgraph result" if whole else "files")
                             + "; choose another --out or pass --force to replace it")
    elif any(p.exists() and not p.is_dir() for p in out.parents):
        raise InputError(f"cannot create output folder {out}: a parent is a file")
    parent = _writable_parent(out)
    if out.exists() and out.absolute().parent == parent and not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"cannot write into the output folder {out}: no write permission")
    if create:
        out.mkdir(parents=True, exist_ok=True)
    return out


class OutputLock:
    """An exclusive lock on one output folder (a lock file beside it, ``.NAME.plsgraph-lock``), held for the whole
    run: a second run on the same --out fails at once with a clear message instead of mixing files. The lock is
    released by the kernel when the process ends, however it ends; a run that ends normally also removes the file.

    Removing it is safe because a lock counts only while its file is still the one at the path: a run that locked
    a file another run removed meanwhile (it opened it just before) sees that and locks the new one instead."""

    def __init__(self, out: str | Path):
        self.out = Path(out)
        self.path = self.out.absolute().parent / f".{self.out.name}.plsgraph-lock"
        self.fd: int | None = None

    def __enter__(self) -> OutputLock:
        import fcntl

        while True:
            try:
                self.out.absolute().parent.mkdir(parents=True, exist_ok=True)
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            except OSError as exc:  # a folder nothing can be written into (read-only, /proc, no permission)
                raise InputError(f"cannot write the output folder {self.out}: {exc.strerror or exc} in "
                                 f"{self.path.parent}; choose an --out on a writable disk") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise InputError(f"another plsgraph run is writing the output folder {self.out} right now; wait for "
                                 "it to finish or choose another --out") from None
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                self.fd = fd
                return self
            os.close(fd)  # the file was removed by the run that held it: lock the one at the path now

    def __exit__(self, *exc: object) -> None:
        if self.fd is not None:
            try:
                os.unlink(self.path)  # still held: no other run can hold this file now
            except OSError:
                pass
            os.close(self.fd)  # closing releases the flock
            self.fd = None


def clear_after_killed_run(out: str | Path, wait_s: float = 3.0) -> bool:
    """What a run on ``out`` that was killed (a batch's worker stopped on an interrupt) left beside it, removed: its
    staging folder and its lock file, and an earlier result caught mid-swap put back. Only under the folder's lock,
    waited for up to ``wait_s`` (a process the killed run forked holds it until it notices, within a second or so);
    False when another process still holds it (its leftovers are then cleared by the next run on the folder)."""
    import time

    deadline = time.monotonic() + wait_s
    while True:
        try:
            with OutputLock(out) as lock:
                staged_output(lock.out)._clear_leftovers(lock.out.absolute().parent)
            return True
        except InputError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.2)
        except OSError:
            return False


#: The --out folder whose result was swapped in while an interrupt was held back (:class:`staged_output`): the
#: interrupt then arrives with the result written, which the command's message says.
JUST_WRITTEN: list[Path] = []


class staged_output:
    """Write a result folder as a whole: the caller writes into ``stage`` (a fresh hidden folder beside ``out``);
    on success it replaces ``out`` (every file of an earlier run goes); on any error or interrupt the stage is
    removed and ``out`` keeps what it had. Use under an :class:`OutputLock`.

        with staged_output(out) as stage:
            write files into stage
    """

    def __init__(self, out: str | Path):
        self.out = Path(out)
        self.stage: Path | None = None

    def __enter__(self) -> Path:
        parent = self.out.absolute().parent
        parent.mkdir(parents=True, exist_ok=True)
        self._clear_leftovers(parent)
        self.stage = Path(tempfile.mkdtemp(dir=parent, prefix=f".{self.out.name}.staging-"))
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(self.stage, 0o777 & ~umask)  # mkdtemp's 0700 would hide the results from the rest of the team
        return self.stage

    def _clear_leftovers(self, parent: Path) -> None:
        """What runs on this folder that were killed (SIGKILL, a power cut) left beside it: their staging folders
        go, and an earlier result caught between the swap's two renames (``.NAME.old-*/previous`` with ``out``
        missing) is put back first. Only under the folder's :class:`OutputLock`, which no such run holds now."""
        import glob
        import re
        import shutil

        # The folder's name taken literally (not as a pattern: `cal[1]` must not reach `cal1`'s), and only what
        # tempfile.mkdtemp names (the prefix, then eight of its letters): `.a.old-xyz` of a folder named `a.old-xyz`
        # is not `a`'s.
        name = glob.escape(self.out.name)
        own = re.compile(re.escape(f".{self.out.name}.") + r"(old|staging)-[a-z0-9_]{8}")
        for old in sorted(parent.glob(f".{name}.old-*")):
            if not own.fullmatch(old.name):
                continue
            prev = old / "previous"
            try:
                if prev.is_dir() and not self.out.exists():
                    os.rename(prev, self.out)
                shutil.rmtree(old, ignore_errors=True)
            except OSError:
                pass
        for stage in parent.glob(f".{name}.staging-*"):
            if stage.is_dir() and own.fullmatch(stage.name):
                shutil.rmtree(stage, ignore_errors=True)

    def __exit__(self, exc_type, exc, tb) -> None:
        import shutil
        import threading

        stage, self.stage = self.stage, None
        if exc_type is not None:
            shutil.rmtree(stage, ignore_errors=True)
            return
        # Swap the finished stage in; an interrupt is held back for the two renames so that it cannot leave the
        # target missing between them, nor end the run with a message that says the earlier result was kept when the
        # new one is in place. Held by swapping the handlers (Python runs them in the main thread whichever thread the
        # signal reached), not by a signal mask: a mask holds a signal sent to the process only in the masking thread,
        # and the kernel hands it to any other (a BLAS worker thread, the figure worker's writer), whose handler then
        # interrupts the main thread between the renames all the same.
        held: list[int] = []
        saved: dict = {}
        swapping = [True]

        def hold(signum, frame) -> None:
            """During the swap: kept. After it (a handler not put back yet): passed on to the one it replaced."""
            if swapping[0]:
                held.append(signum)
            else:
                _deliver(signum, saved[signum])

        old = None
        try:
            if threading.current_thread() is threading.main_thread():
                for sig in HELD_SIGNALS:
                    handler = signal.getsignal(sig)
                    if handler is None:  # set outside Python: it could not be put back, so it is left as it is
                        continue
                    saved[sig] = handler
                    signal.signal(sig, hold)
            if self.out.exists():
                old = Path(tempfile.mkdtemp(dir=stage.parent, prefix=f".{self.out.name}.old-"))
                os.rename(self.out, old / "previous")
            os.rename(stage, self.out)
            JUST_WRITTEN.append(self.out)  # an interrupt held back arrives with the result in place
        except BaseException:
            if old is not None and (old / "previous").exists() and not self.out.exists():
                os.rename(old / "previous", self.out)
            shutil.rmtree(stage, ignore_errors=True)
            raise
        finally:
            swapping[0] = False  # from here a signal reaches its own handler, whichever is installed
            for sig, handler in saved.items():
                signal.signal(sig, handler)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        for sig in held:  # what arrived during the swap, now, with the new result in place
            _deliver(sig, saved[sig])
        JUST_WRITTEN.remove(self.out)  # no interrupt came with the swap


#: The signals :class:`staged_output` holds back while it swaps a result in.
HELD_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


def _deliver(sig: int, handler) -> None:
    """Hand a signal held back to the handler it would have reached: a Python handler is called (it may raise, e.g.
    KeyboardInterrupt), the default action is taken by raising the signal again, an ignored one is dropped."""
    if callable(handler):
        handler(sig, None)
    elif handler != signal.SIG_IGN:  # SIG_DFL, or a handler not set from Python
        signal.raise_signal(sig)


def write_yaml(path: Path, data: Mapping) -> None:
    text = yaml.safe_dump(to_jsonable(data), sort_keys=False, default_flow_style=None, width=120)
    _atomic_write(Path(path), text.encode())


def write_json(path: Path, data: Mapping) -> None:
    _atomic_write(Path(path), (json.dumps(to_jsonable(data), indent=2, allow_nan=False) + "\n").encode())


def write_text(path: Path, text: str) -> None:
    _atomic_write(Path(path), text.encode())


def markdown_table(rows: list[dict], columns: list[str], floatfmt: str = "{:.3f}") -> str:
    """A GitHub markdown table of ``rows`` (dicts) restricted to ``columns``; None prints as '-'."""

    def fmt(v: Any) -> str:
        if v is None:
            return "-"
        if isinstance(v, float | np.floating):
            return floatfmt.format(v) if math.isfinite(v) else "-"
        return str(v)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


_STATUS_COLOUR = {"observable": "#2e7d32", "weak": "#f9a825", "unobservable": "#c62828",
                  "ok": "#2e7d32", "warned": "#f9a825", "error": "#c62828"}


def html_report(title: str, sections: list[tuple[str, str]], images: list[tuple[str, str]],
                tail_sections: list[tuple[str, str]] | None = None) -> str:
    """A self-contained page: ``sections`` are (heading, pre-escaped HTML) pairs, ``images`` (caption, file) follow
    them, and ``tail_sections`` (details) come after the figures."""
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}"
        "th{background:#f3f3f3}figure{display:inline-block;margin:8px}img{max-width:520px}"
        ".warn{color:#a15c00}.st{color:#fff;padding:1px 6px;border-radius:3px}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
    ]
    for head, body in sections:
        parts.append(f"<h2>{html.escape(head)}</h2>{body}")
    if images:
        parts.append("<h2>Figures</h2>")
        for cap, fname in images:
            parts.append(
                f"<figure><img src='{html.escape(fname)}' alt='{html.escape(cap)}'>"
                f"<figcaption>{html.escape(cap)}</figcaption></figure>"
            )
    for head, body in tail_sections or []:
        parts.append(f"<h2>{html.escape(head)}</h2>{body}")
    parts.append("</body></html>")
    return "\n".join(parts)


def html_table(rows: list[dict], columns: list[str], floatfmt: str = "{:.4g}") -> str:
    def cell(c: str, v: Any) -> str:
        if c == "status" and isinstance(v, str):
            col = _STATUS_COLOUR.get(v, "#555")
            return f"<td><span class='st' style='background:{col}'>{html.escape(v)}</span></td>"
        if isinstance(v, float | np.floating):
            return f"<td>{floatfmt.format(v) if math.isfinite(v) else '-'}</td>"
        return f"<td>{html.escape('-' if v is None else str(v))}</td>"

    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = "".join("<tr>" + "".join(cell(c, r.get(c)) for c in columns) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def status_colour(status: str) -> str:
    return _STATUS_COLOUR.get(status, "#555")
