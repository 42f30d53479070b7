"""Camera intrinsics files: plsgraph / ROS camera_calibration YAML, OpenCV FileStorage YAML, Kalibr camchain.

``--camera-info FILE`` accepts any of them; the format is told from the content:

- OpenCV FileStorage (``%YAML:1.0`` first line, ``!!opencv-matrix`` nodes): ``camera_matrix``,
  ``distortion_coefficients``, ``image_width``, ``image_height``, read with ``cv2.FileStorage``.
- Kalibr camchain (``cam0:``, ``cam1:`` ... each with ``camera_model``, ``intrinsics: [fu, fv, pu, pv]``,
  ``distortion_model``, ``distortion_coeffs``, ``resolution: [w, h]``, ``rostopic``). The camera is chosen
  by ``FILE:camN`` if given, else the camera whose ``rostopic`` is the events topic (or shares its
  namespace, e.g. ``/dvs/image_raw`` for ``/dvs/events``), else the only camera, else ``cam0`` with a
  warning.
- Anything else: plsgraph's own YAML (``width``, ``height``, ``K``, ``D``) or ROS camera_calibration YAML
  (``image_width``, ``image_height``, ``camera_matrix: {data}``, ``distortion_coefficients: {data}``).

plsgraph's camera model is pinhole with plumb_bob (Kalibr: radtan) distortion; files with another model
(Kalibr ``equidistant`` / fisheye, ``omni``, ``ds``, ``eucm``) are refused with an error naming it.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from posixpath import dirname

import numpy as np
import yaml

from ..core.camera import CameraModel
from ..errors import InputError

log = logging.getLogger(__name__)

_CAM_KEY = re.compile(r"cam\d+")
_PLUMB_BOB = ("plumb_bob", "rational_polynomial", "radtan", "radial-tangential")


@dataclass(frozen=True)
class CameraFile:
    """A camera read from a file: the model, which camera of the file it is (Kalibr), and what to tell the user."""

    camera: CameraModel
    path: Path
    format: str  # "plsgraph", "ros", "opencv" or "kalibr"
    name: str | None = None
    warnings: tuple[str, ...] = ()


def split_camera_choice(spec: str | Path) -> tuple[Path, str | None]:
    """``FILE:camN`` -> (FILE, 'camN'); a path that exists as given is never split."""
    s = str(spec)
    p = Path(s)
    if p.exists():
        return p, None
    m = re.fullmatch(r"(.+):(cam\d+|\d+)", s)
    if m and Path(m.group(1)).exists():
        name = m.group(2)
        return Path(m.group(1)), name if name.startswith("cam") else f"cam{name}"
    return p, None


def read_camera_file(spec: str | Path, events_topic: str | None = None) -> CameraFile:
    """Read the intrinsics in ``spec`` (a path, or ``path:camN`` for one camera of a Kalibr camchain)."""
    path, choice = split_camera_choice(spec)
    if not path.is_file():
        s = str(spec)
        # The file before the first colon that leaves an existing file (FILE:cam1:cam0, FILE:, FILE:CAM1).
        head, tail = next(((s[:i], s[i + 1:]) for i, c in enumerate(s) if c == ":" and i and Path(s[:i]).is_file()),
                          ("", ""))
        if head:
            raise InputError(f"camera file {head}: {tail!r} is not a camera of a Kalibr camchain; choose one as "
                             f"{head}:camN (or {head}:N), e.g. {head}:cam0")
        raise InputError(f"camera file {path} does not exist")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"camera file {path} cannot be read as text: {exc}") from exc
    if text.lstrip().startswith("%YAML:1.0") or "!!opencv-matrix" in text:
        if choice:
            raise InputError(f"camera file {path} is an OpenCV file with one camera; drop ':{choice}'")
        return CameraFile(_opencv(path), path, "opencv")
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputError(f"camera file {path} is not valid YAML: {exc}") from exc
    if not isinstance(d, dict):
        raise InputError(f"camera file {path} is not a YAML mapping")
    cams = {k: v for k, v in d.items() if isinstance(k, str) and _CAM_KEY.fullmatch(k)}
    if cams:
        name, warns = _pick_kalibr(path, cams, choice, events_topic)
        for w in warns:
            log.warning(w)
        return CameraFile(_kalibr(path, name, cams[name]), path, "kalibr", name, tuple(warns))
    if choice:
        raise InputError(f"camera file {path} holds one camera (no cam0, cam1 ... keys); drop ':{choice}'")
    fmt = "ros" if "camera_matrix" in d else "plsgraph"
    return CameraFile(_ros_or_plsgraph(path, d), path, fmt)


def load_camera_file(spec: str | Path, events_topic: str | None = None) -> CameraModel:
    """The :class:`CameraModel` of :func:`read_camera_file` (warnings go to logging)."""
    return read_camera_file(spec, events_topic).camera


# ----------------------------------------------------------------------------------------------- formats


def _bad(path: Path, field: str, why: str) -> InputError:
    return InputError(f"camera file {path}: field '{field}' {why}")


def _numbers(path: Path, field: str, value, sizes: tuple[int, ...] | None = None) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise _bad(path, field, f"must be a list of numbers, got {value!r}") from exc
    if sizes is not None and a.size not in sizes:
        raise _bad(path, field, f"must have {' or '.join(map(str, sizes))} numbers, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise _bad(path, field, "contains NaN or inf")
    return a


def _size(path: Path, field: str, value) -> int:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise _bad(path, field, f"must be a positive whole number of pixels, got {value!r}") from exc
    if not (v > 0 and v == int(v)):
        raise _bad(path, field, f"must be a positive whole number of pixels, got {value!r}")
    return int(v)


def _dist5(path: Path, field: str, d: np.ndarray) -> np.ndarray:
    """Up to 5 plumb_bob coefficients; longer vectors (rational model) only when the extra terms are zero."""
    if d.size > 5 and np.any(d[5:] != 0):
        raise _bad(
            path, field, f"has {d.size} coefficients with non-zero terms beyond k1 k2 p1 p2 k3; plsgraph supports "
            "plumb_bob (radtan) distortion only"
        )
    return d[:5]


def _model(path: Path, K: np.ndarray, D: np.ndarray, w: int, h: int) -> CameraModel:
    try:
        return CameraModel(w, h, K.reshape(3, 3), D)
    except InputError as exc:
        raise InputError(f"camera file {path}: {exc}") from exc


def _field(path: Path, d: dict, *names: str):
    for n in names:
        if n in d and d[n] is not None:
            return n, d[n]
    raise _bad(path, names[0], "is missing" + (f" (or '{names[1]}')" if len(names) > 1 else ""))


def _ros_or_plsgraph(path: Path, d: dict) -> CameraModel:
    model = str(d.get("distortion_model", "plumb_bob"))
    if model not in _PLUMB_BOB:
        raise _bad(path, "distortion_model", f"is {model!r}; plsgraph supports plumb_bob (radtan) only")
    wn, w = _field(path, d, "width", "image_width")
    hn, h = _field(path, d, "height", "image_height")
    if "K" in d:
        kn, K = "K", d["K"]
    else:
        _, cm = _field(path, d, "K", "camera_matrix")
        if not isinstance(cm, dict) or "data" not in cm:
            raise _bad(path, "camera_matrix", "must be a mapping with 'data' (9 numbers)")
        kn, K = "camera_matrix.data", cm["data"]
    if "D" in d or "dist" in d:
        dn, D = ("D", d["D"]) if "D" in d else ("dist", d["dist"])
    elif "distortion_coefficients" in d:
        dc = d["distortion_coefficients"]
        if not isinstance(dc, dict) or "data" not in dc:
            raise _bad(path, "distortion_coefficients", "must be a mapping with 'data'")
        dn, D = "distortion_coefficients.data", dc["data"]
        declared = [dc.get(k) for k in ("rows", "cols")]
        if all(isinstance(v, int) and not isinstance(v, bool) for v in declared) and isinstance(D, list | tuple) \
                and len(D) != declared[0] * declared[1]:
            # Padding the missing ones with zeros passed a wrong camera as a right one (a cut-off line).
            raise _bad(path, dn, f"has {len(D)} numbers where rows x cols say {declared[0] * declared[1]}; write all "
                       "of them (or rows: 1, cols: 0 and data: [] for no distortion)")
    else:
        raise _bad(path, "D", "is missing (or 'distortion_coefficients'); write D: [] for no distortion")
    Ka = _numbers(path, kn, K, (9,))
    Da = _dist5(path, dn, _numbers(path, dn, D if D is not None else []))
    return _model(path, Ka, Da, _size(path, wn, w), _size(path, hn, h))


def _opencv(path: Path) -> CameraModel:
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise InputError(f"camera file {path} is not a readable OpenCV FileStorage file: {exc}") from exc
    if not fs.isOpened():
        raise InputError(f"camera file {path} is not a readable OpenCV FileStorage file")
    try:
        def node(name: str):
            n = fs.getNode(name)
            if n.empty() or n.isNone():
                raise _bad(path, name, "is missing")
            return n

        def matrix(name: str) -> np.ndarray:
            n = node(name)
            try:
                m = n.mat() if n.isMap() else None
            except cv2.error as exc:
                raise _bad(path, name, "is not a complete !!opencv-matrix (rows, cols, dt, data)") from exc
            if m is None:
                if n.isSeq():
                    return np.array([n.at(i).real() for i in range(n.size())])
                raise _bad(path, name, "must be an !!opencv-matrix (rows, cols, dt, data)")
            return np.asarray(m, float)

        K = _numbers(path, "camera_matrix", matrix("camera_matrix"), (9,))
        D = _dist5(path, "distortion_coefficients", _numbers(path, "distortion_coefficients",
                                                             matrix("distortion_coefficients")))
        w = _size(path, "image_width", node("image_width").real())
        h = _size(path, "image_height", node("image_height").real())
    finally:
        fs.release()
    return _model(path, K, D, w, h)


def _pick_kalibr(path: Path, cams: dict, choice: str | None, events_topic: str | None) -> tuple[str, list[str]]:
    names = sorted(cams, key=lambda k: int(k[3:]))
    topics = {k: str(v.get("rostopic", "")) if isinstance(v, dict) else "" for k, v in cams.items()}
    matching = _matching_cameras(names, topics, events_topic)
    if choice is not None:
        if choice not in cams:
            raise InputError(f"camera file {path} has no camera {choice!r}; it has {', '.join(names)}")
        if len(matching) == 1 and matching[0] != choice and topics[choice]:
            other = matching[0]
            return choice, [f"camera file {path}: {choice} was chosen, but its rostopic {topics[choice]} is not the "
                            f"events topic's ({events_topic}) and {other}'s ({topics[other]}) is: check that {choice} "
                            f"is the camera that recorded the events (another camera's intrinsics move the lever arm "
                            f"by centimetres within its sigma)"]
        return choice, []
    if len(names) == 1:
        return names[0], []
    if len(matching) == 1:
        return matching[0], []
    listing = ", ".join(f"{k} ({topics[k] or 'no rostopic'})" for k in names)
    why = (f"none matches the events topic {events_topic}" if events_topic else
           "the events have no topic to match (an event-camera file)")
    # Taking one of them anyway gave a confident wrong answer where cam0 was another camera (a 5 % focal length off
    # moved the lever arm by 10 cm within a 1 cm sigma): which camera saw the events is the user's to say.
    raise InputError(f"camera file {path} has {len(names)} cameras: {listing}; {why}, so which one saw the events "
                     f"is not known: choose it with --camera-info {path}:camN")


def _matching_cameras(names: list[str], topics: dict[str, str], events_topic: str | None) -> list[str]:
    """The cameras whose rostopic is the events topic; failing one, those in its namespace."""
    if not events_topic:
        return []
    exact = [k for k in names if topics[k] == events_topic]
    if len(exact) == 1:
        return exact
    ns = dirname(events_topic.rstrip("/"))
    return [k for k in names if ns not in ("", "/") and dirname(topics[k].rstrip("/")) == ns]


def _kalibr(path: Path, name: str, cam) -> CameraModel:
    where = f"{name}."
    if not isinstance(cam, dict):
        raise _bad(path, name, "must be a mapping (camera_model, intrinsics, distortion_model, ...)")
    model = str(cam.get("camera_model", "pinhole"))
    if model != "pinhole":
        raise _bad(path, where + "camera_model", f"is {model!r}; plsgraph's camera model is pinhole only")
    dist = str(cam.get("distortion_model", "radtan"))
    if dist in ("equidistant", "fisheye"):
        raise _bad(
            path, where + "distortion_model", f"is {dist!r} (fisheye), which plsgraph's camera model does not "
            "support (pinhole with radtan / plumb_bob distortion); calibrate the camera as pinhole-radtan"
        )
    if dist not in ("radtan", "none"):
        raise _bad(path, where + "distortion_model", f"is {dist!r}; plsgraph supports radtan (plumb_bob) only")
    if "intrinsics" not in cam:
        raise _bad(path, where + "intrinsics", "is missing (expected [fu, fv, pu, pv])")
    fu, fv, pu, pv = _numbers(path, where + "intrinsics", cam["intrinsics"], (4,))
    if dist == "none":
        D = np.zeros(0)
    elif "distortion_coeffs" not in cam:
        raise _bad(path, where + "distortion_coeffs", "is missing (expected [k1, k2, r1, r2] for radtan)")
    else:
        D = _numbers(path, where + "distortion_coeffs", cam["distortion_coeffs"], (4,))
    if "resolution" not in cam:
        raise _bad(path, where + "resolution", "is missing (expected [width, height])")
    res = cam["resolution"]
    if not isinstance(res, list | tuple) or len(res) != 2:
        raise _bad(path, where + "resolution", f"must be [width, height], got {res!r}")
    w = _size(path, where + "resolution", res[0])
    h = _size(path, where + "resolution", res[1])
    K = np.array([fu, 0.0, pu, 0.0, fv, pv, 0.0, 0.0, 1.0])
    return _model(path, K, D, w, h)
