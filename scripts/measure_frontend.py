#!/usr/bin/env python3
"""Front-end measurements behind docs/frontend.md.

``--part sim``: simulated recordings with known truth (the board moving in front of the camera at
several speeds): detection rate, centre error (px), PnP pose error and time-stamp effect for each
event representation. ``--part real``: the real DAVIS346 tag-board recording: how many tags the
aruco detector finds in each representation at 30 Hz, the board geometry that can be read off the
detections, and one picture per representation in docs/img/.

Usage: .venv/bin/python scripts/measure_frontend.py [--part sim|real|all] [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from plsgraph.core.board import Board, load_board  # noqa: E402
from plsgraph.core.camera import davis346_default  # noqa: E402
from plsgraph.core.geometry import inv_T, rotation_error_deg, transform_points  # noqa: E402
from plsgraph.errors import InsufficientDataError  # noqa: E402
from plsgraph.frontend import surfaces  # noqa: E402
from plsgraph.frontend.detect import detect_aprilgrid, detect_tags, make_aruco_detector  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from realdata import SHARED_REAL_DIR  # noqa: E402

IMG_DIR = REPO / "docs" / "img"

# Representations compared on the real recording: (label, kind, surface_at keyword arguments, blur sigma).
REAL_KINDS = [
    ("count", "count", {"window_ns": 33_333_333}, 0.0),
    ("time_surface", "time_surface", {"tau_s": 0.03}, 0.0),
    ("polarity_aware", "polarity_aware", {"window_ns": 33_333_333}, 0.0),
    ("time_surface_signed", "time_surface", {"tau_s": 0.03, "polarity": "signed"}, 0.0),
    ("polarity_aware_signed", "polarity_aware", {"window_ns": 33_333_333, "signed": True}, 0.0),
    ("time_surface_signed_100ms_blur1", "time_surface", {"tau_s": 0.1, "polarity": "signed"}, 1.0),
    ("leaky_50ms", "leaky", {"tau_s": 0.05}, 0.0),
    ("leaky_300ms_blur1", "leaky", {"tau_s": 0.3, "window_ns": 900_000_000}, 1.0),
]


def real_part() -> dict:
    from plsgraph.io.events_reader import read_events

    path = SHARED_REAL_DIR / "davis346_tagboard.mcap"
    ev = read_events(path)
    board = load_board("aprilgrid_4x3_tagboard")
    period = int(round(1e9 / 30))
    tq = np.arange(ev.t_first + period, ev.t_last + 1, period, dtype=np.int64)
    detector = make_aruco_detector(border_bits=1)
    print(f"real recording: {len(ev)} events in {ev.duration_s:.3f} s, {tq.size} windows at 30 Hz")
    print(f"{'representation':<32} {'tags':>5} {'windows>=1':>10} {'windows>=2':>10} {'boards':>6}  ids")
    results = {}
    IMG_DIR.mkdir(parents=True, exist_ok=True)
    show_k = 27  # a window where the board moves fast enough for every representation to show it
    all_corners = []  # (ids, corners) per window for the geometry estimate
    for label, kind, kw, blur in REAL_KINDS:
        tags = w1 = w2 = boards = 0
        ids_seen: set[int] = set()
        for k, t in enumerate(tq):
            img = surfaces.surface_at(ev, int(t), kind, **kw)
            if blur:
                img = cv2.GaussianBlur(img, (0, 0), blur)
            # Unsigned surfaces show edges bright on black; the detector wants a black tag border on
            # white, which neither orientation gives, so both are tried and the union counted.
            variants = [surfaces.to_uint8(img)]
            if img.min() >= 0:
                variants.append(surfaces.to_uint8(img, invert=True))
            found: dict[int, np.ndarray] = {}
            for v in variants:
                r = detect_tags(v, detector)
                for i, c in zip(r.ids.tolist(), r.corners, strict=True):
                    if i < board.cols * board.rows:
                        found.setdefault(i, c)
                if detect_aprilgrid(v, board, None, detector=detector, layout="kalibr").ok:
                    boards += 1
                    break
            tags += len(found)
            w1 += len(found) >= 1
            w2 += len(found) >= 2
            ids_seen |= set(found)
            if len(found) >= 2:
                all_corners.append((np.array(list(found)), np.array(list(found.values()))))
            if k == show_k:
                vis = cv2.cvtColor(variants[0], cv2.COLOR_GRAY2BGR)
                for i, c in found.items():
                    cv2.polylines(vis, [np.round(c).astype(np.int32)], True, (0, 0, 255), 1)
                    cv2.putText(vis, str(i), tuple(np.round(c.mean(axis=0)).astype(int)), cv2.FONT_HERSHEY_SIMPLEX,
                                0.35, (0, 255, 0), 1)
                cv2.imwrite(str(IMG_DIR / f"real_{label}.png"), vis)
        results[label] = {"tags": tags, "windows_with_tag": w1, "windows_with_2_tags": w2, "board_detections": boards,
                          "ids": sorted(ids_seen)}
        print(f"{label:<32} {tags:>5} {w1:>10} {w2:>10} {boards:>6}  {sorted(ids_seen)}")
    results["windows"] = int(tq.size)
    results["geometry"] = real_geometry(all_corners, board)
    return results


def real_geometry(windows: list[tuple[np.ndarray, np.ndarray]], board: Board) -> dict:
    """Layout and tag spacing ratio of the real board from windows with two or more tags.

    Tag pitch / tag size is scale-free: for each candidate spacing ratio, fit one homography from
    the Kalibr layout (tag size 1) to all corners of a window and keep the ratio with the smallest
    residual. Both print layouts are tried; the one that fits says how the tags are printed.
    """
    from plsgraph.core.board import aprilgrid_points
    from plsgraph.frontend.detect import aprilgrid_corner_index

    ratios = np.round(np.arange(0.10, 0.501, 0.01), 3)
    out = {}
    for layout in ("kalibr", "opencv"):
        cost = np.zeros(ratios.size)
        used = 0
        for ids, corners in windows:
            if ids.size < 3:
                continue
            idx = aprilgrid_corner_index(ids, board.cols, layout).ravel()
            img = corners.reshape(-1, 2)
            used += 1
            for j, r in enumerate(ratios):
                P = aprilgrid_points(board.cols, board.rows, 1.0, float(r))[idx, :2]
                H, _ = cv2.findHomography(P, img, 0)
                ph = np.c_[P, np.ones(len(P))] @ H.T
                cost[j] += np.sqrt(np.mean(np.sum((ph[:, :2] / ph[:, 2:] - img) ** 2, axis=1)))
        if used:
            j = int(np.argmin(cost))
            out[layout] = {"windows": used, "best_spacing_ratio": float(ratios[j]), "mean_rms_px": cost[j] / used}
    print("real board geometry (windows with >= 3 tags):", json.dumps(out))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("sim", "real", "all"), default="all")
    ap.add_argument("--quick", action="store_true", help="fewer and shorter simulated sequences")
    args = ap.parse_args()
    res = {}
    if args.part in ("real", "all"):
        res["real"] = real_part()
    if args.part in ("sim", "all"):
        res["sim"] = sim_part(args.quick)
    out = REPO / "docs" / "img" / f"measure_frontend_{args.part}.json"
    out.write_text(json.dumps(res, indent=1, default=float))
    print(f"wrote {out.relative_to(REPO)}")


def simulate_board_events(poses: np.ndarray, t: np.ndarray, camera, board, seed: int = 0):
    """Events of the board seen from poses T_board_cam (m, 4, 4) at times t (m,): the project's event
    simulator (plsgraph.sim.events, default parameters: C = 0.25 +- 0.03, 0.1 Hz/pixel noise, 0.1 ms
    refractory period, adaptive render times)."""
    from plsgraph.sim.events import simulate_events

    return simulate_events(t, poses, camera, board, seed=seed)


def board_motion(board, speed: float, duration: float, dt: float, seed: int = 0):
    """Times and poses T_board_cam of a camera ~0.6 m in front of the board, moving smoothly.

    The camera translates (3 cm amplitude) and wobbles (0.1 rad) along sinusoids of incommensurate
    frequencies; ``speed`` scales the frequencies, so the board stays in view at every speed and the
    image motion grows in proportion (speed 1: about 0.17 m/s and 0.5 rad/s peak, roughly 150 px/s of
    image motion; 5: about 750 px/s, 25 px per 30 Hz window). Returns (t, poses).
    """
    from plsgraph.core.geometry import make_T, so3_exp

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration + 1e-12, dt)
    ph = rng.uniform(0, 2 * np.pi, 6)
    f = speed * np.array([0.9, 1.3, 0.7, 0.8, 1.1, 1.7])
    p = 0.03 * np.sin(2 * np.pi * f[:3] * t[:, None] + ph[:3])
    w = 0.1 * np.sin(2 * np.pi * f[3:] * t[:, None] + ph[3:])
    R = so3_exp(np.array([-0.05, 0.01, 0.05])) @ so3_exp(w)  # camera turned a little off the board normal
    # Camera centre in the board frame: in front of the board centre (board z points away from it).
    centre = board.points.mean(axis=0) + np.array([0.0, 0.0, -0.6]) + p
    return t, make_T(R, centre)


SIM_SPEEDS = {"slow": 0.3, "moderate": 1.0, "fast": 2.5, "very_fast": 5.0}
SIM_KINDS = ["count", "time_surface", "polarity_aware", "leaky"]


def sim_part(quick: bool) -> dict:
    from plsgraph.core.geometry import se3_log
    from plsgraph.frontend.track import camera_track_from_events

    cam = davis346_default()
    board = load_board("acircles_4x11")
    duration = 0.5 if quick else 1.5
    speeds = {"slow": 0.3, "moderate": 1.0, "fast": 2.5} if quick else SIM_SPEEDS
    out = {}
    print(f"{'speed':<10} {'kind':<15} {'Mev/s':>6} {'det%':>5} {'pose%':>6} {'centre px':>9} {'rot deg':>8} "
          f"{'pos mm':>7} {'centre px @query':>16} {'w err deg/s':>11} {'v err mm/s':>10} {'(0.1 s window)':>14}")
    for name, sp in speeds.items():
        t, poses = board_motion(board, sp, duration, 1e-3)
        c0 = time.perf_counter()
        ev = simulate_board_events(poses, t, cam, board)
        sim_s = time.perf_counter() - c0
        row = {"events": len(ev), "sim_seconds": sim_s, "opencv_blob_grid": opencv_baseline(ev, cam, board)}
        if name == "moderate":
            save_sim_pictures(ev, t, poses, cam, board)
        for kind in SIM_KINDS:
            res = {}
            for stamp in ("events", "query"):
                try:
                    tr = camera_track_from_events(ev, cam, board, 30.0, kind, timestamp=stamp)
                except InsufficientDataError as exc:
                    res[stamp] = {"error": str(exc)}
                    continue
                T_true = _interp_poses(t, poses, tr.t)
                uv_true = np.stack([cam.project(transform_points(inv_T(T), board.points)) for T in T_true])
                cerr = np.linalg.norm(tr.detections.uv - uv_true, axis=2)
                perr = se3_log(inv_T(T_true) @ tr.T_board_cam)
                w_err, v_err = velocity_errors(tr, t, poses)
                w_err_short, v_err_short = velocity_errors(tr, t, poses, window_s=0.1)
                res[stamp] = {
                    "omega_err_deg_s_median": w_err,
                    "v_err_mm_s_median": v_err,
                    "omega_err_deg_s_median_window_0.1s": w_err_short,
                    "v_err_mm_s_median_window_0.1s": v_err_short,
                    "windows": tr.info["windows"],
                    "detected": tr.info["detected"],
                    "poses": tr.info["poses"],
                    "skipped": tr.info["skipped"],
                    "points_per_detection": float(np.mean(np.isfinite(tr.detections.uv[:, :, 0]).sum(axis=1))),
                    "centre_err_px_median": float(np.nanmedian(cerr)),
                    "centre_err_px_p90": float(np.nanpercentile(cerr, 90)),
                    "rot_err_deg_median": float(np.median(rotation_error_deg(tr.T_board_cam[:, :3, :3],
                                                                             T_true[:, :3, :3]))),
                    "pos_err_mm_median": float(1e3 * np.median(np.linalg.norm(perr[:, 3:], axis=1))),
                }
            row[kind] = res
            e = res.get("events", {})
            q = res.get("query", {})
            if "error" in e or not e:
                print(f"{name:<10} {kind:<15} {len(ev) / duration / 1e6:>6.2f}   no detections")
                continue
            print(f"{name:<10} {kind:<15} {len(ev) / duration / 1e6:>6.2f} {100 * e['detected'] / e['windows']:>5.0f} "
                  f"{100 * e['poses'] / e['windows']:>6.0f} {e['centre_err_px_median']:>9.3f} "
                  f"{e['rot_err_deg_median']:>8.3f} {e['pos_err_mm_median']:>7.2f} "
                  f"{q.get('centre_err_px_median', float('nan')):>16.3f} {e['omega_err_deg_s_median']:>11.2f} "
                  f"{e['v_err_mm_s_median']:>10.1f} {e['omega_err_deg_s_median_window_0.1s']:>6.1f} "
                  f"{e['v_err_mm_s_median_window_0.1s']:>7.1f}")
        out[name] = row
    return out


def velocity_errors(track, t: np.ndarray, poses: np.ndarray, window_s: float = 0.2) -> tuple[float, float]:
    """Median errors of the pipeline's camera velocities (plsgraph.calib.time_offset.camera_velocities_on_grid,
    valid grid samples) against the true body velocities (central differences of the 1 kHz true poses): angular in
    deg/s, linear in mm/s."""
    from plsgraph.calib.time_offset import camera_velocities_on_grid
    from plsgraph.core.geometry import se3_log
    from plsgraph.errors import InsufficientDataError as _Short

    try:
        cv = camera_velocities_on_grid(track, window_s=window_s)
        tv, w, v = cv.t[cv.valid], cv.omega[cv.valid], cv.v[cv.valid]
    except _Short:
        return float("nan"), float("nan")
    h = 1e-3
    tv = np.clip(tv, t[0] + h, t[-1] - h)
    Tm, Tp = _interp_poses(t, poses, tv - h), _interp_poses(t, poses, tv + h)
    xi = se3_log(inv_T(Tm) @ Tp) / (2 * h)  # body twist (rotation, translation part ~ body velocity)
    T0 = _interp_poses(t, poses, tv)
    v_true = np.einsum("nji,nj->ni", T0[:, :3, :3], (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h))
    w_err = np.degrees(np.median(np.linalg.norm(w - xi[:, :3], axis=1)))
    v_err = 1e3 * np.median(np.linalg.norm(v - v_true, axis=1))
    return float(w_err), float(v_err)


def opencv_baseline(ev, cam, board) -> dict:
    """Windows (of the same 30 Hz grid) in which OpenCV's SimpleBlobDetector + findCirclesGrid alone find the
    grid on each surface: blurred by 1 px, bright and dark blobs, both grid finders, no lattice labelling."""
    from plsgraph.frontend.detect import detect_circle_grid
    from plsgraph.frontend.track import DEFAULT_PARAMS

    period = int(round(1e9 / 30))
    tq = np.arange(ev.t_first + period, ev.t_last + 1, period, dtype=np.int64)
    out = {}
    for kind in SIM_KINDS:
        kw = {"window_ns": period} if kind in ("count", "polarity_aware") else {}
        found = 0
        for t_k in tq:
            img = surfaces.surface_at(ev, int(t_k), kind, **kw, **DEFAULT_PARAMS[kind])
            fg = "dark" if kind == "leaky" else "bright"
            det = detect_circle_grid(np.abs(img) if fg == "bright" else img, board, cam, foreground=fg,
                                     blur_sigma=1.0, exhaustive=True, lattice_fallback=False)
            found += det.ok
        out[kind] = {"windows": int(tq.size), "detected": int(found)}
    print("OpenCV blob + grid finder alone:", {k: f"{v['detected']}/{v['windows']}" for k, v in out.items()})
    return out


def save_sim_pictures(ev, t, poses, cam, board) -> None:
    """docs/img/sim_<kind>.png: each representation of one 30 Hz window, with the true circle centres (green)
    and the detected ones (red) where the front end finds the board."""
    from plsgraph.frontend.detect import detect_circle_grid
    from plsgraph.frontend.track import DEFAULT_PARAMS, _rim_image

    IMG_DIR.mkdir(parents=True, exist_ok=True)
    tq = ev.t_first + 12 * int(round(1e9 / 30))
    T = _interp_poses(t, poses, np.array([tq * 1e-9 - 1 / 60]))[0]
    truth = cam.project(transform_points(inv_T(T), board.points))
    for kind in SIM_KINDS:
        params = DEFAULT_PARAMS[kind]
        kw = {"window_ns": 33_333_333} if kind in ("count", "polarity_aware") else {}
        img = surfaces.surface_at(ev, int(tq), kind, **kw, **params)
        vis = cv2.cvtColor(surfaces.to_uint8(img), cv2.COLOR_GRAY2BGR)
        age = params.get("tau_s", 1 / 30)
        rim, level = _rim_image(img, kind, params, age)
        det = detect_circle_grid(rim, board, cam, foreground="rims", rim_threshold=level)
        vis = cv2.resize(vis, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        for p in truth:
            cv2.circle(vis, tuple(np.round(2 * p + 0.5).astype(int)), 2, (0, 200, 0), -1)
        for p in det.uv[np.isfinite(det.uv[:, 0])]:
            cv2.circle(vis, tuple(np.round(2 * p + 0.5).astype(int)), 3, (0, 0, 255), 1)
        cv2.putText(vis, f"{kind}: {det.reason}", (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 255), 1)
        cv2.imwrite(str(IMG_DIR / f"sim_{kind}.png"), vis)


def _interp_poses(t: np.ndarray, poses: np.ndarray, tq: np.ndarray) -> np.ndarray:
    from plsgraph.core.geometry import interpolate_poses

    return interpolate_poses(np.clip(tq, t[0], t[-1]), t, poses)


if __name__ == "__main__":
    main()
