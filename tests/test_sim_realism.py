"""Real-world effects of the simulator: each effect does what its parameter says; ideal mode is unchanged."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

from plsgraph.core.board import load_board
from plsgraph.core.camera import CameraModel, davis346_default
from plsgraph.core.geometry import inv_T, make_T, so3_exp, transform_points
from plsgraph.errors import InputError
from plsgraph.io.writer import read_truth, write_truth
from plsgraph.sim.events import EventSimParams, simulate_events
from plsgraph.sim.realism import (
    EFFECTS,
    Realism,
    draw_realism,
    effect_fields,
    field_specs,
    ideal,
    only,
    realistic,
)
from plsgraph.sim.render import BoardRenderer, RenderParams, camera_rays
from plsgraph.sim.robot import simulate_robot

T0 = 1_700_000_000.0
QUIET = dict(noise_rate_hz=0.0, contrast_sigma=0.0, refractory_s=0.0)
BOARD = load_board("acircles_4x11")
CAM = CameraModel(80, 60, np.array([[60.0, 0, 40.0], [0, 60.0, 30.0], [0, 0, 1]]), np.array([-0.1, 0.02, 0, 0, 0]))


def _facing(dist: float, dx: float = 0.0) -> np.ndarray:
    R = so3_exp(np.array([0.1, -0.1, 0.05]))
    c = BOARD.points.mean(axis=0)
    return make_T(R, c + R @ np.array([0.0, 0.0, -dist]) + np.array([dx, 0.0, 0.0]))


def _sweep():
    s = np.linspace(0.0, 1.0, 41)
    return T0 + s, np.stack([_facing(0.5, 0.03 * x) for x in s])


def _static(duration: float):
    return T0 + np.array([0.0, duration]), np.stack([_facing(0.5)] * 2)


def _with(base: Realism, group: str, **changes) -> Realism:
    return dataclasses.replace(base, **{group: dataclasses.replace(getattr(base, group), **changes)})


# -- the parameter sets --------------------------------------------------------------------------------------


def test_draws_stay_in_the_documented_ranges():
    rng = np.random.default_rng(0)
    specs = field_specs()
    assert {"latency", "hot_pixels", "flicker", "timestamp_quantization", "lens_distortion", "skid_steer",
            "wheel_radius", "wheel_slip", "odom_latency", "board_scale", "board_yaw", "joystick"} <= set(EFFECTS)
    for _ in range(20):
        fx = draw_realism(rng)
        for r in specs:
            v = getattr(getattr(fx, r["group"]), r["name"])
            if r["range"] is None:
                assert v == r["default"], r["name"]
            elif r["draw"] == "choice":
                assert v in r["range"]
            else:
                assert r["range"][0] <= v <= r["range"][1], (r["name"], v)
    for r in specs:  # every parameter is documented
        assert r["unit"] and r["doc"]


def test_only_switches_one_effect_over_the_ideal_base():
    base = ideal()
    for effect in EFFECTS:
        fx = only(effect, np.random.default_rng(1))
        changed = {(g, f.name) for g in ("sensor", "robot", "scene", "motion")
                   for f in dataclasses.fields(getattr(fx, g))
                   if getattr(getattr(fx, g), f.name) != getattr(getattr(base, g), f.name)}
        assert changed <= set(effect_fields(effect)) and changed, effect
    with pytest.raises(InputError):
        only("rain")
    assert realistic() == Realism() and realistic().motion.joystick and not ideal().motion.joystick


# -- event sensor ---------------------------------------------------------------------------------------------


def test_ideal_events_are_unchanged():
    rec = simulate_robot("rich", duration=1.2, seed=2, realism="ideal")
    ev = rec.events(seed=5)
    # Fingerprint of the event simulator before the real-sensor effects existed.
    assert len(ev) == 440758
    assert int(ev.x.astype(np.int64).sum()) == 83897484 and int(ev.y.astype(np.int64).sum()) == 45985959
    assert int(ev.p.astype(np.int64).sum()) == -1364


def test_hot_pixels_fire_at_their_rate():
    t, T = _static(2.0)
    p = EventSimParams(**QUIET, hot_pixels=3, hot_rate_min_hz=200.0, hot_rate_max_hz=200.0)
    ev = simulate_events(t, T, CAM, BOARD, p, seed=4)
    counts = np.bincount(ev.y.astype(np.int64) * CAM.width + ev.x, minlength=CAM.width * CAM.height)
    hot = np.sort(counts)[::-1]
    assert hot[3] == 0  # a static scene: only the hot pixels fire
    assert np.all(np.abs(hot[:3] - 400) < 4 * np.sqrt(400))


def test_timestamps_are_whole_microseconds():
    t, T = _sweep()
    ev = simulate_events(t + 1.234567e-7, T, CAM, BOARD, EventSimParams(timestamp_resolution_s=1e-6), seed=1)
    assert len(ev) > 1000 and np.all(ev.t % 1000 == 0) and np.all(np.diff(ev.t) >= 0)


def _first_event_times(ev) -> np.ndarray:
    pix = ev.y.astype(np.int64) * CAM.width + ev.x
    order = np.lexsort((ev.t, pix))
    ps = pix[order]
    first = np.r_[True, np.diff(ps) != 0]
    out = np.full(CAM.width * CAM.height, np.nan)
    out[ps[first]] = ev.t[order][first] * 1e-9
    return out


def _delay(illumination: float, **latency) -> float:
    t, T = _sweep()
    rp = RenderParams(illumination=illumination)
    ref = _first_event_times(simulate_events(t, T, CAM, BOARD, EventSimParams(**QUIET, render=rp)))
    late = _first_event_times(simulate_events(t, T, CAM, BOARD, EventSimParams(**QUIET, render=rp, **latency)))
    d = late - ref
    return float(np.median(d[np.isfinite(d)]))


def test_latency_delays_an_edge_by_the_time_constant_and_more_when_dim():
    # A time constant of 2 ms everywhere (every pixel at the cap): events come 2 ms late.
    assert _delay(1.0, latency_s=1.0, latency_max_s=2e-3) == pytest.approx(2e-3, rel=0.1)
    # Time constant latency_s / irradiance: four times dimmer, four times later.
    bright = _delay(1.0, latency_s=2e-4, latency_max_s=1.0)
    dim = _delay(0.25, latency_s=2e-4, latency_max_s=1.0)
    assert 1e-4 < bright < 1e-3
    assert dim / bright == pytest.approx(4.0, rel=0.2)


def test_flicker_fires_at_the_flicker_frequency_by_depth_on_bright_pixels():
    t, T = _static(0.5)

    def run(m: float, **kw):
        return simulate_events(t, T, CAM, BOARD, EventSimParams(**QUIET, flicker_depth=m, flicker_hz=100.0, **kw))

    # Peak-to-peak log modulation log((1 + m) / (1 - m)) against the 0.25 threshold.
    assert len(run(0.05)) == 0
    shallow, deep = run(0.2), run(0.4)
    on = shallow.t[shallow.p > 0] * 1e-9
    assert on.size / (CAM.width * CAM.height) / 0.5 == pytest.approx(100.0, rel=0.05)  # one ON per period
    assert abs(np.mean(np.exp(2j * np.pi * 100.0 * on))) > 0.9  # phase-locked to the light
    assert len(deep) > 1.5 * len(shallow)
    # Photoreceptor bandwidth: slow (dim) pixels filter the flicker out, bright ones still see it.
    # With 0.2 ms at irradiance 1 the black ink (0.05) has 4 ms: 100 Hz is cut to a third, below threshold.
    img = BoardRenderer(CAM, BOARD).intensity(T[0]).ravel()

    def on_ink(ev) -> int:
        return int(np.sum(img[ev.y.astype(np.int64) * CAM.width + ev.x] < 0.06))

    slow = run(0.2, latency_s=2e-4, latency_max_s=1.0)
    assert on_ink(shallow) > 1000 and on_ink(slow) == 0
    assert np.sum(img[slow.y.astype(np.int64) * CAM.width + slow.x] > 0.8) > 0.8 * np.sum(img > 0.8) * 100


def test_drawn_lenses_map_the_image_one_to_one():
    rng = np.random.default_rng(3)
    for _ in range(30):
        draw_realism(rng).sensor.camera(davis346_default())  # raises if the lens folds back in the image
    bad = dataclasses.replace(ideal().sensor, k1=-0.3, k2=0.0)
    with pytest.raises(InputError, match="folds back"):
        bad.camera(davis346_default())


def test_strong_lens_distortion_renders_consistently():
    cam = only("lens_distortion").sensor.camera(davis346_default())
    cam = dataclasses.replace(cam, dist=np.array([-0.3, 0.08, 0.0, 0.0, 0.0]))
    rays, _ = camera_rays(cam)
    v, u = np.mgrid[0 : cam.height, 0 : cam.width]
    uv = cam.project(rays)
    assert np.abs(uv - np.stack([u.ravel(), v.ravel()], axis=1)).max() < 1e-3


# -- robot and scene ------------------------------------------------------------------------------------------


def test_ideal_recording_is_unchanged():
    # Fingerprints of the robot simulation before realism existed (same seed, same arguments).
    rec = simulate_robot("rich", duration=5.0, seed=3, realism="ideal")
    got = [float(np.sum(a)) for a in (rec.wheel_left, rec.wheel_right, rec.cam_t, rec.T_board_cam,
                                        rec.truth_base.T_world_base)]
    assert got == [1220.6744158447264, 1047.0615382334051, 370.16878583472374, 397.86232651242767,
                   20997.60270346194]
    rec = simulate_robot("rich", duration=5.0, seed=3, slip=0.0, encoder_ticks_per_rev=0, realism="ideal")
    assert float(np.sum(rec.wheel_left)) == 1216.738342878295


def _odometry(rec, r: float, b: float) -> tuple[float, float]:
    """Heading change and path length from the wheel angles with radius r and track b."""
    dl, dr = np.diff(rec.wheel_left), np.diff(rec.wheel_right)
    return float(np.sum(r * (dr - dl) / b)), float(np.sum(np.abs(r * (dr + dl) / 2)))


def _truth_motion(rec) -> tuple[float, float]:
    tb = rec.truth_base
    th = np.unwrap(np.arctan2(tb.T_world_base[:, 1, 0], tb.T_world_base[:, 0, 0]))
    return float(th[-1] - th[0]), float(np.sum(np.linalg.norm(np.diff(tb.T_world_base[:, :2, 3], axis=0), axis=1)))


def test_skid_steer_odometry_overstates_turning_by_the_track_ratio():
    fx = _with(ideal(), "robot", track_ratio=1.6)
    rec = simulate_robot("spin", duration=6.0, seed=1, slip=0.0, encoder_ticks_per_rev=0, realism=fx)
    assert rec.track_width == pytest.approx(1.6 * rec.track_width_nominal)
    dth_odo, _ = _odometry(rec, rec.wheel_radius_nominal, rec.track_width_nominal)
    dth_true, _ = _truth_motion(rec)
    # Wheels of a skid-steer robot turn b_eff / b times more than a differential drive's would: integrated
    # with the geometric track, the heading rate is b_eff / b too large.
    assert dth_odo / dth_true == pytest.approx(1.6, rel=1e-3)
    assert _odometry(rec, rec.wheel_radius, rec.track_width)[0] == pytest.approx(dth_true, rel=1e-3)


def test_wheel_radius_error_scales_odometry_distance():
    fx = _with(ideal(), "robot", wheel_radius_error=0.04)
    rec = simulate_robot("straight", duration=6.0, seed=1, slip=0.0, encoder_ticks_per_rev=0, realism=fx)
    _, dist = _odometry(rec, rec.wheel_radius_nominal, rec.track_width_nominal)
    assert dist / _truth_motion(rec)[1] == pytest.approx(1 / 1.04, rel=1e-3)


def test_correlated_slip_is_stronger_when_turning():
    fx = _with(ideal(), "robot", slip_sigma=0.02, slip_tau_s=0.5, slip_turn_gain=3.0)
    err = {}
    for motion in ("straight", "spin"):
        kw = dict(duration=20.0, seed=2, slip=0.0, encoder_ticks_per_rev=0)
        a = simulate_robot(motion, realism=fx, **kw)
        b = simulate_robot(motion, realism="ideal", **kw)
        moving = np.abs(np.diff(b.wheel_left)) > 1e-4
        e = (np.diff(a.wheel_left) / np.where(moving, np.diff(b.wheel_left), 1.0) - 1.0)[moving]
        err[motion] = e
    assert np.std(err["straight"]) == pytest.approx(0.02, rel=0.5)
    assert np.corrcoef(err["straight"][:-1], err["straight"][1:])[0, 1] > 0.8  # correlated, not white
    assert np.std(err["spin"]) > 1.5 * np.std(err["straight"])


def test_odometry_latency_and_jitter_shift_the_stamps():
    kw = dict(duration=5.0, seed=4)
    base = simulate_robot("rich", realism="ideal", **kw)
    late = simulate_robot("rich", realism=_with(ideal(), "robot", odom_latency_s=0.02), **kw)
    assert np.allclose(late.wheel_t - base.wheel_t, 0.02, atol=1e-12)
    assert np.array_equal(late.wheel_left, base.wheel_left)
    assert late.td == pytest.approx(base.td + 0.02)
    # The truth lives in the stamps' clock: camera poses still close the loop.
    assert np.allclose(late.camera_poses_at(late.cam_t), late.T_board_cam, atol=1e-9)
    assert np.allclose(late.T_board_cam, base.T_board_cam, atol=1e-9)
    jit = simulate_robot("rich", realism=_with(ideal(), "robot", odom_jitter_s=2e-3), **kw)
    d = jit.wheel_t - base.wheel_t
    assert np.std(d) == pytest.approx(2e-3, rel=0.2) and np.all(np.diff(jit.wheel_t) > 0)


def test_board_print_scale_scales_the_true_points():
    fx = _with(ideal(), "scene", board_scale=1.01)
    rec = simulate_robot("rich", duration=3.0, seed=5, realism=fx)
    assert np.allclose(rec.board_true.points, 1.01 * rec.board.points)
    uv, inside = rec.project_truth()
    T_cam_board = inv_T(rec.T_board_cam[0])
    assert np.allclose(uv[0], rec.camera.project(transform_points(T_cam_board, 1.01 * rec.board.points)))
    det = rec.detections(noise_px=0.0)
    assert np.array_equal(det.board_points, rec.board.points)  # the detector knows only the nominal board


def test_board_distance_and_yaw_place_the_board():
    fx = _with(_with(ideal(), "scene", board_distance_m=2.2, board_yaw_deg=20.0), "motion", joystick=True)
    rec = simulate_robot("rich", duration=10.0, seed=3, realism=fx)
    lo, hi = rec.info["range_m"]
    assert 1.5 < lo < 2.2 < hi < 3.0
    # The board normal is turned 20 deg about the vertical away from the robot's starting view direction.
    z_board = rec.T_world_board[:3, 2]
    z_cam = rec.T_base_cam[:3, :3] @ np.array([0.0, 0.0, 1.0])
    ang = np.degrees(np.arctan2(z_board[1], z_board[0]) - np.arctan2(z_cam[1], z_cam[0]))
    assert ang == pytest.approx(20.0, abs=1e-6)


def test_joystick_driving_is_smooth_bounded_and_sometimes_loses_the_board():
    lost = []
    for seed in range(3):
        rec = simulate_robot("rich", duration=30.0, seed=seed)
        st = rec.realism.motion
        tb = rec.truth_base
        assert np.abs(tb.v[:, 0]).max() <= st.v_max_mps + 1e-9
        assert np.abs(tb.omega[:, 2]).max() <= st.omega_max_rad_s + 1e-9
        acc = np.abs(np.diff(tb.v[:, 0])) / np.diff(tb.t)
        assert acc.max() < 2 * st.v_max_mps / st.smoothing_s  # smoothed: no jumps
        flags = rec.board_in_view
        assert flags.shape == rec.cam_t.shape and flags.mean() > 0.6
        lost.append(not flags.all())
    assert any(lost)


def test_truth_yaml_carries_nominal_and_true_values(tmp_path):
    rec = simulate_robot("rich", duration=4.0, seed=1)
    truth = {"T_base_cam": rec.T_base_cam, "td": rec.td, **rec.truth_dict()}
    write_truth(tmp_path / "r.mcap", truth)
    back = read_truth(tmp_path / "r.mcap")
    assert np.allclose(back["T_base_cam"], rec.T_base_cam)
    assert back["wheel_radius_nominal"] == pytest.approx(0.098)
    assert back["wheel_radius_true"] == pytest.approx(0.098 * 1.02)
    assert back["track_width_nominal"] == pytest.approx(0.37)
    assert back["track_width_effective"] == pytest.approx(0.37 * 1.5)
    assert back["board_scale"] == pytest.approx(1.003)
    assert back["realism"]["name"] == "realistic" and back["realism"]["sensor"]["flicker_hz"] == 100.0
    assert 0.0 < back["board_in_view_fraction"] <= 1.0
    yaml.safe_dump(back)  # plain types only


def test_simulate_command_is_realistic_unless_ideal(tmp_path, capsys):
    from plsgraph.cli.main import main

    for flags, name in (([], "realistic"), (["--ideal"], "ideal")):
        out = tmp_path / f"{name}.mcap"
        assert main(["simulate", "--duration", "1.2", "--event-format", "evt3", "--out", str(out), *flags]) == 0
        truth = read_truth(out)
        assert truth["realism"]["name"] == name
        assert {"T_base_cam", "td", "wheel_radius", "track_width", "wheel_radius_nominal", "track_width_effective",
                "board_scale", "board_in_view_fraction"} <= set(truth)
    assert truth["track_width_effective"] == truth["track_width_nominal"] == truth["track_width"]
    capsys.readouterr()


def test_floor_tilts_the_base_by_its_slope_and_lifts_it_by_its_height():
    fx = only("floor")
    fx = dataclasses.replace(fx, scene=dataclasses.replace(fx.scene, floor_slope_deg=0.6, floor_wavelength_m=1.0))
    rec = simulate_robot("rich", duration=15, seed=4, realism=fx)
    flat = simulate_robot("rich", duration=15, seed=4, realism="ideal")
    T, T0 = rec.truth_base.T_world_base, flat.truth_base.T_world_base
    tilt = np.degrees(np.arccos(np.clip(T[:, 2, 2], -1.0, 1.0)))
    assert 0.3 < np.sqrt(np.mean(tilt**2)) < 1.2 and tilt.max() < 3.0
    # Same path and heading seen from above; the wheels (planar odometry) do not change.
    np.testing.assert_allclose(T[:, :2, 3], T0[:, :2, 3], atol=1e-12)
    heading = np.arctan2(T[:, 1, 0], T[:, 0, 0])
    np.testing.assert_allclose(np.unwrap(heading), np.unwrap(np.arctan2(T0[:, 1, 0], T0[:, 0, 0])), atol=0.02)
    np.testing.assert_array_equal(rec.wheel_left, flat.wheel_left)
    # The base's z axis is the floor's normal: moving along the base's x axis follows the floor's height.
    step = np.diff(T[:, :3, 3], axis=0)
    along = np.einsum("ni,ni->n", step, T[:-1, :3, 0])
    climb = np.einsum("ni,ni->n", step, T[:-1, :3, 2])
    moving = np.abs(along) > 1e-4
    assert np.max(np.abs(climb[moving] / along[moving])) < 0.02  # < 1.2 deg from the base's own plane


def test_drawing_the_floor_leaves_every_other_draw_alone():
    a = np.random.default_rng(11)
    fx = draw_realism(a)
    next_a = a.uniform()
    # The same draws without the floor: every field but the floor's, and the caller's next number, agree.
    b = np.random.default_rng(11)
    import plsgraph.sim.realism as R

    values = R._values("ideal")
    R._switch_on(values, [r for r in R.field_specs() if r["effect"] not in R.LATE_EFFECTS], b)
    R._lens_fix(values)
    assert b.uniform() == next_a
    for g in R.GROUPS:
        for name, v in values[g].items():
            if (g, name) not in R.effect_fields("floor"):
                assert getattr(getattr(fx, g), name) == v, (g, name)
    assert 0.0 <= fx.scene.floor_slope_deg <= 1.0
