"""Joint refinement of T_base_cam and td with GTSAM: reprojection + odometry + planar-motion factors.

Graph (see docs/refinement.md):

* variables: base poses ``T_world_base`` at *knots* (odometry samples decimated to
  ``knot_rate_hz``), ``T_base_cam``, ``T_world_board`` and ``td`` (a gtsam 1-vector);
* one reprojection factor per detection frame (factors.reprojection), linking the two knots that
  bracket ``t_cam + td`` with the extrinsic, the board and td;
* odometry between-factors between consecutive knots, their relative motion composed from the
  full-rate odometry and their covariance from the differential-drive model (factors.odometry);
* a planar-motion prior on every knot (factors.planar), an anchor on the first knot (the world frame
  is the odometry origin; without it the whole scene could slide);
* weak regularising priors on T_base_cam and td around the seed, so that directions the motion does
  not excite (camera height under planar motion, always) leave a solvable, honest problem;
* optional user priors: closed-form rotation (weak), camera height, board-on-the-floor.

Decimation: with knots at 10 Hz instead of 50 Hz a 60 s recording has 600 instead of 3000 base
poses. The detail of the odometry between two knots is not lost: each frame's base pose is the knot
interpolation times the full-rate odometry's deviation from the same interpolation of its own knot
poses, evaluated at the frame's current odometry time (so it moves with td), see factors.reprojection.

Seeding: R_base_cam and td from the caller (closed form + correlation); the translation of
T_base_cam and T_world_board by linear least squares from the PnP poses and the odometry given that
rotation (the height, unobservable there too, is kept at the seed's by a ridge term).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import gtsam
import numpy as np

from factors.odometry import (
    EdgeMotions,
    OdometryNoise,
    PlanarSteps,
    make_odometry_factors,
    make_scaled_odometry_factors,
    path_increments,
)
from factors.planar import make_planar_factor
from factors.priors import make_height_prior, make_rotation_prior, make_subspace_prior, make_vertical_board_prior
from factors.reprojection import FrameBatch, OdometryDetail, ReprojectionFrames, make_reprojection_factors

from ..core.camera import CameraModel
from ..core.geometry import PoseInterpolator, inv_T, is_rotation, make_T, project_to_so3, so3_exp, so3_log
from ..core.tracks import BaseTrack, CameraTrack
from ..errors import InputError, InsufficientDataError, PlsgraphError
from .observability import (
    AXES,
    OBSERVABLE_RATIO,
    UNOBSERVABLE_RATIO,
    ObservabilityReport,
    not_converged_report,
    observability_report,
    user_axes_jacobian,
)

log = logging.getLogger(__name__)

KEY_CAM = gtsam.symbol("c", 0)
KEY_BOARD = gtsam.symbol("b", 0)
KEY_TD = gtsam.symbol("t", 0)
KEY_SCALE = gtsam.symbol("s", 0)  # odometry intrinsics (s_v, s_w): arc-length and heading-change factors
# Sigma (in prior sigmas) of the prior that holds unobservable directions at the seed during the solve.
_FREEZE_SIGMA = 1e-3


#: An adapted odometry variance factor at or above this gets a warning in the result.
NOISY_ODOMETRY_FACTOR = 10.0
#: RefinementOptions.max_span_windows leaves the long spans' frames in when they are more than this share of the
#: frames (a recording of a board that is slow in the image nearly throughout: its frames are all it has).
MAX_LONG_SPAN_SHARE = 0.5


def knot_key(k: int) -> int:
    return gtsam.symbol("x", int(k))


@dataclass(frozen=True)
class RefinementOptions:
    """Settings of :func:`refine`. Sigmas in SI units (m, rad, s, px)."""

    knot_rate_hz: float | None = 10.0  # None: one base pose per odometry sample
    sigma_px: float = 0.5
    # Detections found on spans of m windows (slow boards; front end info["span_windows"]) share most of their
    # events with their neighbours; with weight_by_span their pixel sigma is sigma_px * sqrt(m), so m of them weigh
    # as one. Off: on the study it made the rotation worse (median 0.46 -> 0.51 deg, one run 2.1 -> 10.4 deg with
    # an honest 14 deg yaw sigma; docs/refinement.md, "Detections of slow boards").
    weight_by_span: bool = False
    # The front end's detectors whose detections the graph uses (camera_track.info["detector"]: "rims", "blobs",
    # "image"); None: all.
    detectors: tuple[str, ...] | None = None
    # Detections found on spans of more than this many windows (camera_track.info["span_windows"]) are left out of
    # the graph, unless that would leave out more than MAX_LONG_SPAN_SHARE of the frames; None: all. A slow board's
    # circles found as blobs of events over a long span come out further apart than they are when the board looms
    # (the edge moving away from the focus of expansion sweeps more pixels and makes more events), so the board looks
    # nearer in them: on the study they biased the wheel radius low (docs/refinement.md, "Long spans").
    max_span_windows: float | None = 8.0
    # The detectors' own pixel noise: at the noise model's adaptation (adapt_odometry_noise) each detector's frames
    # (camera_track.info["detector"]: blobs, rims) get a pixel variance factor from their residuals, the median of
    # their frames' mean squares relative to all frames' (normalised so that the frames' geometric mean is 1; groups
    # of fewer than DETECTOR_NOISE_MIN_FRAMES frames keep 1). Blob centres by polarity are several times more precise
    # than rim centres (docs/frontend.md); one sigma for both weighs the rims up and the blobs down.
    adapt_detector_noise: bool = False
    robust: str | None = "huber"  # "huber", "cauchy" or None
    robust_k: float = 1.5  # threshold relative to a frame's expected whitened norm (see reprojection_noise)
    min_points: int = 6
    odometry_noise: OdometryNoise = field(default_factory=OdometryNoise)
    # Odometry intrinsics in the graph: the odometry's arc lengths are scaled by s_v (effective / nominal wheel
    # radius) and its heading changes by s_w ((r / b) / (r0 / b0)), with priors around the nominal values (1, 1).
    # A skid-steer robot's effective track is 1.2-2x the geometric one, hence the wide prior on s_w.
    estimate_odometry_scale: bool = True
    speed_scale_prior_sigma: float = 0.05  # relative (wheel radius)
    turn_scale_prior_sigma: float = 1.0  # relative (track width)
    # The odometry edges' translation error divided by the arc-length scale (the noise of the measured odometry,
    # not of the rescaled motion; see make_scaled_odometry_factors). Measured on two studies' tracks: the wheel
    # radius's median bias -0.8 -> -0.6 % and -0.6 -> -0.3 %, its median |error| 1.03 -> 0.83 % and 0.81 -> 0.96 %,
    # the rotation's 95th percentile 2.9 -> 3.2 deg on one: off (docs/refinement.md, "The wheel radius's sigma and
    # its bias").
    odometry_noise_in_measurement: bool = False
    scale_rebuild_tol: float = 1e-3  # rebuild the odometry detail between knots when a scale moved this much
    # Odometry stamps that jitter about a regular clock (the message stamped on arrival, the wheels sampled on a
    # timer) are put back on that clock: jittered stamps bias td and the lever arm (docs/refinement.md).
    regularize_odometry_stamps: bool = True
    # Before the graph, td is searched within seed +- td_search_s by matching how far the camera and the base turn
    # over short intervals (scale-free in the turn rate); a wrong seed td otherwise leaves the graph in a local
    # minimum (docs/refinement.md). 0 disables the search.
    td_search_s: float = 0.6
    td_search_replace_s: float = 0.02  # the search's td replaces the seed only when this far from it
    # When it does, the graph is also solved from the closed form's td and scales, and the answer whose fit both
    # graphs prefer is kept; answers they cannot choose between that disagree beyond their sigmas are flagged.
    td_two_starts: bool = True
    two_starts_decisive: float = 10.0  # difference of the graphs' summed errors that decides between two answers
    planar: bool = True
    planar_sigma_z: float = 0.005
    planar_sigma_tilt: float = 0.005
    anchor_sigma: float = 1e-4
    # The planar prior likewise: a real floor undulates, and its tilt is alike over many consecutive knots. The
    # knots' departures from level (roll and pitch) are measured the same way after the first solve and the prior's
    # tilt variance scaled by them (docs/refinement.md, "Uneven floors"). The height's departures mostly measure the
    # camera's depth noise, not the floor, and loosening them cost accuracy on flat floors: off unless asked for.
    adapt_planar_prior: bool = True
    adapt_planar_height: bool = False
    max_planar_prior_factor: float = 400.0
    anchor_tilt: bool = False  # hold the first knot's roll and pitch too (the floor's plane = its patch of floor)
    # Regularisation (always on, weak): keeps unobservable directions at the seed.
    reg_sigma_rot: float = 0.5
    reg_sigma_trans: float = 1.0
    reg_sigma_td: float = 0.1
    # Added in quadrature to the reported td sigma (not to the estimate): what the model leaves out (pixel latency
    # that depends on intensity and speed, correlated wheel slip, odometry latency) moves td by several ms on
    # realistic recordings. 6 ms was the floor at which the validation study's td errors fell within 3 sigma on 87 %
    # of runs (1 ms: 43 %); at 6 ms their mean z^2 was 2.7 on study_v26, at 8 ms 1.7 with every estimate and verdict
    # the same (docs/validation.md). It comes down when those effects are modelled.
    td_model_sigma: float = 0.008
    # Added in quadrature to the reported arc-length scale's sigma (relative; the effective wheel radius's, and
    # through the scales' covariance the track's): what the model leaves out of the camera's sense of distance. On
    # event detections the board's pattern comes out slightly too large or too small with the board's speed and its
    # growth in the image (docs/refinement.md, "The wheel radius's sigma and its bias"): the radius came out low
    # by 0.6-0.9 % (median) on three 30-run studies, beyond 3 sigma on 2 / 1 / 0 of 28 runs. 0.75 % puts all
    # within 3 sigma with a mean z^2 of 0.8-1.2 ("A model floor on the wheel radius's sigma").
    speed_scale_model_sigma: float = 0.0075
    # Optional user priors.
    rotation_prior_sigma: float | None = None  # prior on R_base_cam at the seed (closed form), rad
    camera_height: float | None = None  # z of the camera in the base frame, m
    camera_height_sigma: float = 0.01
    board_height: float | None = None  # z of the board origin above the world floor plane (base z = 0), m
    board_height_sigma: float = 0.01
    board_vertical: bool = False  # the board stands upright: its normal is horizontal
    board_vertical_sigma: float = 0.01
    # Optimisation.
    optimizer: str = "lm"  # "lm" (own loop on GTSAM's linear algebra), "gtsam-lm" or "dogleg" (GTSAM's optimizers)
    max_iterations: int = 30
    lm_lambda_min: float = 1.0  # initial and smallest Levenberg-Marquardt damping (see _optimize)
    relative_tol: float = 1e-6
    absolute_tol: float = 1e-9
    # Passes (solve, then outlier rejection, re-bracketing at the new td, the noise model's adaptation, the chassis
    # vibration's rounds, freezing) before "did not settle" (a problem: the gate flags it). Two harsh independent
    # recordings (h202, h203) used all of 16 and settled within 17-18; on the three studies no run needs more than 16.
    max_passes: int = 24
    # Processes the refinement may use: with 2, the second opinion on the knots' spacing is solved in a forked process
    # beside the marginals and the jackknife (the same answer; the pipeline passes the front end's worker count).
    workers: int = 1
    # The odometry noise model describes good wheels on a hard floor, with independent errors per edge. Skid-steer
    # robots slip far more, and the slip is correlated over tenths of a second (many edges): a model that trusts
    # such odometry bends the camera's yaw and lever arm to fit it (docs/refinement.md, "Correlated wheel slip").
    # After the first solve the odometry's whitened planar residuals say how much more variance it has (their
    # robust mean square, at least 1, times their autocorrelation time over the edges); the odometry variances are
    # multiplied by that (at most max_odometry_noise_factor) and the graph is solved again, once.
    adapt_odometry_noise: bool = True
    # The adaptation's factor measured and applied separately for the heading terms (which carry the edges' roll and
    # pitch too) and for the distance terms (along and across) of the odometry noise, instead of one factor from all
    # three planar residuals. On two 30-run studies (study_v28's tracks and another seed's) the refined rotation's
    # median fell 0.62 -> 0.47 and 0.47 -> 0.39 deg, "no worse than the closed form" rose 79 -> 82 and 79 -> 86 %,
    # the sigmas stayed honest (docs/refinement.md, "Heading and distance slip weighted apart").
    split_odometry_noise: bool = True
    # The edges' roll and pitch (OdometryNoise.tilt: the floor's shape between knots, not the wheels) are not scaled
    # by the heading's slip factor (scale_odometry_tilt off) but by their own factor, measured from their residuals
    # as the heading's and the distances' are (adapt_odometry_tilt, with split_odometry_noise). Slip weighted the
    # heading down by 14-30x on study_v30's worst runs, and the floor's tilt between knots with it, so roll and pitch
    # leaned on the planar prior's absolute tilt: rotation median 0.47 -> 0.36 deg on study_v30's tracks and 0.39 ->
    # 0.34 deg on another seed's, no worse than the closed form 82 -> 86 % and 86 -> 89 % (docs/refinement.md,
    # "The floor's tilt between knots").
    scale_odometry_tilt: bool = False
    adapt_odometry_tilt: bool = True
    # The change the adaptation (odometry and planar) made to the calibration is a second opinion on the reported
    # sigma per axis (the larger is reported): how much the answer depends on the noise model is an uncertainty the
    # marginals do not hold (the td of a study recording moved by 17 ms against a marginal sigma of 1 ms;
    # docs/refinement.md).
    add_noise_model_sensitivity: bool = True
    # Second opinion on the arc-length scale (the effective wheel radius): a jackknife over this many stretches of
    # the recording of the scale that fits the refined knots' forward motion to the odometry's. Wheel slip
    # correlated over seconds makes the whole recording's slip an error the graph's marginal does not hold: its
    # sigma was exceeded 3x on 11 and 7 % of two studies' runs (docs/refinement.md, "The wheel radius's sigma and
    # its bias").
    # The larger sigma is reported. 0 disables it.
    scale_jackknife_segments: int = 10
    # The same second opinion on the turn scale s_w (the effective track width): the knots' heading changes against
    # the odometry's, per stretch. On recordings from an independent generator with a vibrating base and dim light
    # the track came out 6.3 sigma off with exit 0 (docs/refinement.md, "The track width's sigma").
    turn_scale_jackknife: bool = True
    # The calibration's second opinions carried over to the odometry intrinsics through their correlation with it
    # (odometry_given_calibration).
    propagate_to_odometry: bool = True
    # Second opinion on T_base_cam and td: a linearized jackknife over this many consecutive stretches of camera
    # frames (frame_jackknife: one Gauss-Newton step from the solution without a stretch's reprojection factors,
    # per stretch). Errors shared by a stretch's frames (a slip episode the graph explains with the extrinsic, a
    # stretch of biased detections) spread its leave-one-out answers; the graph's marginal counts every frame as
    # independent. Computed whenever segments >= 2 (RefinementResult.inflation["frame_jackknife_sigma"]); with
    # add_frame_jackknife the larger sigma is reported per axis. 0 disables it. On the third 30-run study (seed 2)
    # (run, axis) pairs within 3 sigma rose 97.6 -> 99.4 % (x 89 -> 96 %, y 96 -> 100 %), mean rotation NEES
    # 0.96 -> 0.88; on the two other studies nothing moved out of 3 sigma and the NEES hardly changed
    # (docs/refinement.md, "A second opinion on the lever arm: the frame jackknife").
    frame_jackknife_segments: int = 10
    add_frame_jackknife: bool = True
    # The calibration's move for a focal length this much (relative) longer than the camera model's, to first order
    # (focal_sensitivity; RefinementResult.inflation["focal_length_sensitivity"]): what the CameraInfo's accuracy is
    # worth in each axis. 0: not computed. The lever arm along the optical axis moves by about the board's distance
    # times the focal length's relative error (a constant depth error of every view looks like a lever arm), 2-3 cm
    # per 1 % (docs/refinement.md, "The focal length in the sigmas").
    focal_sensitivity_rel: float = 0.01
    # The radial distortion (k1, k2) the board views fit (plsgraph.calib.lens, when they disagree with the camera
    # model's): the calibration's first-order move to it is measured as the focal length's is
    # (RefinementResult.inflation["lens_distortion_move"]), and the gate flags a result it would carry beyond its
    # sigmas. None: not measured.
    lens_distortion_views: tuple[float, float] | None = None
    # How well the focal length is known (relative, one sigma): each reported variance gets (move per unit relative
    # focal error x focal_sigma_rel)^2 added, an error source independent of the data's. 0: none.
    focal_sigma_rel: float = 0.0
    # Second opinion on T_base_cam and td: the same refinement (same seed, same frames) with the knots this many
    # times denser; the change it makes is a sensitivity to how the trajectory between knots is modelled, and the
    # larger sigma is reported per axis (RefinementResult.inflation["knot_spacing_sensitivity"]). On recordings from
    # an independent generator (vibrating base, slipping skid-steer wheels, jittered wheel stamps) the answer moved
    # by up to 2 deg of yaw, 35 cm of lever arm and 13 ms of td between 10 and 20 Hz knots, errors the marginals and
    # the jackknife put at 4.4 sigma and 3.1 sigma; on clean recordings it moves by millimetres (docs/refinement.md,
    # "A second opinion on the knots' spacing"). None or <= 1 disables it.
    knot_sensitivity_factor: float | None = 2.0
    max_odometry_noise_factor: float = 400.0
    freeze_unobservable: bool = True  # hold directions the data does not observe at the seed (see refine)
    freeze_ratio: float = OBSERVABLE_RATIO  # posterior/prior sigma above which a direction is held at the seed
    reject_px: float = 3.0  # a frame whose RMS exceeds max(reject_px, reject_factor * median) is dropped
    reject_factor: float = 5.0
    bracket_margin_s: float = 0.3  # knots extend this far beyond the detections (td may move)
    # Moving-average window (s) of the odometry used for the detail between knots. Encoder quantization makes
    # the full-rate odometry jagged; unsmoothed, that texture holds td near its seed (docs/refinement.md).
    odometry_smoothing_s: float = 0.1
    # The smoothing fits a line in time through each window (True) instead of averaging it: where messages were lost,
    # an average moves each pose next to the gap along the path by the speed times its window's mean time offset. The
    # times are the samples' places on the odometry's clock where its stamps only jitter (smoothing_times).
    smooth_in_time: bool = True
    # The base's roll and pitch at a few hertz that the wheels do not report (a vibrating chassis, a bumpy floor):
    # measured once from the frames' residuals at the solution (chassis_tilt_jitter) and, where the camera sees it,
    # given to the odometry edges' roll and pitch (docs/refinement.md, "A vibrating base").
    adapt_chassis_vibration: bool = True
    marginals: bool = True
    scale_covariance: bool = True  # inflate the covariance by chi2/dof when the fit is worse than sigma_px says
    # Second opinion on the covariance: the factors are independent in the model, but detection errors of
    # consecutive windows and wheel slip are correlated in time. The covariance is multiplied by the integrated
    # autocorrelation time of the whitened residuals (reprojection over frames, odometry over edges; the larger),
    # i.e. samples / effective samples (docs/refinement.md, "Honest uncertainty").
    inflate_correlated: bool = True
    # The pixel noise as measured by the fit where it is below sigma_px: the covariance graph's reprojection variance
    # is multiplied by the fit's chi2/dof when that is below 1 (at least pixel_variance_floor; the a-posteriori
    # variance factor; above 1, scale_covariance inflates the whole covariance). The solve keeps sigma_px. On the
    # three 30-run studies the detections' chi2/dof was 0.09-0.59 (median 0.17): sigma_px counted them as 2.4 times
    # noisier than they were, and the rotation's mean NEES was 0.63-0.87 against 3; with the measured variance
    # 1.08-1.52, (run, axis) pairs within 3 sigma 99.0 % (docs/refinement.md, "The pixel noise the fit measures").
    pixel_variance_from_fit: bool = True
    pixel_variance_floor: float = 0.1
    # The floor's tilt (the planar prior's tilt rows, the odometry edges' roll and pitch) counted in the covariance
    # through each knot's gain on the camera's roll and pitch, its errors an AR(1) process in time with the
    # residuals' variance and autocorrelation time (tilt_influence_correction), instead of as a mean over the knots.
    # Off: on the three 30-run studies it brought the rotation's mean NEES from 1.08 / 1.22 / 1.52 to 1.51 / 1.54 /
    # 1.83 with the same (run, axis) pairs within 3 sigma, but on a built 0.6 deg floor (test_refine_honesty's
    # _floor_case) pitch went from 2.8 to 3.2 sigma: a floor is correlated in space, and a path that turns over the
    # same patches again is not an AR(1) process in time (docs/refinement.md, "The floor's tilt through its
    # influence").
    tilt_variance_from_influence: bool = False
    max_inflation: float = 100.0
    # Disagreement with the seed: assumed 1-sigma of the closed form (it gives none), combined with the refinement's.
    seed_sigma_rot: float = np.radians(1.0)
    seed_sigma_td: float = 0.01

    def __post_init__(self) -> None:
        if not (np.isfinite(self.td_model_sigma) and self.td_model_sigma >= 0):
            raise InputError("refinement option td_model_sigma must be >= 0")
        pos = ("sigma_px", "robust_k", "speed_scale_prior_sigma", "turn_scale_prior_sigma",
               "planar_sigma_z", "planar_sigma_tilt", "anchor_sigma", "reg_sigma_rot",
               "reg_sigma_trans", "reg_sigma_td", "camera_height_sigma", "board_height_sigma", "board_vertical_sigma")
        for name in pos:
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"refinement option {name} must be a positive number, got {v}")
        for name in ("td_model_sigma", "speed_scale_model_sigma"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"refinement option {name} must be a number >= 0, got {v}")
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise InputError(f"refinement option workers must be a whole number >= 1, got {self.workers!r}")
        if not (np.isfinite(self.pixel_variance_floor) and 0 < self.pixel_variance_floor <= 1):
            raise InputError("refinement option pixel_variance_floor must be in (0, 1], got "
                             f"{self.pixel_variance_floor}")
        k = self.lens_distortion_views
        if k is not None and (len(k) != 2 or not all(np.isfinite(float(x)) for x in k)):
            raise InputError(f"refinement option lens_distortion_views must be two finite numbers (k1, k2), got {k!r}")
        if self.knot_rate_hz is not None and not self.knot_rate_hz > 0:
            raise InputError("knot_rate_hz must be positive or None (every odometry sample)")
        if self.optimizer not in ("lm", "gtsam-lm", "dogleg"):
            raise InputError(f"optimizer must be 'lm', 'gtsam-lm' or 'dogleg', got {self.optimizer!r}")
        if self.max_iterations < 1 or self.max_passes < 1 or self.min_points < 3:
            raise InputError("max_iterations and max_passes must be >= 1 and min_points >= 3")


@dataclass(frozen=True)
class RefinementResult:
    """Refined calibration with its uncertainty and the bookkeeping of the solve.

    ``cov`` (7, 7): marginal covariance of (T_base_cam tangent in GTSAM order: rotation, translation,
    right perturbation, i.e. camera axes; td). ``cov_base_axes`` (7, 7): the same in base axes (rotation
    about base x/y/z, translation along base x/y/z; td), the axes of the observability report. Both None
    when the solve did not converge or the marginals failed - never a confident covariance on a bad result.
    """

    T_base_cam: np.ndarray
    td: float
    T_world_board: np.ndarray
    knot_t: np.ndarray
    T_world_base: np.ndarray
    converged: bool
    iterations: int
    initial_error: float
    final_error: float
    rms_px_initial: float
    rms_px_final: float
    n_frames: int
    n_frames_rejected: int
    n_frames_dropped: int
    n_points: int
    cov: np.ndarray | None = None
    n_frames_long_span: int = 0  # of n_frames_dropped: found on spans longer than max_span_windows
    cov_base_axes: np.ndarray | None = None
    chi2_per_dof: float = float("nan")
    observability: ObservabilityReport | None = None
    warnings: tuple[str, ...] = ()
    priors: dict = field(default_factory=dict)
    timing: dict = field(default_factory=dict)
    seed_T_base_cam: np.ndarray | None = None
    seed_td: float = float("nan")
    # Odometry intrinsics (see odometry_report): scales, their covariance, effective radius / track and status.
    odometry: dict | None = None
    # Quantity -> |refined - seed| in sigmas of their difference, for quantities where refinement and closed form
    # disagree beyond what both uncertainties allow (see disagreement_with_seed); empty when they agree.
    disagreement: dict = field(default_factory=dict)
    inflation: dict = field(default_factory=dict)  # autocorrelation times and the covariance factor applied
    # The turn-angle search's td when it replaced the closed form's (a wrong correlation peak) and the refinement
    # ended nearer it than the closed form's; None when the closed form's td was kept, or when the refinement came
    # back nearer it (the search's peak was the wrong one). Comparisons of td with "the seed" use this one.
    td_searched: float | None = None
    # (T_base_cam, td) solved under the model's own noise, before the noise model was adapted (None when it was not):
    # what the sensitivity second opinion compares with
    held_solution: tuple | None = None
    # When the refinement was solved from two time offsets (see _two_starts): both starts and ends, which was kept,
    # how the two answers differ in sigmas, and the axes on which they differ while the data hardly prefer either.
    two_starts: dict | None = None
    # The frames solved (camera times, (m,)) and their reprojection residuals at the solution (m, N, 2: predicted -
    # detected, px, NaN where a point was not detected), as the graph has them: the report's residual figure
    residual_t: np.ndarray | None = None
    residual_px: np.ndarray | None = None

    @property
    def R_base_cam(self) -> np.ndarray:
        return self.T_base_cam[:3, :3]

    @property
    def sigma_rot_deg(self) -> np.ndarray | None:
        """1-sigma of the rotation about base x, y, z (deg), or None."""
        return None if self.cov_base_axes is None else np.degrees(np.sqrt(np.diag(self.cov_base_axes)[:3]))

    @property
    def sigma_trans_m(self) -> np.ndarray | None:
        return None if self.cov_base_axes is None else np.sqrt(np.diag(self.cov_base_axes)[3:6])

    @property
    def sigma_td(self) -> float | None:
        return None if self.cov_base_axes is None else float(np.sqrt(self.cov_base_axes[6, 6]))

    def to_dict(self) -> dict:
        def arr(a):
            return None if a is None else np.asarray(a).tolist()

        return {
            "T_base_cam": arr(self.T_base_cam),
            "td": self.td,
            "T_world_board": arr(self.T_world_board),
            "converged": self.converged,
            "iterations": self.iterations,
            "initial_error": self.initial_error,
            "final_error": self.final_error,
            "rms_px_initial": self.rms_px_initial,
            "rms_px_final": self.rms_px_final,
            "n_frames": self.n_frames,
            "n_frames_rejected": self.n_frames_rejected,
            "n_frames_dropped": self.n_frames_dropped,
            "n_frames_long_span": self.n_frames_long_span,
            "n_points": self.n_points,
            "chi2_per_dof": self.chi2_per_dof,
            "cov": arr(self.cov),
            "cov_base_axes": arr(self.cov_base_axes),
            "sigma_rot_deg": arr(self.sigma_rot_deg),
            "sigma_trans_m": arr(self.sigma_trans_m),
            "sigma_td": self.sigma_td,
            "observability": None if self.observability is None else self.observability.to_dict(),
            "warnings": list(self.warnings),
            "priors": dict(self.priors),
            "timing": dict(self.timing),
            "odometry": None if self.odometry is None else dict(self.odometry),
            "disagreement": dict(self.disagreement),
            "inflation": dict(self.inflation),
            "td_searched": self.td_searched,
            "two_starts": None if self.two_starts is None else dict(self.two_starts),
        }


# ---------------------------------------------------------------------------------------------------- set-up
@dataclass(frozen=True)
class _Problem:
    """Everything about a recording that does not change between passes."""

    frames: ReprojectionFrames  # all usable frames; brackets filled per pass
    frame_t: np.ndarray
    knot_idx: np.ndarray  # indices into the odometry samples
    knot_t: np.ndarray
    T_knots_odo: np.ndarray
    base_track: BaseTrack
    odo_t: np.ndarray  # odometry (smoothed) for the detail between knots
    odo_T: np.ndarray
    n_dropped: int
    warnings: tuple[str, ...]
    n_long_span: int = 0  # of n_dropped: frames on spans longer than max_span_windows
    steps: PlanarSteps | None = None  # the nominal odometry's steps (None: intrinsics not estimated)
    scale: tuple[float, float] = (1.0, 1.0)  # (s_v, s_w) the odometry poses above were rescaled with
    frame_sigma: np.ndarray | None = None  # per frame: its pixel sigma in units of sigma_px (None: all 1)
    frame_group: np.ndarray | None = None  # per frame: the front end's detector (camera_track.info["detector"])


def scaled_base_track(base_track: BaseTrack, s_v: float, s_w: float, steps: PlanarSteps | None = None,
                      at: int = 0) -> BaseTrack:
    """The base track with arc lengths scaled by ``s_v`` and heading changes by ``s_w`` (planar), equal to the
    given one at sample ``at``."""
    if s_v == 1.0 and s_w == 1.0:
        return base_track
    steps = steps or PlanarSteps.from_poses(base_track.T_world_base)
    T0 = base_track.T_world_base
    T = steps.poses(T0[0], s_v, s_w)
    T = T0[at] @ inv_T(T[at]) @ T
    return BaseTrack(base_track.t, T, base_track.v * s_v, base_track.omega * s_w, info=dict(base_track.info))


def _check_seed(seed_T_base_cam: np.ndarray, seed_td: float) -> tuple[np.ndarray, float]:
    T = np.asarray(seed_T_base_cam, dtype=float)
    if T.shape == (3, 3):
        T = make_T(T, np.zeros(3))
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError("seed_T_base_cam must be a finite 4 x 4 transform (or a 3 x 3 rotation)")
    if not is_rotation(T[:3, :3], tol=1e-4):
        raise InputError("seed_T_base_cam: the rotation block is not a rotation (orthonormal, det +1)")
    T = make_T(project_to_so3(T[:3, :3]), T[:3, 3])
    td = float(seed_td)
    if not np.isfinite(td):
        raise InputError(f"seed_td must be finite, got {seed_td}")
    return T, td


def _clock_slots(t: np.ndarray, step: float) -> np.ndarray | None:
    """Each stamp's place on the regular clock the stamps follow (integers from 0; a dropped message leaves a place
    out), or None where two stamps fall on one place.

    The clock's period is the one near ``step`` at which the stamps' phases agree best (the peak of
    ``|sum exp(2 pi i t / P)|``, found coarse to fine): dropped messages do not move it and the jitter only blurs it.
    Each stamp then takes the nearest tick of that clock."""
    t = np.asarray(t, dtype=float) - float(t[0])
    span = float(t[-1])
    if not span > 0:
        return None
    centre, width = float(step), 0.02 * float(step)
    for _ in range(4):
        P = centre + np.linspace(-width, width, 81)
        coherence = np.abs(sum(np.exp(2j * np.pi * t[None, i:i + 8192] / P[:, None]).sum(axis=1)
                               for i in range(0, t.size, 8192)))  # in chunks: 81 x 8192 at a time, not 81 x n
        centre = float(P[int(np.argmax(coherence))])
        width /= 20.0
    phase = np.angle(np.exp(2j * np.pi * t / centre).sum()) / (2 * np.pi) * centre
    slot = np.round((t - phase) / centre)
    # Two stamps on one tick: one of them was bunched up against the other (a late stamp holds the next one back, or
    # comes in just before it); it takes the free tick beside it.
    for i in np.flatnonzero(np.diff(slot) <= 0):
        if slot[i + 1] != slot[i]:
            continue
        if i == 0 or slot[i - 1] < slot[i] - 1:
            slot[i] -= 1
        elif i + 2 >= slot.size or slot[i + 2] > slot[i + 1] + 1:
            slot[i + 1] += 1
    slot -= slot[0]
    return slot if np.all(np.diff(slot) > 0) else None


def smoothing_times(t: np.ndarray, quantile: float = 0.95, max_dev: float = 0.45) -> np.ndarray:
    """The times the odometry's smoothing fits its lines over: where the stamps follow a regular clock within jitter,
    each sample's place on that clock (a dropped message leaves its place empty), else the stamps themselves.

    Stamps taken on arrival are late by a varying delay while the wheels were sampled on a steady clock: a line
    fitted over such stamps would carry their jitter into the poses, an average over the samples would treat a
    dropped message's double step as one. Per stretch between gaps (as regular_stamps), the clock's places are read
    off the stamps (_clock_slots) and taken when ``quantile`` of the stamps lie within ``max_dev`` of a step of them."""
    t = np.asarray(t, dtype=float)
    if t.size < 10:
        return t
    dt = np.diff(t)
    med = float(np.median(dt))
    if not med > 0:
        return t
    cuts = np.r_[0, np.flatnonzero(dt > 2.5 * med) + 1, t.size]
    out = t.copy()
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        if b - a < 10:
            continue
        slot = _clock_slots(t[a:b], med)
        if slot is None:
            continue
        A = np.stack([slot, np.ones_like(slot)], axis=1)
        c = np.linalg.lstsq(A, t[a:b], rcond=None)[0]
        fit = A @ c
        if c[0] > 0 and np.quantile(np.abs(t[a:b] - fit), quantile) < max_dev * c[0]:
            out[a:b] = fit
    return out if np.all(np.diff(out) > 0) else t


def regular_stamps(t: np.ndarray, gap_factor: float = 2.5, max_dev: float = 0.45) -> tuple[np.ndarray, float]:
    """Stamps of a regularly sampled stream with their jitter removed, and the jitter's std (s).

    Per stretch between gaps (steps longer than ``gap_factor`` median steps) the stamps are fitted by a straight
    line over the sample index (a regular clock, its rate free); the stretch keeps its stamps unless every
    deviation from the line is below ``max_dev`` of a step (jitter, not irregular sampling). Where the index does not
    fit, the line is fitted over the samples' places on the clock (:func:`_clock_slots`): a message that was dropped,
    or merged into the next (wheel messages stamped in bursts), leaves its place empty, and counted by the index it
    put every later stamp a step off the line, so that a whole stretch kept its jitter. The result stays strictly
    increasing. Returns the original stamps when nothing qualifies.
    """
    t = np.asarray(t, dtype=float)
    if t.size < 10:
        return t, 0.0
    dt = np.diff(t)
    med = float(np.median(dt))
    cuts = np.r_[0, np.flatnonzero(dt > gap_factor * med) + 1, t.size]
    out = t.copy()
    dev = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        if b - a < 10:
            continue
        i = np.arange(b - a, dtype=float)
        A = np.stack([i, np.ones_like(i)], axis=1)
        c = np.linalg.lstsq(A, t[a:b], rcond=None)[0]
        fit = A @ c
        r = t[a:b] - fit
        if not (np.max(np.abs(r)) < max_dev * c[0] and c[0] > 0):
            slot = _clock_slots(t[a:b], med)
            if slot is None or slot[-1] == b - a - 1:  # no place left empty: the index was the clock's places
                continue
            A = np.stack([slot, np.ones_like(slot)], axis=1)
            c = np.linalg.lstsq(A, t[a:b], rcond=None)[0]
            fit = A @ c
            r = t[a:b] - fit
        if np.max(np.abs(r)) < max_dev * c[0] and c[0] > 0:
            out[a:b] = fit
            dev.append(r)
    if not dev or np.any(np.diff(out) <= 0):
        return t, 0.0
    return out, float(np.std(np.concatenate(dev)))


def turn_angle_td_search(camera_track: CameraTrack, base_track: BaseTrack, td0: float, half: float,
                         interval_s: float = 0.25, step: float = 0.005
                         ) -> tuple[float, float, float, float] | None:
    """td (s) within ``td0 +- half`` at which the camera's and the base's turn angles over ``interval_s`` agree
    best, the turn-rate scale s_w that matches them, the (robust) cost there and the cost at ``td0``; None when
    the recording has too little turning or the best td lies at the border of the range.

    The angle the camera turns between two of its poses equals the angle the base turns (a rigid mount, planar
    motion), whatever R_base_cam; the odometry's angle is off by the turn scale s_w, which is fitted per
    candidate (least squares), so the search depends neither on the rotation seed nor on the track width.
    """
    t = camera_track.t
    R = camera_track.T_board_cam[:, :3, :3]
    j = np.searchsorted(t, t + interval_s)
    ok = j < t.size
    i = np.flatnonzero(ok)
    j = j[ok]
    ok = np.abs(t[j] - t[i] - interval_s) < 0.2 * interval_s
    i, j = i[ok], j[ok]
    tb = base_track.t
    ok = (t[i] + td0 - half >= tb[0]) & (t[j] + td0 + half <= tb[-1])
    i, j = i[ok], j[ok]
    if i.size < 20:
        return None
    w_ij = so3_log(np.einsum("nji,njk->nik", R[i], R[j]))  # camera rotations over the intervals (camera axes)
    # Planar motion: every one of them turns about the same axis, the vertical in camera axes - the dominant
    # direction of the rotation vectors, found without td or R_base_cam. The signed angle about it is far less
    # noisy than the magnitude (PnP's out-of-plane rotation noise of a small board is large).
    axis = np.linalg.svd(w_ij, full_matrices=False)[2][0]
    a = w_ij @ axis
    Tb = base_track.T_world_base
    th = np.unwrap(np.arctan2(Tb[:, 1, 0], Tb[:, 0, 0]))
    if np.sqrt(np.mean(a**2)) < 0.02:  # hardly any turning: td is not seen this way
        return None
    db0 = np.interp(t[j] + td0, tb, th) - np.interp(t[i] + td0, tb, th)
    if a @ db0 < 0:
        a = -a
    k_rad = 0.01  # Huber threshold (rad): about the turn-angle error of two poses plus odometry slip

    def cost(td: float) -> tuple[float, float]:
        b = np.interp(t[j] + td, tb, th) - np.interp(t[i] + td, tb, th)
        # Robust (Huber, IRLS) fit of the turn scale: pairs across a bad pose (a flipped PnP solution) or a slip
        # must not decide; the cost is in units of a fixed angle so that all candidates compare alike.
        w = np.ones_like(a)
        for _ in range(4):
            s = float((w * a) @ b / max((w * b) @ b, 1e-12))
            r = a - s * b
            w = np.minimum(1.0, k_rad / np.maximum(np.abs(r), 1e-12))
        rho = np.where(np.abs(r) <= k_rad, r**2, 2 * k_rad * np.abs(r) - k_rad**2)
        return float(np.mean(rho)), s

    grid = td0 + np.arange(-half, half + 0.5 * step, step)
    c = np.array([cost(float(x))[0] for x in grid])
    k = int(np.argmin(c))
    if k == 0 or k == grid.size - 1:
        return None
    fine = grid[k] + np.arange(-step, step + 1e-9, step / 10)
    cf = np.array([cost(float(x))[0] for x in fine])
    m = int(np.argmin(cf))
    td = float(fine[m])
    if 0 < m < fine.size - 1:
        y0, y1, y2 = cf[m - 1 : m + 2]
        den = y0 - 2 * y1 + y2
        if den > 0:
            td += 0.5 * (step / 10) * (y0 - y2) / den
    val, s_w = cost(td)
    return td, s_w, val, float(c[int(round(half / step))])


def _select_knots(base_track: BaseTrack, t_lo: float, t_hi: float, rate: float | None,
                  also: np.ndarray | None = None) -> np.ndarray:
    """Odometry sample indices of the knots: every sample (``rate`` None) or about ``rate`` per second, plus the
    samples ``also`` (the ends of bridged gaps, so that one edge spans exactly each gap) inside the span."""
    t = base_track.t
    i0 = int(max(0, np.searchsorted(t, t_lo, "right") - 1))
    i1 = int(min(t.size - 1, np.searchsorted(t, t_hi, "left")))
    if rate is None:
        return np.arange(i0, i1 + 1)
    dt = float(np.median(np.diff(t)))
    step = max(1, int(round(1.0 / (rate * dt))))
    idx = np.arange(i0, i1 + 1, step)
    if idx[-1] != i1:
        idx = np.r_[idx, i1]
    if also is not None and np.size(also):
        a = np.asarray(also, dtype=int).ravel()
        idx = np.unique(np.r_[idx, a[(a >= i0) & (a <= i1)]])
    return idx


#: Extra uncertainty of an odometry edge across a bridged gap (plsgraph.gaps): the net motion is known, the path
#: is not, so the edge's position is loose (a floor plus a share of the distance driven in the gap); its heading
#: (cumulative wheel angles) gets a small floor.
BRIDGE_POSITION_FLOOR_M = 0.02
BRIDGE_POSITION_PER_M = 0.2
BRIDGE_HEADING_RAD = 0.005


def _bridged(base_track: BaseTrack) -> np.ndarray:
    from ..gaps import bridged_gaps

    return bridged_gaps(base_track)


def _gap_steps(base_track: BaseTrack) -> tuple[np.ndarray, np.ndarray]:
    """Samples (ia, ib) that open and close each bridged gap, found within half a step of its times (the refinement
    may have put the stamps on a regular clock, which moves them by up to 0.45 of a step)."""
    g = _bridged(base_track)
    t = base_track.t
    if not g.size or t.size < 2:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    h = 0.5 * float(np.median(np.diff(t)))
    ia = np.clip(np.searchsorted(t, g[:, 0] + h, "right") - 1, 0, t.size - 1)
    ib = np.clip(np.searchsorted(t, g[:, 1] - h, "left"), 0, t.size - 1)
    return ia, ib


def _bridged_gap_samples(base_track: BaseTrack) -> np.ndarray:
    """Indices of the odometry samples that open and close each bridged gap."""
    ia, ib = _gap_steps(base_track)
    return np.unique(np.r_[ia, ib]).astype(int)


def _near_bridged_gap(base_track: BaseTrack, tau: np.ndarray, opt: RefinementOptions) -> np.ndarray:
    """Frames (odometry times ``tau``) whose pose would take the odometry's path across a bridged gap: inside one,
    or near enough that the smoothed detail between knots or a td that moves in the solve reaches into it."""
    g = _bridged(base_track)
    out = np.zeros(np.shape(tau), dtype=bool)
    margin = 0.1 + 0.5 * opt.odometry_smoothing_s
    for a, b in g:
        out |= (tau > a - margin) & (tau < b + margin)
    return out


def _bridge_covariance(prob: _Problem) -> np.ndarray | None:
    """Extra covariance (edges, 6, 6) of the odometry edges across bridged gaps; None when there are none."""
    g = _bridged(prob.base_track)
    if not g.size:
        return None
    kt = prob.knot_t
    ki = np.asarray(prob.knot_idx)
    T = prob.base_track.T_world_base
    extra = np.zeros((kt.size - 1, 6, 6))
    for ia, ib in zip(*_gap_steps(prob.base_track), strict=True):
        i = int(np.searchsorted(ki, ia, "right") - 1)
        if i < 0 or i >= ki.size - 1 or ki[i + 1] < ib:
            continue  # outside the knots' span
        d = float(np.linalg.norm(T[ib, :2, 3] - T[ia, :2, 3]))
        sp = BRIDGE_POSITION_FLOOR_M + BRIDGE_POSITION_PER_M * d
        extra[i, 3, 3] += sp**2
        extra[i, 4, 4] += sp**2
        extra[i, 2, 2] += BRIDGE_HEADING_RAD**2
    return extra


def _rescaled(prob: _Problem, scale: tuple[float, float], opt: RefinementOptions) -> _Problem:
    """The problem with its odometry poses (knots' odometry, detail between knots) rebuilt for ``scale``."""
    import dataclasses

    k0 = int(prob.knot_idx[0])
    track = scaled_base_track(prob.base_track, scale[0], scale[1], prob.steps, at=k0)
    dt = float(np.median(np.diff(prob.odo_t)))
    half = int(round(0.5 * opt.odometry_smoothing_s / dt)) if opt.odometry_smoothing_s > 0 else 0
    return dataclasses.replace(prob, T_knots_odo=track.T_world_base[prob.knot_idx],
                               odo_T=smooth_poses(track.T_world_base, half,
                                                  smoothing_times(track.t) if opt.smooth_in_time else None),
                               scale=(float(scale[0]), float(scale[1])))


def _prepare(
    camera_track: CameraTrack, base_track: BaseTrack, camera: CameraModel, seed_td: float, opt: RefinementOptions,
    scale: tuple[float, float] = (1.0, 1.0), knot_tds: tuple[float, float] | None = None,
) -> _Problem:
    det = camera_track.detections
    if det is None or len(det) == 0:
        raise InputError(
            "refine needs the pixel detections: camera_track.detections is empty "
            "(build the camera track with plsgraph.frontend.pose.camera_track_from_detections)"
        )
    if len(base_track) < 2:
        raise InsufficientDataError("refine: the base track has fewer than 2 odometry samples")
    warnings: list[str] = []
    if opt.regularize_odometry_stamps:
        t_reg, jitter = regular_stamps(base_track.t)
        if jitter > 0:
            log.info("odometry stamps put on a regular clock (jitter %.2f ms)", 1e3 * jitter)
            base_track = BaseTrack(t_reg, base_track.T_world_base, base_track.v, base_track.omega,
                                   info=dict(base_track.info, stamp_jitter_s=jitter))
    n_valid = np.all(np.isfinite(det.uv), axis=-1).sum(axis=1)
    tau = det.t + seed_td
    t_odo = base_track.t
    inside = (tau >= t_odo[0]) & (tau <= t_odo[-1])
    keep = (n_valid >= opt.min_points) & inside
    src = camera_track.info.get("detector")
    if opt.detectors is not None and src is not None and len(src) == len(det):
        keep &= np.isin(np.asarray(src, dtype=str), list(opt.detectors))
    for key in ("detector", "span_windows"):
        if key in camera_track.info and len(camera_track.info[key]) != len(det):
            log.warning("refine: the front end's %s list (%d) does not match the %d detections; not used", key,
                        len(camera_track.info[key]), len(det))
    spans_all = camera_track.info.get("span_windows")
    n_long = 0
    if opt.max_span_windows is not None and spans_all is not None and len(spans_all) == len(det):
        long_span = np.asarray(spans_all, dtype=float) > opt.max_span_windows
        usable = n_valid >= opt.min_points  # the share is decided on frames that do not depend on the seed's td
        if np.count_nonzero(long_span & usable) <= MAX_LONG_SPAN_SHARE * np.count_nonzero(usable):
            n_long = int(np.count_nonzero(long_span & keep))
            keep &= ~long_span
        elif np.any(long_span & keep):
            log.info("refine: %d of %d frames were found on spans longer than %g windows; too many to leave out, "
                     "kept", int(np.count_nonzero(long_span & usable)), int(np.count_nonzero(usable)),
                     opt.max_span_windows)
    try:
        from ..odometry.wheels import in_gap

        gap = in_gap(base_track, tau)
        if np.any(gap & keep):
            warnings.append(f"{int(np.sum(gap & keep))} frame(s) fall into odometry gaps or jumps and were dropped")
        keep &= ~gap
        near = _near_bridged_gap(base_track, tau, opt)
        if np.any(near & keep):
            log.info("refine: %d frame(s) near bridged odometry gaps dropped", int(np.sum(near & keep)))
        keep &= ~near
    except ImportError:  # odometry helpers are optional for this module
        pass
    if np.sum(~inside):
        warnings.append(f"{int(np.sum(~inside))} frame(s) lie outside the odometry time span (after td); dropped")
    if np.sum(n_valid < opt.min_points):
        warnings.append(f"{int(np.sum(n_valid < opt.min_points))} frame(s) have fewer than {opt.min_points} points")
    if keep.sum() < 3:
        raise InsufficientDataError(
            f"refine: only {int(keep.sum())} detection frame(s) overlap the odometry with >= {opt.min_points} "
            "points; check td, the recording's topics and the board detections"
        )
    t = det.t[keep]
    frame_sigma = None
    spans = camera_track.info.get("span_windows") if opt.weight_by_span else None
    if spans is not None and len(spans) == len(det):
        frame_sigma = np.sqrt(np.maximum(1.0, np.asarray(spans, dtype=float)))[keep]
    if knot_tds is None:
        lo, hi = t[0] + seed_td, t[-1] + seed_td
    else:  # knots independent of seed_td: over every frame with points, shifted by any td in the range
        t_all = det.t[n_valid >= opt.min_points]
        lo, hi = t_all[0] + knot_tds[0], t_all[-1] + knot_tds[1]
    knot_idx = _select_knots(base_track, lo - opt.bracket_margin_s, hi + opt.bracket_margin_s, opt.knot_rate_hz,
                             _bridged_gap_samples(base_track))
    if knot_idx.size < 2:
        raise InsufficientDataError("refine: the detections span less than one odometry step")
    frames = ReprojectionFrames(t, np.zeros(t.size), np.ones(t.size), det.uv[keep], det.board_points, camera)
    dt = float(np.median(np.diff(t_odo)))
    half = int(round(0.5 * opt.odometry_smoothing_s / dt)) if opt.odometry_smoothing_s > 0 else 0
    prob = _Problem(
        frames=frames,
        frame_t=t,
        knot_idx=knot_idx,
        knot_t=t_odo[knot_idx],
        T_knots_odo=base_track.T_world_base[knot_idx],
        base_track=base_track,
        odo_t=t_odo,
        odo_T=smooth_poses(base_track.T_world_base, half, smoothing_times(t_odo) if opt.smooth_in_time else None),
        n_dropped=int((~keep).sum()),
        n_long_span=n_long,
        warnings=tuple(warnings),
        steps=PlanarSteps.from_poses(base_track.T_world_base) if opt.estimate_odometry_scale else None,
        frame_sigma=frame_sigma,
        frame_group=np.asarray(src, dtype=str)[keep] if src is not None and len(src) == len(det) else None,
    )
    if opt.estimate_odometry_scale and tuple(scale) != (1.0, 1.0):
        prob = _rescaled(prob, scale, opt)
    return prob


def smooth_poses(T: np.ndarray, half: int, t: np.ndarray | None = None) -> np.ndarray:
    """Poses smoothed over 2 * half + 1 samples: positions, and rotations in the tangent space of each sample
    (R_i Exp(c_i) with c_i from Log(R_i^T R_j)).

    Without ``t`` a moving average. With the sample times ``t``, a straight line fitted in time through the
    window and taken at the sample's own time: where the stamps are uneven (jitter, a dropped message) a plain
    average stands for the window's mean time, not the sample's, and moves the pose along the path by the speed
    times that difference (a heading error of the turn rate times a few milliseconds); the line does not. On
    even stamps both are the same.

    The window stays centred: within ``half`` samples of an end it shrinks to the samples available on both
    sides (the end samples are kept as they are). Repeating the end sample instead would weight the past (or
    the future) more and so shift the smoothed poses in time there, and frames near the ends of the odometry
    would pull td by milliseconds.
    """
    T = np.asarray(T, dtype=float)
    if half < 1 or len(T) < 3:
        return T
    n = len(T)
    i = np.arange(n)
    off = np.arange(-half, half + 1)
    reach = np.minimum(half, np.minimum(i, n - 1 - i))  # (n,) half-width of each sample's centred window
    w = (np.abs(off)[None, :] <= reach[:, None]).astype(float)
    idx = np.clip(i[:, None] + off[None, :], 0, n - 1)  # clipped entries have weight 0
    if t is not None:
        # weights of the value at t_i of a least-squares line through the window: w_j (S2 - S1 dt_j) / (S0 S2 - S1^2)
        dt = np.asarray(t, dtype=float)[idx] - np.asarray(t, dtype=float)[:, None]
        s0, s1, s2 = w.sum(1), (w * dt).sum(1), (w * dt * dt).sum(1)
        det = s0 * s2 - s1 * s1
        ok = det > 1e-12 * np.maximum(s0 * s2, 1e-300)
        lin = w * (s2[:, None] - s1[:, None] * dt) / np.where(ok, det, 1.0)[:, None]
        w = np.where(ok[:, None], lin, w / s0[:, None])
    else:
        w /= w.sum(axis=1, keepdims=True)  # (n, w)
    R = T[:, :3, :3]
    rel = np.einsum("nji,nwjk->nwik", R, R[idx])  # R_i^T R_j
    w_mean = np.einsum("nwk,nw->nk", so3_log(rel.reshape(-1, 3, 3)).reshape(n, -1, 3), w)
    return make_T(R @ so3_exp(w_mean), np.einsum("nwk,nw->nk", T[:, :3, 3][idx], w))


def _brackets(prob: _Problem, td: float, rows: np.ndarray) -> tuple[ReprojectionFrames, np.ndarray]:
    """Frames ``rows`` with their bracketing knots at ``td`` and the full-rate odometry for the detail between knots."""
    t = prob.frame_t[rows]
    tau = np.clip(t + td, prob.knot_t[0], prob.knot_t[-1])
    a = np.clip(np.searchsorted(prob.knot_t, tau, "right") - 1, 0, prob.knot_t.size - 2)
    b = a + 1
    odo = OdometryDetail(prob.odo_t, prob.odo_T, prob.odo_T[prob.knot_idx[a]], prob.odo_T[prob.knot_idx[b]])
    f = prob.frames
    frames = ReprojectionFrames(t, prob.knot_t[a], prob.knot_t[b], f.uv[rows], f.board_points, f.camera, odo)
    return frames, np.stack([a, b], axis=1)


def _chordal_mean(R: np.ndarray) -> np.ndarray:
    return project_to_so3(np.sum(R, axis=0))


def seed_translation_and_board(
    camera_track: CameraTrack,
    base_track: BaseTrack,
    R_base_cam: np.ndarray,
    td: float,
    t_prior: np.ndarray | None = None,
    prior_weight: float = 1e-3,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera translation in the base frame and T_world_board from PnP poses and odometry, given R_base_cam.

    Every frame says ``X_i C T_cam_board_i = B``. With the rotation of C fixed the translation part is
    linear in (t_C, t_B): ``R_Xi t_C - t_B = -(p_Xi + R_Xi R_C t_cb_i)``. A ridge term (weight
    ``prior_weight`` relative to all frames together) keeps directions the motion does not determine
    (the height under planar motion, everything when driving straight) at ``t_prior``. Frames whose
    residual is far above the median are dropped once.
    Returns (t_base_cam (3,), T_world_board (4, 4)).
    """
    t = camera_track.t + td
    ok = (t >= base_track.t[0]) & (t <= base_track.t[-1])
    if ok.sum() < 2:
        raise InsufficientDataError("seeding: fewer than 2 camera poses overlap the odometry; check td")
    X = base_track.poses_at(t[ok])
    T_cb = inv_T(camera_track.T_board_cam[ok])
    RX, pX = X[:, :3, :3], X[:, :3, 3]
    R_B = _chordal_mean(RX @ R_base_cam @ T_cb[:, :3, :3])
    rhs = -(pX + np.einsum("nij,nj->ni", RX @ R_base_cam, T_cb[:, :3, 3]))  # (n, 3)
    n = rhs.shape[0]
    t0 = np.zeros(3) if t_prior is None else np.asarray(t_prior, dtype=float)
    use = np.ones(n, dtype=bool)
    for _ in range(2):
        A = np.zeros((3 * int(use.sum()) + 3, 6))
        A[:-3, :3] = RX[use].reshape(-1, 3)
        A[:-3, 3:] = np.tile(-np.eye(3), (int(use.sum()), 1))
        w = np.sqrt(prior_weight * use.sum())
        A[-3:, :3] = w * np.eye(3)
        y = np.r_[rhs[use].ravel(), w * t0]
        sol = np.linalg.lstsq(A, y, rcond=None)[0]
        res = np.linalg.norm((np.einsum("nij,j->ni", RX, sol[:3]) - sol[3:]) - rhs, axis=1)
        med = np.median(res[use])
        new = res <= max(5.0 * med, 1e-3)
        if np.array_equal(new, use):
            break
        use = new
    return sol[:3], make_T(R_B, sol[3:])


# ---------------------------------------------------------------------------------------------------- graph
def _add_priors(graph: gtsam.NonlinearFactorGraph, C0: np.ndarray, td0: float, opt: RefinementOptions,
                R_prior: np.ndarray) -> None:
    reg = np.r_[np.full(3, opt.reg_sigma_rot), np.full(3, opt.reg_sigma_trans)]
    graph.add(gtsam.PriorFactorPose3(KEY_CAM, gtsam.Pose3(C0), gtsam.noiseModel.Diagonal.Sigmas(reg)))
    graph.add(gtsam.PriorFactorVector(KEY_TD, np.array([td0]), gtsam.noiseModel.Isotropic.Sigma(1, opt.reg_sigma_td)))
    if opt.rotation_prior_sigma is not None:
        graph.add(make_rotation_prior(KEY_CAM, R_prior, opt.rotation_prior_sigma))
    if opt.camera_height is not None:
        graph.add(make_height_prior(KEY_CAM, opt.camera_height, opt.camera_height_sigma))
    if opt.board_height is not None:
        graph.add(make_height_prior(KEY_BOARD, opt.board_height, opt.board_height_sigma))
    if opt.board_vertical:
        graph.add(make_vertical_board_prior(KEY_BOARD, opt.board_vertical_sigma))


# The base's roll and pitch between knots (chassis_tilt_jitter) are taken into the odometry edges when their excess
# over the pixel noise is this many of its standard errors and at least this large (rad, about 0.03 deg).
VIBRATION_Z = 5.0
VIBRATION_MIN_RAD = 5e-4
VIBRATION_ROUNDS = 3
VIBRATION_MAX_RAD = np.radians(1.0)

_HEADING_NOISE = ("yaw_per_radian", "yaw_per_metre", "floor_rad")


def _scaled_noise(noise: OdometryNoise, var_factor: float | tuple[float, ...], keep_tilt: bool = False
                  ) -> OdometryNoise:
    """``noise`` with its variances multiplied by ``var_factor``, or by (heading, distance[, tilt]) factors: the
    heading's terms by the first, the distance terms by the second. The edges' roll and pitch (``noise.tilt``) are
    scaled by the heading's factor, or with ``keep_tilt`` only by the third factor when there is one."""
    import dataclasses

    fh, fd, *ft = (var_factor, var_factor) if np.isscalar(var_factor) else var_factor
    scaled = {f.name: getattr(noise, f.name) * float(np.sqrt(fh if f.name in _HEADING_NOISE else fd))
              for f in dataclasses.fields(noise) if f.name != "tilt"}
    tilt = noise.tilt
    if not keep_tilt:  # the tilt scaled along with the heading (as when the tilt took the heading's terms)
        tilt = None if tilt is None else tuple(v * float(np.sqrt(fh)) for v in tilt)
    else:
        tilt = tilt if tilt is not None else (noise.yaw_per_radian, noise.yaw_per_metre, noise.floor_rad)
        if ft:  # the floor's tilt measured on its own
            tilt = tuple(v * float(np.sqrt(ft[0])) for v in tilt)
    return dataclasses.replace(noise, **scaled, tilt=tilt)


def _with_vibration(noise: OdometryNoise, vib_var: float) -> OdometryNoise:
    """``noise`` with the roll and pitch of each edge widened by the difference of two knots' chassis tilts."""
    import dataclasses

    tilt = noise.tilt if noise.tilt is not None else (noise.yaw_per_radian, noise.yaw_per_metre, noise.floor_rad)
    return dataclasses.replace(noise, tilt=(tilt[0], tilt[1], float(np.sqrt(tilt[2] ** 2 + 2.0 * vib_var))))


def chassis_tilt_jitter(batch: FrameBatch, values: gtsam.Values, eps: float = 1e-4) -> dict:
    """How much the camera sees the base roll and pitch between what the knots follow: per frame, the small tilt of
    the base (about its x and y axes, at its origin) that best explains that frame's residuals, against what the
    pixel noise alone would give it.

    Returns ``{"var": (roll, pitch) excess variances (rad^2, >= 0), "z": (roll, pitch) their significance,
    "sigma_px": the pixel noise measured with the tilt taken out}``. Without vibration the per-frame tilts are as
    scattered as the pixel noise makes them and the excess is zero within its spread."""
    from factors.reprojection import evaluate_frames

    knots, C, B, td = batch._read_all(values)
    ki = batch.knot_index

    def residual(kn: np.ndarray) -> np.ndarray:
        return evaluate_frames(batch.frames, kn[ki[:, 0]], kn[ki[:, 1]], C, B, td, False).residual

    r0 = residual(knots)
    ok = np.isfinite(r0[..., 0]) & np.isfinite(r0[..., 1])
    J = np.zeros(r0.shape + (2,))
    for axis in (0, 1):
        E = np.eye(4)
        E[:3, :3] = so3_exp(eps * np.eye(3)[axis])
        J[..., axis] = (residual(knots @ E) - r0) / eps
    r = np.where(ok[..., None], r0, 0.0).reshape(len(r0), -1)
    A = np.where(ok[..., None, None], J, 0.0).reshape(len(r0), -1, 2)
    AtA = np.einsum("mki,mkj->mij", A, A)
    n_pts = ok.sum(axis=1)
    use = (n_pts >= 6) & (np.linalg.det(AtA) > 0)
    out = {"var": (0.0, 0.0), "z": (0.0, 0.0), "sigma_px": float("nan"), "frames": int(use.sum())}
    if use.sum() < 20:
        return out
    A, r, AtA, n_pts = A[use], r[use], AtA[use], n_pts[use]
    inv = np.linalg.inv(AtA)
    delta = -np.einsum("mij,mkj,mk->mi", inv, A, r)  # per-frame tilt (rad) that best explains the residuals
    left = r + np.einsum("mki,mi->mk", A, delta)
    dof = float(np.sum(2 * n_pts) - 2 * len(r))
    s2 = float(np.sum(left**2)) / max(dof, 1.0)  # pixel noise with the tilts taken out
    expected = s2 * np.stack([inv[:, 0, 0], inv[:, 1, 1]], axis=1)
    d2 = delta**2
    excess = d2.mean(axis=0) - expected.mean(axis=0)
    spread = np.sqrt(np.var(d2 - expected, axis=0) / len(d2))
    z = excess / np.maximum(spread, 1e-300)
    out.update(var=tuple(float(v) for v in np.maximum(excess, 0.0)), z=tuple(float(v) for v in z),
               sigma_px=float(np.sqrt(s2)))
    return out


def _largest(var_factor: float | tuple[float, ...]) -> float:
    """The largest of the odometry's variance factors (heading, distance; the floor's tilt, if adapted, too)."""
    return float(np.max(var_factor))


def _covariance_odometry_factor(odo_var: float | tuple[float, ...], tau: float) -> float | tuple[float, ...]:
    """The odometry variance factor of the covariance's graph: the adapted one when the wheels' factor was raised
    (it holds their correlation), else the residuals' autocorrelation time ``tau`` for the wheels' terms and for the
    edges' tilt unless its own factor was measured."""
    if _slip(odo_var) > 1.0:
        return odo_var
    return (tau, tau, odo_var[2] if isinstance(odo_var, tuple) and len(odo_var) > 2 else tau)


def _slip(var_factor: float | tuple[float, ...]) -> float:
    """The larger of the wheels' variance factors (heading, distance): the slip, without the floor's tilt."""
    return float(np.max(np.ravel(var_factor)[:2]))


def _pixel_sigma(prob: _Problem, rows: np.ndarray, opt: RefinementOptions) -> float | np.ndarray:
    """Pixel sigma of the frames ``rows`` (one value when all frames share it)."""
    if prob.frame_sigma is None:
        return opt.sigma_px
    return opt.sigma_px * prob.frame_sigma[rows]


def _build_graph(prob: _Problem, rows: np.ndarray, td_bracket: float, opt: RefinementOptions,
                 C_prior: np.ndarray, td_prior: float, R_prior: np.ndarray, rep_var: float = 1.0,
                 odo_var: float | tuple[float, float] = 1.0, planar_var: tuple[float, float] = (1.0, 1.0),
                 vib_var: float = 0.0):
    """The factor graph; ``rep_var`` / ``odo_var`` multiply the variances of the reprojection / odometry factors
    (used for the covariance under correlated errors, see correlation_inflation); ``vib_var`` (rad^2) is the variance
    of each knot's roll and pitch about the floor's (a vibrating chassis): an edge's roll and pitch get twice it."""
    frames, kidx = _brackets(prob, td_bracket, rows)
    keys = np.array([knot_key(k) for k in range(prob.knot_t.size)], dtype=np.int64)
    batch = FrameBatch(frames, keys, kidx, KEY_CAM, KEY_BOARD, KEY_TD)
    graph = gtsam.NonlinearFactorGraph()
    for f in make_reprojection_factors(batch, _pixel_sigma(prob, rows, opt) * np.sqrt(rep_var), opt.robust,
                                       opt.robust_k):
        graph.add(f)
    noise = opt.odometry_noise if np.all(np.asarray(odo_var) == 1.0) else \
        _scaled_noise(opt.odometry_noise, odo_var, keep_tilt=not opt.scale_odometry_tilt)
    if vib_var > 0:
        noise = _with_vibration(noise, vib_var)
    d, a = path_increments(prob.base_track.t, prob.base_track.T_world_base, prob.knot_idx)
    extra = _bridge_covariance(prob)  # not scaled by the adapted odometry variance: it is not the wheels' noise
    if prob.steps is not None:
        for f in make_scaled_odometry_factors(keys, KEY_SCALE, prob.steps, prob.knot_idx, d, a, noise,
                                              noise_scale=1.0 if opt.odometry_noise_in_measurement else None,
                                              extra_cov=extra):
            graph.add(f)
        sig = np.array([opt.speed_scale_prior_sigma, opt.turn_scale_prior_sigma])
        graph.add(gtsam.PriorFactorVector(KEY_SCALE, np.ones(2), gtsam.noiseModel.Diagonal.Sigmas(sig)))
    else:
        for f in make_odometry_factors(keys, prob.T_knots_odo, d, a, noise, extra_cov=extra):
            graph.add(f)
    if opt.planar:
        sz, st = opt.planar_sigma_z * np.sqrt(planar_var[0]), opt.planar_sigma_tilt * np.sqrt(planar_var[1])
        for k in keys:
            graph.add(make_planar_factor(int(k), sz, st, 0.0))
    if opt.anchor_tilt:
        anchor = gtsam.noiseModel.Isotropic.Sigma(6, opt.anchor_sigma)
    else:
        # The first knot fixes the gauge (position, heading), not the floor's plane: its roll and pitch are left to
        # the planar factors, so that the plane is the one all knots lie on, not the first knot's patch of floor.
        anchor = gtsam.noiseModel.Diagonal.Sigmas(np.r_[1.0, 1.0, np.full(4, opt.anchor_sigma)])
    graph.add(gtsam.PriorFactorPose3(int(keys[0]), gtsam.Pose3(prob.T_knots_odo[0]), anchor))
    _add_priors(graph, C_prior, td_prior, opt, R_prior)
    return graph, batch, keys


#: Fewest frames of one detector for its own pixel variance factor (adapt_detector_noise).
DETECTOR_NOISE_MIN_FRAMES = 20


def detector_noise_factors(prob: _Problem, rows: np.ndarray, batch: FrameBatch, values: gtsam.Values
                           ) -> dict[str, float]:
    """Per detector, the pixel variance factor of its frames (``adapt_detector_noise``): the median over its frames
    (``rows``, at the solution ``values``) of their mean squared error in units of their pixel sigma, relative to
    the others', normalised to a geometric mean of 1 over the frames. Empty without detectors or with one group."""
    if prob.frame_group is None:
        return {}
    per = _frame_rms(batch, values)[0]
    if prob.frame_sigma is not None:
        per = per / prob.frame_sigma[rows]
    groups = prob.frame_group[rows]
    ms = {}
    for g in np.unique(groups):
        x = per[(groups == g) & np.isfinite(per) & (per > 0)]
        if x.size >= DETECTOR_NOISE_MIN_FRAMES:
            ms[str(g)] = float(np.median(x**2))
    if len(ms) < 2:
        return {}
    n = {g: int(np.count_nonzero(groups == g)) for g in ms}
    mean_log = sum(n[g] * np.log(ms[g]) for g in ms) / sum(n.values())
    return {g: float(np.exp(np.log(ms[g]) - mean_log)) for g in ms}


def _with_detector_noise(prob: _Problem, factors: dict[str, float]) -> _Problem:
    """``prob`` with each frame's pixel sigma scaled by the square root of its detector's variance factor."""
    import dataclasses

    if not factors or prob.frame_group is None:
        return prob
    f = np.array([factors.get(str(g), 1.0) for g in prob.frame_group], dtype=float)
    base = prob.frame_sigma if prob.frame_sigma is not None else np.ones(f.size)
    return dataclasses.replace(prob, frame_sigma=base * np.sqrt(f))


def _frame_rms(batch: FrameBatch, values: gtsam.Values) -> tuple[np.ndarray, float, int]:
    """Per-frame RMS (px, of the 2-D error), the overall RMS and the number of points."""
    r = batch.evaluate_all(values, jacobians=False).residual
    e2 = np.sum(r**2, axis=-1)  # NaN where not detected
    n = np.sum(np.isfinite(e2), axis=1)
    per = np.sqrt(np.nansum(e2, axis=1) / np.maximum(n, 1))
    total = float(np.sqrt(np.nansum(e2) / max(1, n.sum())))
    return per, total, int(n.sum())


def _damped_solve(lin: gtsam.GaussianFactorGraph, dims: list[tuple[int, int]], lam: float):
    """Solve the linear system with Levenberg-Marquardt damping ``lam`` (identity in each tangent space)."""
    damped = lin.clone()
    r = float(np.sqrt(lam))
    for key, dim in dims:
        damped.add(gtsam.JacobianFactor(key, r * np.eye(dim), np.zeros(dim), gtsam.noiseModel.Unit.Create(dim)))
    return damped.optimize()


def _predicted_decrease(lin: gtsam.GaussianFactorGraph, delta: gtsam.VectorValues) -> float:
    """How much the linearized cost ``lin`` falls along the step ``delta``."""
    return float(lin.error(gtsam.VectorValues.Zero(delta)) - lin.error(delta))


def _levenberg_marquardt(graph, initial: gtsam.Values, opt: RefinementOptions, progress=None,
                         batch: FrameBatch | None = None):
    """Levenberg-Marquardt on top of GTSAM's linearization and elimination.

    GTSAM's own LevenbergMarquardtOptimizer gave the same steps but spent seconds per iteration in C++ on
    long recordings (docs/refinement.md) where linearize + eliminate take a fraction of that; this loop
    does exactly: linearize, damp, eliminate, retract, evaluate, adapt the damping, and ends where a step that
    failed was expected by the linear model to gain less than the tolerance. ``batch``: the graph's
    reprojection factors' batch, evaluated once per error and linearization and served to the factors without
    their reading the values (:meth:`FrameBatch.evaluated_at`); the same numbers either way.
    """

    def error(v: gtsam.Values) -> float:
        if batch is None:
            return graph.error(v)
        with batch.evaluated_at(v, jacobians=False):
            return graph.error(v)

    def linearize(v: gtsam.Values):
        if batch is None:
            return graph.linearize(v)
        with batch.evaluated_at(v, jacobians=True):
            return graph.linearize(v)

    values = initial
    err = error(values)
    dims = [(int(k), _dim_of(values, int(k))) for k in values.keys()]
    lam = opt.lm_lambda_min
    converged = False
    it = 0
    for it in range(1, opt.max_iterations + 1):
        lin = linearize(values)
        accepted = False
        while lam <= 1e12:
            try:
                delta = _damped_solve(lin, dims, lam)
            except RuntimeError:  # indeterminate at this damping
                lam *= 10.0
                continue
            new = values.retract(delta)
            new_err = error(new)
            if np.isfinite(new_err) and new_err <= err:
                accepted = True
                break
            # A step the linear model itself expects to gain less than the convergence tolerance (and that did not
            # gain at all): at the minimum. More damping only shortens the step, so it would take a full elimination
            # for each tenfold of lambda to find the same (up to 12 of them, 0.14 s on the benchmark recording).
            if _predicted_decrease(lin, delta) <= max(opt.absolute_tol, opt.relative_tol * err):
                break
            lam *= 10.0
        log.debug("iteration %d: error %.6g -> %.6g, lambda %.3g", it, err, new_err if accepted else err, lam)
        if progress is not None:
            progress(it, opt.max_iterations)
        if not accepted:  # no step decreases the error: at the minimum (to the damping's resolution)
            converged = True
            break
        dec = err - new_err
        values, err = new, new_err
        lam = max(lam / 10.0, opt.lm_lambda_min)
        if dec <= opt.absolute_tol or dec <= opt.relative_tol * max(err + dec, 1e-300):
            converged = True
            break
    return values, it, converged


def _optimize(graph, initial: gtsam.Values, opt: RefinementOptions, progress=None,
              batch: FrameBatch | None = None) -> tuple[gtsam.Values, int, bool]:
    if opt.optimizer == "lm":
        return _levenberg_marquardt(graph, initial, opt, progress, batch)
    if opt.optimizer == "dogleg":
        params = gtsam.DoglegParams()
        params.setMaxIterations(opt.max_iterations)
        optimizer = gtsam.DoglegOptimizer(graph, initial, params)
    else:
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(opt.max_iterations)
        # GTSAM's Cholesky calls a pivot "indeterminate" when it is tiny relative to its diagonal, which td is
        # (the knots absorb most of its information). With LM's default lambda of 1e-5 every iteration then
        # fails several times (a full elimination each) before the damping is large enough. A damping of 1
        # (information 1 rad^-2, 1 m^-2, 1 s^-2 on each variable, negligible next to the data) avoids that.
        params.setlambdaInitial(opt.lm_lambda_min)
        params.setlambdaLowerBound(opt.lm_lambda_min)
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    prev = graph.error(initial)
    converged = False
    it = 0
    for it in range(1, opt.max_iterations + 1):
        optimizer.iterate()
        err = optimizer.error()
        log.debug("iteration %d: error %.6g", it, err)
        if progress is not None:
            progress(it, opt.max_iterations)
        if not np.isfinite(err):
            break
        dec = prev - err
        if abs(dec) <= opt.absolute_tol or abs(dec) <= opt.relative_tol * max(prev, 1e-300):
            converged = True
            break
        prev = err
    return optimizer.values(), it, converged


def _values(prob: _Problem, T_knots: np.ndarray, C: np.ndarray, B: np.ndarray, td: float) -> gtsam.Values:
    v = gtsam.Values()
    if prob.steps is not None:
        v.insert(KEY_SCALE, np.array(prob.scale, dtype=float))
    for k in range(prob.knot_t.size):
        v.insert(knot_key(k), gtsam.Pose3(T_knots[k]))
    v.insert(KEY_CAM, gtsam.Pose3(C))
    v.insert(KEY_BOARD, gtsam.Pose3(B))
    v.insert(KEY_TD, np.array([td]))
    return v


def joint_marginal_covariance(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: list[int]) -> np.ndarray:
    """Joint marginal covariance of ``keys`` (tangent order, keys in the given order) at ``values``.

    Not gtsam.Marginals: the weakly regularised unobservable directions make the information span ten
    orders of magnitude, and GTSAM's Cholesky then reports an indeterminate system although the matrix is
    positive definite. Here GTSAM eliminates only the well-conditioned variables (the base knots) and the
    small Schur complement on the calibration variables (T_base_cam, T_world_board, td and ``keys``) is
    inverted with numpy. If that elimination fails, a sparse LU on the full information matrix is used.
    """
    lin = graph.linearize(values)
    all_keys = [int(k) for k in lin.keyVector()]
    keep = [k for k in (KEY_BOARD, KEY_CAM, KEY_TD) if k in all_keys]
    keep += [int(k) for k in keys if int(k) not in keep]
    elim = [k for k in all_keys if k not in keep]
    try:
        if elim:
            rest = lin.eliminatePartialMultifrontal(elim)[1]
        else:
            rest = lin
        order = gtsam.Ordering()
        for k in keep:
            order.push_back(k)
        S = rest.hessian(order)[0]
    except RuntimeError as exc:
        log.debug("partial elimination failed (%s); using the sparse Schur complement", exc)
        S = _schur_sparse(lin, values, keep)
    S = 0.5 * (S + S.T)
    w = np.linalg.eigvalsh(S)
    if not np.all(np.isfinite(w)) or w.min() <= 0:
        raise np.linalg.LinAlgError(
            f"information matrix of the calibration is not positive definite (min eig {w.min():.3g})"
        )
    cov_s = np.linalg.inv(S)
    offs = np.r_[0, np.cumsum([_dim_of(values, k) for k in keep])]
    idx = np.concatenate([np.arange(offs[keep.index(int(k))], offs[keep.index(int(k)) + 1]) for k in keys])
    return cov_s[np.ix_(idx, idx)]


def _schur_sparse(lin: gtsam.GaussianFactorGraph, values: gtsam.Values, keep: list[int]) -> np.ndarray:
    """Schur complement of the information matrix onto ``keep`` with scipy (GTSAM-independent fallback)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    i, j, v = lin.sparseJacobian_()
    all_keys = sorted(int(k) for k in lin.keyVector())  # GTSAM's default (natural) ordering of the columns
    offs = np.r_[0, np.cumsum([_dim_of(values, k) for k in all_keys])]
    n = int(offs[-1])
    A = sp.csc_matrix((v, (i.astype(np.int64) - 1, j.astype(np.int64) - 1)), shape=(int(i.max()), n + 1))[:, :n]
    H = (A.T @ A).tocsc()
    pos = {k: p for p, k in enumerate(all_keys)}
    s_idx = np.concatenate([np.arange(offs[pos[k]], offs[pos[k] + 1]) for k in keep])
    r_idx = np.setdiff1d(np.arange(n), s_idx)
    Hss = H[s_idx][:, s_idx].toarray()
    if not r_idx.size:
        return Hss
    Hrs = H[r_idx][:, s_idx].toarray()
    X = spla.splu(H[r_idx][:, r_idx].tocsc()).solve(Hrs)
    return Hss - Hrs.T @ X


def _dim_of(values: gtsam.Values, key: int) -> int:
    if key == KEY_TD:
        return 1
    try:
        values.atPose3(key)
        return 6
    except RuntimeError:
        return int(np.size(values.atVector(key)))


def _prior_information(opt: RefinementOptions, user_priors: bool = True) -> np.ndarray:
    """Information (7 x 7, user axes) the priors put directly on (T_base_cam, td); optionally only the regulariser."""
    d = np.r_[np.full(3, opt.reg_sigma_rot**-2), np.full(3, opt.reg_sigma_trans**-2), opt.reg_sigma_td**-2]
    if not user_priors:
        return np.diag(d)
    if opt.rotation_prior_sigma is not None:
        d[:3] += opt.rotation_prior_sigma**-2
    if opt.camera_height is not None:
        d[5] += opt.camera_height_sigma**-2
    return np.diag(d)


def _calibration_covariance(graph, values: gtsam.Values, C: np.ndarray, chi2: float,
                            opt: RefinementOptions, with_scale: bool = False,
                            tilt_correction: np.ndarray | None = None):
    """Marginal covariance of (T_base_cam, td) in GTSAM axes and in base (user) axes; with ``with_scale`` also
    the joint 9 x 9 covariance of (user axes, s_v, s_w) (None without the odometry intrinsics). ``tilt_correction``
    (tilt_influence_correction's, in the joint's tangent axes) sets the variances of roll and pitch (base axes) to
    the graph's plus its own; their rows and columns are scaled to match, the correlations and the other axes kept."""
    has_scale = values.exists(KEY_SCALE)
    keys = [KEY_CAM, KEY_TD] + ([KEY_SCALE] if has_scale else [])
    full = joint_marginal_covariance(graph, values, keys)
    if tilt_correction is not None:
        full = _with_tilt_correction(full, tilt_correction, C)
    if opt.scale_covariance and chi2 > 1.0:
        full = full * chi2
    cov = full[:7, :7]
    J = user_axes_jacobian(C[:3, :3])
    if not with_scale:
        return cov, J @ cov @ J.T
    joint = None
    if has_scale:
        J9 = np.eye(9)
        J9[:7, :7] = J
        joint = J9 @ full @ J9.T
    return cov, J @ cov @ J.T, joint


#: The floor tilt's correction leaves roll's and pitch's variance at least this fraction of the graph's.
TILT_MIN_VARIANCE_FRACTION = 0.05


def _with_tilt_correction(full: np.ndarray, correction: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``full`` (tangent axes of T_base_cam, td[, scales]) with roll's and pitch's variance (base axes) those of
    ``full + correction`` (at least TILT_MIN_VARIANCE_FRACTION of their own): their rows and columns scaled, so the
    result stays positive definite and keeps its correlations and every other variance."""
    J = user_axes_jacobian(C[:3, :3])
    base = J @ full[:7, :7] @ J.T
    add = J @ correction[:7, :7] @ J.T
    s = np.ones(7)
    for i in (0, 1):
        v = base[i, i]
        if v > 0:
            s[i] = np.sqrt(max(v + add[i, i], TILT_MIN_VARIANCE_FRACTION * v) / v)
    T = np.eye(full.shape[0])
    T[:7, :7] = np.linalg.solve(J, s[:, None] * J)  # J^-1 diag(s) J: the scaling in tangent axes
    return T @ full @ T.T


def _new_unobservable(
    cov_user: np.ndarray, prior_info: np.ndarray, frozen: list[np.ndarray], ratio: float
) -> list[np.ndarray]:
    """Functionals (7,) in user axes of eigen-directions the data does not observe and that are not frozen yet.

    A functional f measures the component of a change du along the direction in prior sigmas (f @ du).
    """
    import scipy.linalg

    S = np.sqrt(np.diag(np.linalg.inv(prior_info)))
    A = np.linalg.inv(cov_user)
    lam, V = scipy.linalg.eigh(S[:, None] * A * S[None, :], S[:, None] * prior_info * S[None, :])
    Z = np.array([f * S for f in frozen]).reshape(-1, 7)  # frozen directions in scaled coordinates
    out = []
    for j in np.argsort(lam):
        if 1.0 / np.sqrt(max(lam[j], 1e-300)) < ratio:
            break
        v = V[:, j] / np.linalg.norm(V[:, j])
        if Z.size:
            Q = np.linalg.qr(Z.T)[0]
            if np.linalg.norm(v - Q @ (Q.T @ v)) < 0.5:
                continue
        out.append(v / S)
        Z = np.vstack([Z, v[None]])
    return out


def _honest_covariance(cov_user: np.ndarray, opt: RefinementOptions, frozen: bool,
                       cov_decide: np.ndarray | None = None) -> np.ndarray:
    """The reported covariance: directions held at the seed get the regulariser's sigma back, td its model floor.

    A direction the solve held at the seed carries the seed's value, so the data's (weak) information on it
    must not shrink its sigma. Every eigen-direction whose posterior/prior sigma ratio is at or above
    ``freeze_ratio`` (exactly those the freezing rule holds) is reset to the prior along it.
    """
    import scipy.linalg

    cov = 0.5 * (cov_user + cov_user.T)
    if frozen and opt.freeze_unobservable:
        Lp = _prior_information(opt, user_priors=False)
        # Which directions are held is decided on ``cov_decide`` (the covariance before the inflation for correlated
        # errors, which must not turn a determined direction into a held one); they get the prior back in ``cov``.
        dec = cov if cov_decide is None else 0.5 * (cov_decide + cov_decide.T)
        lam, V = scipy.linalg.eigh(np.linalg.inv(dec), Lp)  # V^T Lp V = I, dec = V diag(1/lam) V^T
        held = 1.0 / np.sqrt(np.maximum(lam, 1e-300)) >= opt.freeze_ratio
        Vi = np.linalg.inv(V)
        Cv = Vi @ cov @ Vi.T  # cov in the same coordinates
        Cv[held, :] = 0.0
        Cv[:, held] = 0.0
        Cv[held, held] = 1.0
        cov = V @ Cv @ V.T
    cov = cov.copy()
    cov[6, 6] += opt.td_model_sigma**2
    return cov


def held_directions(cov_decide: np.ndarray | None, opt: RefinementOptions) -> list[dict]:
    """What the data said of each direction the freezing rule holds at the seed (those :func:`_honest_covariance`
    resets to the prior): per direction, ``ratio`` (its posterior / prior sigma on the data and the regulariser alone,
    at or above ``freeze_ratio``) and ``shares`` (axis -> its share of the direction in prior sigmas, those of 5 % or
    more). A direction held at a ratio well below UNOBSERVABLE_RATIO was determined, only too weakly to be used; one
    near 1 not at all. :func:`held_weakly` reads them per axis."""
    import scipy.linalg

    if cov_decide is None or not opt.freeze_unobservable:
        return []
    Lp = _prior_information(opt, user_priors=False)
    S = 1.0 / np.sqrt(np.diag(Lp))  # prior sigmas
    dec = 0.5 * (cov_decide + cov_decide.T)
    lam, V = scipy.linalg.eigh(np.linalg.inv(dec), Lp)  # as in _honest_covariance
    out = []
    for j in np.argsort(lam):
        ratio = 1.0 / np.sqrt(max(float(lam[j]), 1e-300))
        if ratio < opt.freeze_ratio:
            break
        share = (V[:, j] / S) ** 2
        share /= share.sum()
        keep = [k for k in range(7) if share[k] >= 0.05]
        out.append({"ratio": ratio, "shares": {AXES[k]: float(share[k]) for k in keep},
                    "data_sigma": {AXES[k]: float(min(ratio, 1.0) * S[k]) for k in keep}})
    return out


def held_weakly(held: list[dict], axis: str) -> float | None:
    """The data's sigma along ``axis`` (rad, m or s) when every direction held at the seed that ``axis`` takes part
    in (a fifth or more of it) was determined, only too weakly to be used (ratio below UNOBSERVABLE_RATIO): the
    posterior sigma along ``axis`` of the one it takes the largest part in, on the data and the regulariser alone.
    None when one of them was not determined at all, or none holds ``axis``. From the directions of
    :func:`held_directions` (report.json: the refinement's ``priors.held_directions``)."""
    touching = [h for h in held if h["shares"].get(axis, 0.0) >= 0.2]
    if not touching or max(h["ratio"] for h in touching) >= UNOBSERVABLE_RATIO:
        return None
    return max(touching, key=lambda h: h["shares"][axis])["data_sigma"][axis]


def _unobservable_at(graph, values: gtsam.Values, opt: RefinementOptions, frozen: list[np.ndarray],
                     warnings: list[str]) -> tuple[list[np.ndarray], np.ndarray | None]:
    """New directions (user-axes functionals) that only the regulariser holds at ``values``, and the
    (unscaled, GTSAM-axes) covariance they were found from.

    Only what the regulariser alone holds is frozen: a direction a user prior informs (a measured camera
    height, a closed-form rotation prior) stays free and is pulled by that prior.
    """
    C = values.atPose3(KEY_CAM).matrix()
    try:
        cov, cov_base = _calibration_covariance(graph, values, C, 1.0, opt)
    except (RuntimeError, np.linalg.LinAlgError) as exc:
        warnings.append(f"observability check failed ({exc}); no direction was held at the seed")
        return [], None
    reg = _prior_information(opt, user_priors=False)
    return _new_unobservable(cov_base, reg, frozen, opt.freeze_ratio), cov


def _difference(a: RefinementResult, b: RefinementResult) -> np.ndarray:
    """a - b in (roll, pitch, yaw, x, y, z, td), the rotation as the relative rotation about the base axes."""
    d = so3_log(a.T_base_cam[:3, :3] @ b.T_base_cam[:3, :3].T)
    return np.r_[d, a.T_base_cam[:3, 3] - b.T_base_cam[:3, 3], a.td - b.td]


def _sigma_before_knots(res: RefinementResult) -> np.ndarray:
    """The result's per-axis sigma (AXES order) before the knot-spacing second opinion was added."""
    inflation = res.inflation or {}
    # (Before the focal length's share too, which both starts share: a result finished without the knots' opinion.)
    before = inflation.get("sigma_before_knot_spacing") or inflation.get("sigma_before_focal_length")
    if before is not None:
        return np.array([before[a] for a in AXES])
    return np.sqrt(np.diag(res.cov_base_axes))


def _two_starts(first: tuple | None, second: tuple | None, td_search: float, td_given: float,
                opt: RefinementOptions, failed: list[Exception] | None = None) -> RefinementResult:
    """Of two refinements of one recording, started from the search's time offset (``first``) and from the closed
    form's (``second``), each a (result, scorer, values) or None if that start failed: the one the data prefer,
    with a record of both. A fourth element (a :class:`_Deferred`, see ``defer_knots``) gives the chosen result
    with its knots' second opinion; the other's is dropped.

    Each solve's final model scores both solutions (the solves share their knots, so either's values fit either
    model; each solution's frames are bracketed at its own td; the regularising priors are common). The models
    differ only in their adapted noise and in frames near the ends, so a solution both prefer fits the data better;
    the sum of the two differences, E_a(b) - E_a(a) + E_b(b) - E_b(a), decides (negative: ``second``). Where the
    two answers differ by more than 3 sigma on an axis while the scores differ by less than
    ``two_starts_decisive`` (or could not be compared), the data hardly tell one minimum from the other and the
    answer is not known to that axis's sigma: the result says so in ``two_starts["ambiguous"]`` and the gate
    flags it. A start that failed or did not converge leaves the other's answer, and the record says so.
    """
    record: dict = {"td_start_s": [float(td_search), float(td_given)],
                    "td_end_s": [None if x is None else float(x[0].td) for x in (first, second)],
                    "converged": [x is not None and bool(x[0].converged) for x in (first, second)]}
    if failed:
        record["failed"] = [str(e) for e in failed]
    ok = record["converged"]
    pick_second = None
    if ok[0] and ok[1]:
        (_, ga, va, *_), (_, gb, vb, *_) = first, second
        try:
            e = [[score(v) for v in (va, vb)] for score in (ga, gb)]
            delta = (e[0][1] - e[0][0]) + (e[1][1] - e[1][0])
        except RuntimeError as exc:  # a key one solve lacks: no comparison
            log.info("refine: the two starts could not be compared (%s)", exc)
            e, delta = None, float("nan")
        if np.isfinite(delta):
            record.update(errors=e, delta=float(delta))
            pick_second = bool(delta < 0)
        else:
            record["compared"] = False
            pick_second = False  # the search's start, as with one start
    elif first is not None and second is not None:
        pick_second = ok[1] and not ok[0]
    else:
        pick_second = first is None
    chosen, other = (second, first) if pick_second else (first, second)
    # A start solved without the knots' second opinion (defer_knots) gets it now that it is the one reported.
    if other is not None and len(other) > 3 and other[3] is not None:
        other[3].discard()
    chosen = chosen[3].result() if len(chosen) > 3 and chosen[3] is not None else chosen[0]
    other = None if other is None else other[0]
    record["chosen"] = "closed_form" if pick_second else "search"
    if chosen.cov_base_axes is not None and other is not None and other.converged:
        # The sigmas before the knots' second opinion: the losing start's denser solve may fall into the winner's
        # basin, and that jump is no sensitivity of the model.
        sig = _sigma_before_knots(chosen)
        if other.cov_base_axes is not None:
            sig = np.maximum(sig, _sigma_before_knots(other))
        z = np.abs(_difference(chosen, other)) / np.maximum(sig, 1e-300)
        z[5] = 0.0  # the height is held or prior-given: not an answer of the motion
        record["z"] = dict(zip(AXES, np.round(z, 2).tolist(), strict=True))
        close = not (abs(record.get("delta", 0.0)) >= opt.two_starts_decisive)
        off = [a for a, v in zip(AXES, z, strict=True) if v > 3.0]
        if off and close:
            record["ambiguous"] = off
    which = "the closed form's" if pick_second else "the search's"
    other_name = "the search's" if pick_second else "the closed form's"
    if other is None or not other.converged:
        how = "failed" if other is None else "did not converge"
        note = (f"the refinement was solved from the search's time offset ({1e3 * td_search:+.1f} ms) and from the "
                f"closed form's ({1e3 * td_given:+.1f} ms); the one from {other_name} {how}, the one from {which} "
                f"ended at {1e3 * chosen.td:+.1f} ms and is reported")
    else:
        why = (" (the two could not be compared)" if "delta" not in record else
               " (the two fit the data equally well)" if abs(record["delta"]) < 0.05 else
               f" (its fit is better by {abs(record['delta']):.1f} in the two graphs' errors)")
        note = (f"the refinement was solved from the search's time offset ({1e3 * td_search:+.1f} ms) and from the "
                f"closed form's ({1e3 * td_given:+.1f} ms); the one from {which} ended at {1e3 * chosen.td:+.1f} ms "
                f"and is reported{why}; the one from {other_name} ended at {1e3 * other.td:+.1f} ms")
    timing = dict(chosen.timing, starts_s=[None if x is None else float(x[0].timing.get("total_s", 0.0))
                                           for x in (first, second)])
    return replace(chosen, warnings=tuple(chosen.warnings) + (note,), two_starts=record, timing=timing)


def refine(
    camera_track: CameraTrack,
    base_track: BaseTrack,
    camera: CameraModel,
    seed_T_base_cam: np.ndarray,
    seed_td: float,
    options: RefinementOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
    seed_odometry_scale: tuple[float, float] | None = None,
    on_solution: Callable[[SimpleNamespace], None] | None = None,
) -> RefinementResult:
    """Refine T_base_cam and td jointly with the base trajectory and the board pose.

    ``camera_track.detections`` are the pixel measurements (one reprojection factor per frame);
    ``camera_track.T_board_cam`` seeds the board pose. ``seed_T_base_cam`` (4 x 4, or 3 x 3 rotation)
    and ``seed_td`` come from the closed form and the time alignment. Raises InputError /
    InsufficientDataError on unusable input; a solve that does not converge is returned with
    ``converged=False``, no covariance, and a warning (never a confident covariance on it).

    Passes: solve; drop outlier frames and re-bracket if td moved; then, with ``freeze_unobservable``,
    directions of (T_base_cam, td) the data does not observe are held at the seed and the solve is
    repeated from the seed (a wandering unobservable direction would bias the others through the
    nonlinearity). The covariance is always that of the graph without the freezing prior.

    ``on_solution(solution)`` is called once the solve has ended, before its covariance and second opinions are
    worked out, with its T_base_cam, R_base_cam, td and T_world_board (the result's, unless something later replaces
    them; it is not called when two starts are solved, since which one is reported is known only at the end). What
    it raises is logged, not raised: it is for work beside the refinement (the report's figures).
    """
    opt = options or RefinementOptions()
    t_start = time.perf_counter()
    C_seed, td_seed = _check_seed(seed_T_base_cam, seed_td)
    scale0 = _check_scale(seed_odometry_scale) if opt.estimate_odometry_scale else (1.0, 1.0)
    td_given = td_seed
    scale0_given = scale0
    search_note = None
    if opt.td_search_s > 0:
        found = turn_angle_td_search(camera_track, base_track, td_seed, opt.td_search_s)
        # The search escapes a wrong correlation peak (tens to hundreds of ms off); closer than td_search_replace_s
        # the graph's own estimate is the finer one (replacing a good seed by the search cost 0.25 deg of yaw on an
        # ideal recording), so the seed stays.
        if found is not None and abs(found[0] - td_seed) > opt.td_search_replace_s:
            log.info("refine: td seed %.4f s -> %.4f s (turn-angle search)", td_seed, found[0])
            search_note = (f"the closed form's time offset {1e3 * td_seed:+.1f} ms was a wrong correlation peak: the "
                           f"turn-angle search found {1e3 * found[0]:+.1f} ms and the refinement started there; the "
                           "closed-form rotation, solved at the wrong offset, is not used to check the refined one")
            if opt.estimate_odometry_scale:
                # The seed's odometry scales were fitted at the wrong td: start from nominal speed and this turn scale.
                scale0 = (1.0, float(np.clip(found[1], 0.3, 3.0)))
            td_seed = found[0]
    if td_seed == td_given or not opt.td_two_starts:
        res = _refine_from(camera_track, base_track, camera, opt, progress, C_seed, td_seed, td_given, td_seed,
                           scale0, search_note, None, t_start, on_solution=on_solution)[0]
        for w in res.warnings:
            log.warning(w)
        return res
    # The search replaced the closed form's offset: solve from both and keep the answer the data prefer
    # (see _two_starts). Both solves use the same knots, so that each graph can score the other's solution.
    knot_tds = (min(td_seed, td_given), max(td_seed, td_given))
    starts = ((td_seed, scale0, search_note), (td_given, scale0_given, None))
    solved: list = []
    failed: list[Exception] = []
    try:
        for td0, s0, note in starts:
            t0 = time.perf_counter()
            try:
                # The knots' second opinion is wanted of the reported start only (with two workers the first start's
                # runs beside the second start's solve).
                solved.append(_refine_from(camera_track, base_track, camera, opt, progress, C_seed, td0, td_given,
                                           td_seed, s0, note, knot_tds, t0, defer_knots=True))
            except (PlsgraphError, RuntimeError, np.linalg.LinAlgError) as exc:
                # One start failing (too many outliers from a bad offset) must not cost the other's answer.
                log.info("refine: the start from td %.4f s failed (%s)", td0, exc)
                solved.append(None)
                failed.append(exc)
        if solved[0] is None and solved[1] is None:
            raise failed[0]
        res = _two_starts(solved[0], solved[1], td_seed, td_given, opt, failed)
    except BaseException:
        for x in solved:  # a start's second opinion started beside and not asked for: stopped
            if x is not None and len(x) > 3 and x[3] is not None:
                x[3].discard()
        raise
    res = replace(res, timing=dict(res.timing, total_s=time.perf_counter() - t_start))
    for w in res.warnings:
        log.warning(w)
    return res


def _refine_from(camera_track: CameraTrack, base_track: BaseTrack, camera: CameraModel, opt: RefinementOptions,
                 progress, C_seed: np.ndarray, td_start: float, td_given: float, td_search: float,
                 scale0: tuple[float, float], search_note: str | None, knot_tds: tuple[float, float] | None,
                 t_start: float, probe: bool = False, warm: dict | None = None, defer_knots: bool = False,
                 on_solution: Callable[[SimpleNamespace], None] | None = None
                 ) -> tuple:
    """One refinement started at ``td_start`` (and odometry scales ``scale0``): the result, a scorer (the final
    graph's error of any values of the same knots, their frames bracketed at their own td) and the final values.
    ``td_given`` is the closed form's offset, ``td_search`` the search's (equal to it when the search kept it);
    they are the references the result is compared with. ``knot_tds``: the knots cover the frames shifted by
    any td in this range (the same knots for solves from different offsets). ``probe``: only the solution is wanted
    (a second opinion's solve): the result has no covariance and no second opinions of its own. ``warm``: start
    from another solve's answer (``C_seed`` its T_base_cam, ``td_start`` its td, ``scale0`` its scales; the dict's
    ``B``, ``knot_t`` and ``T_world_base`` its board and trajectory) and its frozen directions (``frozen``, not looked
    for again); with ``adapt`` the noise model is adapted again as in any solve, else that solve's noise factors
    (``odo_var``, ``planar_var``) are kept. ``defer_knots``: the result is returned without the knots' second opinion,
    with a fourth element that gives the result with it (``None`` where there is none): of two starts only the one
    reported needs it (see refine)."""
    td_seed = td_start
    # A warm solve selects its frames and knot span, and anchors its priors, where the solve it continues did.
    prob = _prepare(camera_track, base_track, camera, td_seed if warm is None else warm["anchor"][1], opt, scale0,
                    knot_tds)
    warnings = list(prob.warnings) + ([search_note] if search_note else [])
    t_guess = C_seed[:3, 3].copy()
    if opt.camera_height is not None:
        t_guess[2] = opt.camera_height
    if warm is None:
        seed_track = scaled_base_track(prob.base_track, *scale0, prob.steps, at=int(prob.knot_idx[0]))
        t_C, B0 = seed_translation_and_board(camera_track, seed_track, C_seed[:3, :3], td_seed, t_guess)
        C0 = make_T(C_seed[:3, :3], t_C)
        seed_values = _values(prob, prob.T_knots_odo, C0, B0, td_seed)
    else:
        C0, B0 = C_seed, warm["B"]
        kt = np.asarray(warm["knot_t"], dtype=float)
        knots = PoseInterpolator(kt, warm["T_world_base"])(np.clip(prob.knot_t, kt[0], kt[-1]))
        seed_values = _values(prob, knots, C0, B0, td_seed)
    values = seed_values
    rows = np.arange(len(prob.frames))
    prior_info = _prior_information(opt)
    C_anc, td_anc, R_anc = (C0, td_seed, C_seed[:3, :3]) if warm is None else warm["anchor"]
    J0 = user_axes_jacobian(C_anc[:3, :3])
    t_setup = time.perf_counter() - t_start

    total_it = 0
    odo_var = 1.0  # odometry variance factor (adapt_odometry_noise)
    held_solution = None  # (T_base_cam, td) solved under the model's own noise, before the adaptation
    planar_var = (1.0, 1.0)  # planar prior variance factors, height and tilt (adapt_planar_prior)
    vib_var = 0.0  # variance of the base's roll and pitch the camera sees between knots (adapt_chassis_vibration)
    vib_rounds = 0
    vibration: dict | None = None
    adapted = False
    rejected = np.zeros(len(prob.frames), dtype=bool)
    initial_error = rms0 = None
    converged = False
    settled = False
    td_bracket = td_seed
    frozen: list[np.ndarray] = []
    detector_var: dict[str, float] = {}  # per detector, its pixel variance factor (adapt_detector_noise)
    if warm is not None:
        if not warm.get("adapt", False):
            odo_var, planar_var, adapted = warm["odo_var"], warm["planar_var"], True
            detector_var = dict(warm.get("detector_var") or {})
            prob = _with_detector_noise(prob, detector_var)
        # The rocking is the base's, not the knots': a continued solve keeps the one measured (its rounds cost passes).
        vib_var = float(warm.get("vib_var", 0.0))
        vib_rounds = VIBRATION_ROUNDS
        frozen = list(warm["frozen"])
        rejected = np.isin(prob.frame_t, warm["rejected_t"])  # the frames the continued solve dropped as outliers
        rows = np.flatnonzero(~rejected)
    t_opt = 0.0
    cov = cov_base = None
    knots_job: _Beside | None = None  # the knots' second opinion, started once the solve has settled
    solution_sent = False  # on_solution called
    for pas in range(opt.max_passes):
        graph, batch, keys = _build_graph(prob, rows, td_bracket, opt, C_anc, td_anc, R_anc, odo_var=odo_var,
                                          planar_var=planar_var, vib_var=vib_var)
        # What the graph is built with: variances adapted below by less than 1.25 do not rebuild it, and the second
        # opinions taken on it (the jackknife's, the focal length's) must see the graph the solution is of.
        graph_built = (prob, dict(odo_var=odo_var, planar_var=planar_var, vib_var=vib_var))
        if initial_error is None:
            initial_error = float(graph.error(values))
            rms0 = _frame_rms(batch, values)[1]
            log.info("refine: %d frames, %d knots, initial error %.4g, RMS %.3f px", rows.size, keys.size,
                     initial_error, rms0)
        if pas == 0 and opt.freeze_unobservable and opt.marginals and warm is None:
            # Which directions does the motion leave to the regulariser? The information structure is set by the
            # motion, so the seed is a good enough linearization point to find them before they can wander.
            frozen += _unobservable_at(graph, values, opt, frozen, warnings)[0]
        solve_graph = graph
        if frozen:
            solve_graph = gtsam.NonlinearFactorGraph(graph)
            W = np.array(frozen) @ J0  # user-axes functionals -> GTSAM tangent at C0
            solve_graph.add(make_subspace_prior(KEY_CAM, KEY_TD, C_anc, [td_anc], W, _FREEZE_SIGMA))
        t0 = time.perf_counter()
        values, it, converged = _optimize(solve_graph, values, opt, progress, batch)
        t_opt += time.perf_counter() - t0
        total_it += it
        per, rms, _ = _frame_rms(batch, values)
        td_now = float(values.atVector(KEY_TD)[0])
        bad = per > max(opt.reject_px, opt.reject_factor * float(np.median(per)))
        moved = abs(td_now - td_bracket) > 0.25 * float(np.median(np.diff(prob.knot_t)))
        log.info("refine pass %d: %d iterations, RMS %.3f px, %d outlier frame(s), td %.5f s, %d frozen", pas + 1,
                 it, rms, int(bad.sum()), td_now, len(frozen))
        if bad.any():
            if rows.size - bad.sum() < 3:
                raise InsufficientDataError("refine: almost every frame is an outlier; check the seed and intrinsics")
            rejected[rows[bad]] = True
            rows = rows[~bad]
        if moved:
            td_bracket = td_now
        rescaled = False
        if prob.steps is not None:
            s_now = values.atVector(KEY_SCALE)
            if np.max(np.abs(s_now / np.array(prob.scale) - 1.0)) > opt.scale_rebuild_tol:
                # The detail between knots was built from the odometry at the old scales: rebuild it.
                prob = _rescaled(prob, (float(s_now[0]), float(s_now[1])), opt)
                rescaled = True
        if bad.any() or moved or rescaled:
            log.debug("refine: solving again (%s)", ", ".join(w for w, c in (("outliers", bad.any()), (
                "td moved by a quarter knot", moved), ("odometry scale rebuilt", rescaled)) if c))
            continue
        if converged and opt.adapt_odometry_noise and not adapted:
            # Once: the factor is measured at the solution under the model's own noise (measured again under the
            # scaled noise, the residuals' correlation would be counted a second time).
            adapted = True
            held_solution = (values.atPose3(KEY_CAM).matrix(), float(values.atVector(KEY_TD)[0]))
            if opt.split_odometry_noise:
                tilt = opt.adapt_odometry_tilt and not opt.scale_odometry_tilt
                odo_var = tuple(float(v) for v in np.clip(odometry_noise_factor(graph, values, split=True, tilt=tilt),
                                                           1.0, opt.max_odometry_noise_factor))
            else:
                odo_var = float(np.clip(odometry_noise_factor(graph, values), 1.0, opt.max_odometry_noise_factor))
            if _slip(odo_var) >= NOISY_ODOMETRY_FACTOR:
                warnings.append(
                    f"the wheel odometry's errors carry {_slip(odo_var):.0f}x the variance of good odometry on a "
                    "hard floor (wheel slip correlated over many samples, as on skid-steer robots); the refinement "
                    "weighted it down by that factor, so yaw and lever arm rest more on the camera and their sigmas "
                    "are larger")
            if opt.adapt_detector_noise:
                detector_var = detector_noise_factors(prob, rows, batch, values)
                if detector_var:
                    prob = _with_detector_noise(prob, detector_var)
                    log.info("refine: pixel variance factors by detector %s",
                             {g: round(v, 2) for g, v in detector_var.items()})
            if opt.planar and opt.adapt_planar_prior:
                f = np.clip(planar_noise_factors(graph, values), 1.0, opt.max_planar_prior_factor)
                planar_var = (float(f[0]) if opt.adapt_planar_height else 1.0, float(f[1]))
                log.info("refine: planar prior variance factors (height, tilt) %s", np.round(planar_var, 1))
            if _largest(odo_var) > 1.25 or max(planar_var) > 1.25 or detector_var:
                log.info("refine: odometry errors %sx the model's variance (magnitude x correlation); solving "
                         "again with the odometry and planar variances scaled", np.round(odo_var, 1))
                continue
        if converged and opt.adapt_chassis_vibration and vib_rounds < VIBRATION_ROUNDS and \
                (adapted or not opt.adapt_odometry_noise):
            # The base's roll and pitch the knots do not follow, measured at the adapted solution; where it is above
            # the pixel noise it is added to the edges' roll and pitch and the solve continues, until what is left is
            # noise (or VIBRATION_ROUNDS rounds).
            vib_rounds += 1
            jit = chassis_tilt_jitter(batch, values)
            if max(jit["z"]) > VIBRATION_Z and np.mean(jit["var"]) > VIBRATION_MIN_RAD**2 \
                    and vib_var < VIBRATION_MAX_RAD**2:
                vib_var = min(vib_var + float(np.mean(jit["var"])), VIBRATION_MAX_RAD**2)
                vibration = dict(jit, total=vib_var, rounds=vib_rounds)
                log.info("refine: the camera sees the base roll / pitch by %s deg beyond what the knots follow; the "
                         "odometry edges' roll and pitch widened (%.3f deg per knot)",
                         np.round(np.degrees(np.sqrt(jit["var"])), 3), np.degrees(np.sqrt(vib_var)))
                continue
            if vibration is None:
                vibration = dict(jit, total=vib_var, rounds=vib_rounds)
        if not (converged and opt.freeze_unobservable and opt.marginals) or warm is not None:
            settled = True
            break
        # The knots' second opinion and the figures need only this solution: they start before the check below,
        # which rarely finds a direction (then the second opinion is dropped and the solve starts over; the figures
        # are drawn again if their solution is not the result's).
        if converged and not probe and knots_job is None and _wants_knot_probe(opt):
            knots_job = _start_knot_probe(camera_track, base_track, camera, opt, td_given, td_search, knot_tds,
                                          values, prob, frozen, rejected, vib_var, odo_var, planar_var,
                                          (C_anc, td_anc, R_anc), scale0, t_opt, detector_var)
        try:
            if not solution_sent:
                solution_sent = _send_solution(on_solution, values, prob.frame_t[rows], batch, prob.knot_t)
            # Check again at the solution; a direction found only now is frozen and the solve starts over.
            new = _unobservable_at(graph, values, opt, frozen, warnings)[0]
        except BaseException:
            if knots_job is not None:
                knots_job.discard()  # nobody will ask for its answer
            raise
        if not new:
            settled = True
            break
        if knots_job is not None:
            knots_job.discard()
            knots_job = None
        frozen += new
        values = seed_values
        log.info("refine: %d direction(s) not observable; holding them at the seed and solving again", len(new))
    try:  # the knots' second opinion, started when the passes settled, is not left running if this raises
        if not settled:
            warnings.append("outlier rejection / re-bracketing / freezing did not settle within max_passes")
        if vib_var > 0:
            warnings.append(
                f"the camera sees the base rock in roll and pitch by about {np.degrees(np.sqrt(vib_var)):.2f} deg at "
                "a few hertz, which the wheels do not report (a vibrating chassis or a bumpy floor); the base's roll "
                "and pitch between knots were loosened to follow it")

        if settled:
            final_graph = graph  # same frames and brackets as the last solve
        else:
            final_graph, batch, keys = _build_graph(prob, rows, td_bracket, opt, C_anc, td_anc, R_anc,
                                                    odo_var=odo_var, planar_var=planar_var, vib_var=vib_var)
            graph_built = (prob, dict(odo_var=odo_var, planar_var=planar_var, vib_var=vib_var))
        final_error = float(final_graph.error(values))
        per, rms, n_pts = _frame_rms(batch, values)
        C = values.atPose3(KEY_CAM).matrix()
        B = values.atPose3(KEY_BOARD).matrix()
        td = float(values.atVector(KEY_TD)[0])
        T_knots = np.stack([values.atPose3(int(k)).matrix() for k in keys])
        dof = max(1, 2 * n_pts - 6 * keys.size - 13)
        sig = np.broadcast_to(np.asarray(_pixel_sigma(prob, rows, opt), dtype=float), (rows.size,))
        res_raw = batch.evaluate_all(values, False).residual
        res_now = np.nan_to_num(res_raw)
        chi2 = float(np.sum((res_now / sig[:, None, None]) ** 2) / dof)
        if not np.isfinite(final_error):
            converged = False
            warnings.append("the optimisation produced a non-finite error")
        if not converged:
            warnings.append(
                f"the optimisation did not converge in {opt.max_iterations} iterations per pass; the result is not "
                "reliable and no covariance is given (try a better seed, more iterations or a robust loss)"
            )
        if rms > 5 * opt.sigma_px:
            warnings.append(
                f"final reprojection RMS {rms:.2f} px is far above the assumed pixel noise {opt.sigma_px} px; "
                "check intrinsics, td and outliers"
            )

        t1 = time.perf_counter()
        cov = cov_base = joint = cov_plain = None
        inflation: dict = {}
        report: ObservabilityReport | None = None
        if probe:
            return RefinementResult(T_base_cam=C, td=td, T_world_board=B, knot_t=prob.knot_t.copy(),
                                    T_world_base=T_knots, converged=bool(converged), iterations=total_it,
                                    initial_error=float(initial_error),
                                    final_error=final_error, rms_px_initial=float(rms0), rms_px_final=rms,
                                    n_frames=int(rows.size), n_frames_rejected=int(rejected.sum()),
                                    n_frames_dropped=prob.n_dropped, n_frames_long_span=prob.n_long_span,
                                    n_points=n_pts, cov=None, cov_base_axes=None,
                                    chi2_per_dof=chi2, observability=None, warnings=tuple(warnings), priors={},
                                    timing={"total_s": time.perf_counter() - t_start}), None, values
        if knots_job is None and converged and _wants_knot_probe(opt):
            # (Usually started when the passes settled, above.) Solved beside the marginals and the jackknife. Not
            # earlier than the final answer (at the noise model's adaptation, beside the passes after it: tried,
            # 2026-11-28): its solve stops at a relative tolerance, so in a direction the data hardly fix (td) it
            # ends near where it starts, and from the solution before the adapted passes it counted their move as
            # the knots' (td changes of 17-24 ms on study runs where it had found under 2 ms).
            knots_job = _start_knot_probe(camera_track, base_track, camera, opt, td_given, td_search, knot_tds, values,
                                          prob, frozen, rejected, vib_var, odo_var, planar_var, (C_anc, td_anc, R_anc),
                                          scale0, t_opt, detector_var)
        if not solution_sent:
            _send_solution(on_solution, values, prob.frame_t[rows], batch, prob.knot_t)
    except BaseException:
        if knots_job is not None:
            knots_job.discard()
        raise
    try:  # until the end: a job started beside is not left running when something below raises
        if converged and opt.marginals:
            try:
                cov_graph, tilt_corr = final_graph, None
                if opt.inflate_correlated:
                    inflation = correlation_inflation(final_graph, batch, values, opt, _pixel_sigma(prob, rows, opt))
                    rep_factor = inflation["reprojection_autocorrelation_time"]
                    if opt.pixel_variance_from_fit and chi2 < 1.0:
                        # The detections are less noisy than sigma_px says: the covariance takes their measured
                        # variance.
                        inflation["pixel_variance_factor"] = max(chi2, opt.pixel_variance_floor)
                        rep_factor *= inflation["pixel_variance_factor"]
                    cov_odo = _covariance_odometry_factor(odo_var, inflation["odometry_autocorrelation_time"])
                    cov_graph = _build_graph(prob, rows, td_bracket, opt, C0, td_seed, C_seed[:3, :3],
                                             rep_factor,
                                             # an adapted odometry variance already holds the correlation
                                             cov_odo, planar_var, vib_var)[0]
                    cov_plain = _calibration_covariance(final_graph, values, C, chi2, opt)[1]
                    if opt.planar and opt.tilt_variance_from_influence:
                        try:
                            keys = (KEY_CAM, KEY_TD) + ((KEY_SCALE,) if values.exists(KEY_SCALE) else ())
                            tilt_corr, ratio = tilt_influence_correction(cov_graph, values, keys)
                            inflation["tilt_influence_ratio"] = ratio
                        except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
                            log.info("refine: the floor tilt's influence could not be measured (%s); its share of "
                                     "the covariance is the graph's", exc)
                cov, cov_base, joint = _calibration_covariance(cov_graph, values, C, chi2, opt, with_scale=True,
                                                               tilt_correction=tilt_corr)
            except (RuntimeError, np.linalg.LinAlgError) as exc:
                warnings.append(f"marginal covariances could not be computed ({exc}); no uncertainty is reported")
        jackknife = None
        jk_steps: dict = {}  # the jackknife's step on the whole graph, which the focal length's sensitivity shares
        t_jk = time.perf_counter()
        if converged and opt.marginals and opt.frame_jackknife_segments >= 2:
            jk_graph = final_graph
            if frozen:
                jk_graph = gtsam.NonlinearFactorGraph(final_graph)
                jk_graph.add(make_subspace_prior(KEY_CAM, KEY_TD, C0, [td_seed], np.array(frozen) @ J0, _FREEZE_SIGMA))
            try:
                # The graph's first factors are the frames' reprojection factors, one per frame with points.
                n_rep = sum(1 for i in range(len(batch.frames)) if batch.n_valid(i) > 0)
                jackknife = frame_jackknife(jk_graph, values, n_rep, opt.frame_jackknife_segments, jk_steps)
            except (RuntimeError, np.linalg.LinAlgError) as exc:
                log.info("refine: frame jackknife failed (%s)", exc)
                if opt.add_frame_jackknife:
                    warnings.append(f"the jackknife over stretches of frames could not be solved ({exc}); the "
                                    "sigmas hold only the marginal covariance and the noise model's sensitivity, not "
                                    "errors shared by stretches of frames")
        focal_move = None
        focal_tried = bool(converged and opt.marginals and opt.focal_sensitivity_rel > 0)
        if focal_tried:
            try:
                extra = ([make_subspace_prior(KEY_CAM, KEY_TD, C0, [td_seed], np.array(frozen) @ J0, _FREEZE_SIGMA)]
                         if frozen else [])
                # On the graph the solution and the jackknife's step are of: the same problem and variances.
                focal_move = focal_sensitivity(graph_built[0], rows, td_bracket, opt, values, (C_anc, td_anc, R_anc),
                                               graph_built[1], extra, opt.focal_sensitivity_rel, jk_steps.get("whole"))
            except (RuntimeError, np.linalg.LinAlgError, PlsgraphError) as exc:
                log.info("refine: the focal length's sensitivity could not be solved (%s)", exc)
            if focal_move is None and opt.focal_sigma_rel > 0 and cov_base is not None:
                warnings.append("the calibration's sensitivity to the focal length could not be solved; the sigmas "
                                "do not hold the focal length's uncertainty (--focal-sigma)")
        lens_move = None
        if converged and opt.marginals and opt.lens_distortion_views is not None:
            cam0 = prob.frames.camera
            dist = np.asarray(cam0.dist, dtype=float).copy()
            dist[:2] = opt.lens_distortion_views
            try:
                extra = ([make_subspace_prior(KEY_CAM, KEY_TD, C0, [td_seed], np.array(frozen) @ J0, _FREEZE_SIGMA)]
                         if frozen else [])
                lens_move = camera_sensitivity(graph_built[0], rows, td_bracket, opt, values, (C_anc, td_anc, R_anc),
                                               graph_built[1], extra, replace(cam0, dist=dist),
                                               jk_steps.get("whole"))
            except (RuntimeError, np.linalg.LinAlgError, PlsgraphError) as exc:
                log.info("refine: the lens distortion's move could not be solved (%s)", exc)
        t_jk = time.perf_counter() - t_jk
        sensitivity = None
        if held_solution is not None and (_largest(odo_var) > 1.0 or max(planar_var) > 1.0):
            sensitivity = noise_model_sensitivity(C, td, *held_solution)
    except BaseException:
        if knots_job is not None:
            knots_job.discard()  # nobody will ask for its answer
        raise
    t_ready = time.perf_counter()

    def finish(job: _Beside | None, cov_base, cov, joint, report, warnings: list[str]) -> tuple:
        """The covariance with the second opinions (the knots' from ``job``, if any) and the result."""
        t_in = time.perf_counter()
        warnings = list(warnings)
        knot_sensitivity = knot_spacing = sigma_before_knots = None
        sigma_before_focal = focal_m = None
        cov_base_shared = cov_base  # without the focal length's share, which the closed form and both starts share
        held: list[dict] = []  # what the data said of the directions held at the seed (held_directions)
        t_knots = time.perf_counter()
        if job is not None:
            if cov_base is not None:
                knot_sensitivity, knot_spacing = knot_change(job.result(), prob.knot_t, C, td)
            else:
                job.discard()
        t_knots = time.perf_counter() - t_knots
        if cov_base is not None:
            # Which directions are held is decided on the covariance before the second opinions' inflation
            # (cov_plain, as _honest_covariance decides; without it, on this one).
            held = held_directions(cov_plain if cov_plain is not None else cov_base, opt) if frozen else []
            cov_base = _honest_covariance(cov_base, opt, bool(frozen), cov_plain)
            k_all = np.ones(7)
            if sensitivity is not None and opt.add_noise_model_sensitivity:
                # Second opinion: what the solution moved by when the noise model was adapted is an uncertainty of
                # the model itself, which the marginals (of either model) do not hold. Per axis, the larger of the two
                # variances is reported (correlations scaled along).
                sig = np.sqrt(np.diag(cov_base))
                k = np.maximum(sensitivity / np.maximum(sig, 1e-300), 1.0)
                cov_base = cov_base * np.outer(k, k)
                k_all = k_all * k
            if jackknife is not None and opt.add_frame_jackknife:
                # Second opinion: the spread of the leave-one-stretch-out answers (see frame_jackknife).
                sig = np.sqrt(np.diag(cov_base))
                k = np.maximum(jackknife / np.maximum(sig, 1e-300), 1.0)
                cov_base = cov_base * np.outer(k, k)
                k_all = k_all * k
            if knot_sensitivity is not None:
                # Second opinion: the change denser knots make (see knot_spacing_sensitivity).
                sig = np.sqrt(np.diag(cov_base))
                sigma_before_knots = sig
                k = np.maximum(knot_sensitivity / np.maximum(sig, 1e-300), 1.0)
                cov_base = cov_base * np.outer(k, k)
                k_all = k_all * k
                if np.any(k[[2, 3, 4, 6]] > KNOT_WARN_FACTOR):
                    warnings.append(knot_warning(knot_sensitivity, knot_spacing))
            sigma_before_focal = np.sqrt(np.diag(cov_base))
            cov_base_shared = cov_base
            if focal_move is not None and opt.focal_sigma_rel > 0 and opt.focal_sensitivity_rel > 0:
                # The focal length's own uncertainty, independent of the data's and shared by every axis with its
                # sign: the rank-one covariance of its move (the odometry scales' part is added below).
                focal_m = focal_move / opt.focal_sensitivity_rel * opt.focal_sigma_rel
                cov_base = cov_base + np.outer(focal_m[:7], focal_m[:7])
            if joint is not None and opt.propagate_to_odometry:
                joint = odometry_given_calibration(joint, k_all, opt.td_model_sigma)
            if joint is not None and focal_m is not None and focal_m.size == joint.shape[0]:
                joint = joint + np.outer(focal_m, focal_m)
            Ji = np.linalg.inv(user_axes_jacobian(C[:3, :3]))
            cov = Ji @ cov_base @ Ji.T
            report = observability_report(cov_base, prior_info, converged=True, regularized=True,
                                          planar_motion=opt.planar, prior_notes=_prior_notes(opt, frozen, held),
                                          held_weak=tuple(a for a in AXES if held_weakly(held, a) is not None))
        elif opt.marginals:
            report = not_converged_report("the optimisation did not converge" if not converged else "marginals failed")
        scale_jk = turn_jk = None
        if joint is not None and prob.steps is not None and opt.scale_jackknife_segments >= 2:
            # Second opinion on the arc-length scale (see speed_scale_jackknife): the larger sigma is reported.
            s_now = values.atVector(KEY_SCALE)
            scale_jk = speed_scale_jackknife(T_knots, prob.steps, prob.knot_idx, float(s_now[1]),
                                             opt.scale_jackknife_segments)
            sig_v = float(np.sqrt(max(float(joint[7, 7]), 0.0)))
            if scale_jk is not None and np.isfinite(sig_v) and scale_jk > sig_v:
                ks = np.ones(joint.shape[0])
                ks[7] = scale_jk / sig_v if sig_v > 0 else 1.0
                joint = joint * np.outer(ks, ks)
            if opt.turn_scale_jackknife:
                # The same second opinion on the turn scale (the effective track width, with the radius).
                turn_jk = turn_scale_jackknife(T_knots, prob.steps, prob.knot_idx, opt.scale_jackknife_segments)
                sig_w = float(np.sqrt(max(float(joint[8, 8]), 0.0)))
                if turn_jk is not None and np.isfinite(sig_w) and turn_jk > sig_w:
                    ks = np.ones(joint.shape[0])
                    ks[8] = turn_jk / sig_w if sig_w > 0 else 1.0
                    joint = joint * np.outer(ks, ks)
        joint_data = joint  # what the data determined: the intrinsics' observability status is judged on it
        if joint is not None and prob.steps is not None and opt.speed_scale_model_sigma > 0:
            joint = joint.copy()
            joint[7, 7] += (opt.speed_scale_model_sigma * float(values.atVector(KEY_SCALE)[0])) ** 2
        # The covariances alone (a deferred finish: not the time between the two calls).
        t_marg = (t_ready - t1 - t_jk) + (time.perf_counter() - t_in - t_knots)
        priors = {
            "regularisation": {"sigma_rot_rad": opt.reg_sigma_rot, "sigma_trans_m": opt.reg_sigma_trans,
                               "sigma_td_s": opt.reg_sigma_td, "at": "seed"},
            "rotation_prior_sigma": opt.rotation_prior_sigma,
            "camera_height": opt.camera_height,
            "board_height": opt.board_height,
            "board_vertical": opt.board_vertical,
            "planar": opt.planar,
            "frozen_directions": [dict(zip(AXES, np.round(f / np.linalg.norm(f), 4).tolist(), strict=True))
                                  for f in frozen],
            # What the data said of each direction held at the seed (see held_directions).
            "held_directions": held,
        }
        def score(v: gtsam.Values) -> float:
            """This solve's final model (frames, noise) on the values ``v``, bracketed at their own td. The weak
            regularising priors sit at the caller's seed (``C_seed``, ``td_given``), the same for every start: at each
            start's own seed they would favour the answer that stayed nearer its start."""
            return float(_build_graph(prob, rows, float(v.atVector(KEY_TD)[0]), opt, C_seed, td_given, C_seed[:3, :3],
                                      odo_var=odo_var, planar_var=planar_var, vib_var=vib_var)[0].error(v))

        td_ref, compare_rotation = td_search, td_search == td_given
        if td_search != td_given and abs(td - td_given) < abs(td - td_search):
            # The refinement, started at the search's offset, ended nearer the closed form's. Within what their sigmas
            # allow of it, the search's peak was the wrong one and the closed form (its rotation too) is the reference
            # the result is checked against again; farther, it agrees with neither, and the nearer one (the closed
            # form's) is the reference for td only: a rotation solved at a td that far off is none.
            td_ref = td_given
            sig_td = float(np.sqrt(cov_base[6, 6])) if cov_base is not None else 0.0
            back = abs(td - td_given) <= 3.0 * float(np.hypot(sig_td, opt.seed_sigma_td))
            compare_rotation = back
            warnings = [w for w in warnings if w != search_note]
            sig_all = float(np.hypot(sig_td, opt.seed_sigma_td))
            apart = f"{1e3 * abs(td - td_search):.0f} ms"
            if sig_all > 0:
                apart += f", {abs(td - td_search) / sig_all:.1f} sigma"
            where = (f"nearer the closed form's; the search's peak lies {apart} from the refined td" if back else
                     f"{1e3 * abs(td - td_given):.0f} ms from the closed form's and farther from the search's: it "
                     "agrees with neither")
            warnings.append(f"the turn-angle search put the time offset at {1e3 * td_search:+.1f} ms, "
                            f"{1e3 * abs(td_search - td_given):.0f} ms from the closed form's "
                            f"{1e3 * td_given:+.1f} ms; the refinement ended at {1e3 * td:+.1f} ms, {where}")
        return RefinementResult(
            T_base_cam=C,
            td=td,
            T_world_board=B,
            knot_t=prob.knot_t.copy(),
            T_world_base=T_knots,
            converged=bool(converged),
            iterations=total_it,
            initial_error=float(initial_error),
            final_error=final_error,
            rms_px_initial=float(rms0),
            rms_px_final=rms,
            n_frames=int(rows.size),
            n_frames_rejected=int(rejected.sum()),
            n_frames_dropped=prob.n_dropped,
            n_frames_long_span=prob.n_long_span,
            n_points=n_pts,
            cov=cov,
            cov_base_axes=cov_base,
            chi2_per_dof=chi2,
            observability=report,
            warnings=tuple(warnings),
            priors=priors,
            timing={"setup_s": t_setup, "optimize_s": t_opt, "marginals_s": t_marg, "jackknife_s": t_jk,
                    "knot_sensitivity_s": t_knots, "total_s": time.perf_counter() - t_start},
            seed_T_base_cam=C_seed,
            seed_td=td_given,
            residual_t=prob.frame_t[rows].copy(),
            residual_px=res_raw.astype(np.float32),
            odometry=odometry_report(values, joint, base_track.info, opt, scale0, joint_data)
            if prob.steps is not None else None,
            disagreement={} if cov_base is None else disagreement_with_seed(C, td, cov_base_shared, C_seed, td_ref, opt,
                                                                              rotation=compare_rotation),
            inflation={**inflation, "odometry_variance_factor": _slip(odo_var),
                       **({"odometry_variance_factors": dict(zip(("heading", "distance", "tilt")[:len(odo_var)],
                                                                 odo_var, strict=True))}
                          if isinstance(odo_var, tuple) else {}),
                       "noise_model_sensitivity": None if sensitivity is None else dict(zip(
                           ("roll", "pitch", "yaw", "x", "y", "z", "td"), sensitivity.tolist(), strict=True)),
                       "planar_variance_factors": {"height": float(planar_var[0]), "tilt": float(planar_var[1])},
                       "detector_variance_factors": dict(detector_var),
                       "floor_tilt_rms_deg": floor_tilt_rms_deg(values, prob.knot_t.size),
                       "chassis_vibration_deg": None if vibration is None else {
                           "per_knot": float(np.degrees(np.sqrt(vib_var))), "rounds": int(vibration["rounds"]),
                           "last_roll": float(np.degrees(np.sqrt(vibration["var"][0]))),
                           "last_pitch": float(np.degrees(np.sqrt(vibration["var"][1]))),
                           "last_z": [float(z) for z in vibration["z"]], "applied": bool(vib_var > 0)},
                       "speed_scale_jackknife_sigma": scale_jk,
                       "turn_scale_jackknife_sigma": turn_jk,
                       "frame_jackknife_sigma": None if jackknife is None else dict(zip(
                           ("roll", "pitch", "yaw", "x", "y", "z", "td"), jackknife.tolist(), strict=True)),
                       "knot_spacing_sensitivity": None if knot_sensitivity is None else dict(zip(
                           ("roll", "pitch", "yaw", "x", "y", "z", "td"), knot_sensitivity.tolist(), strict=True)),
                       "knot_spacing_s": knot_spacing,
                       "focal_length_sensitivity": None if focal_move is None else {
                           "focal_change": float(opt.focal_sensitivity_rel),
                           "focal_sigma_in_sigmas": float(opt.focal_sigma_rel) if focal_m is not None else 0.0,
                           **dict(zip(("roll", "pitch", "yaw", "x", "y", "z", "td", "speed_scale", "turn_scale"),
                                      focal_move.tolist(), strict=False))},
                       "lens_distortion_move": None if lens_move is None else {
                           "k1_k2": [float(x) for x in opt.lens_distortion_views],
                           **dict(zip(("roll", "pitch", "yaw", "x", "y", "z", "td", "speed_scale", "turn_scale"),
                                      lens_move.tolist(), strict=False))},
                       "sigma_before_focal_length": None if sigma_before_focal is None else dict(zip(
                           ("roll", "pitch", "yaw", "x", "y", "z", "td"), sigma_before_focal.tolist(), strict=True)),
                       "sigma_before_knot_spacing": None if sigma_before_knots is None else dict(zip(
                           ("roll", "pitch", "yaw", "x", "y", "z", "td"), sigma_before_knots.tolist(), strict=True))},
            td_searched=None if td_ref == td_given else float(td_search),
            held_solution=held_solution,
        ), score, values

    if defer_knots:
        args = (cov_base, cov, joint, report, warnings)
        try:
            first = finish(None, *args)
        except BaseException:
            if knots_job is not None:
                knots_job.discard()
            raise
        return (*first, None if knots_job is None else _Deferred(finish, knots_job, args))
    return finish(knots_job, cov_base, cov, joint, report, warnings)


def autocorrelation_time(x: np.ndarray, max_lag: int = 60) -> float:
    """Integrated autocorrelation time 1 + 2 sum_l rho_l of a multichannel series ``x`` (time first; NaN = missing),
    the sum stopped at the first lag whose correlation is <= 0 (Geyer's initial positive sequence, simplified).

    It is the factor by which correlated samples inflate the variance of a mean over them (1 for white noise).
    """
    x = np.asarray(x, dtype=float).reshape(len(x), -1)
    n = x.shape[0]
    if n < 4:
        return 1.0
    x = x - np.nanmean(x, axis=0)
    ok = np.isfinite(x)
    x0 = np.where(ok, x, 0.0)
    var = float(np.sum(x0**2))
    if var <= 0:
        return 1.0
    tau = 1.0
    for lag in range(1, min(max_lag, n // 4) + 1):
        both = ok[lag:] & ok[:-lag]
        num = float(np.sum(np.where(both, x0[lag:] * x0[:-lag], 0.0)))
        den = float(np.sqrt(np.sum(np.where(both, x0[lag:] ** 2, 0.0)) * np.sum(np.where(both, x0[:-lag] ** 2, 0.0))))
        rho = num / den if den > 0 else 0.0
        if rho <= 0.0:
            break
        tau += 2.0 * rho
    return float(tau)


MIN_JACKKNIFE_STRETCH_M = 0.05  # forward or back, summed over a stretch's edges


def speed_scale_jackknife(T_knots: np.ndarray, steps: PlanarSteps, knot_idx: np.ndarray, s_w: float,
                          segments: int = 10) -> float | None:
    """Jackknife sigma of the arc-length scale s_v over ``segments`` consecutive stretches of knots.

    Per odometry edge, the knots' forward motion (x of X_a^-1 X_b) against the nominal odometry's at the turn scale
    ``s_w``; the scale is their least-squares ratio. Leaving out one stretch at a time, the spread of the ratios
    holds errors correlated within a stretch (wheel slip over seconds) that the graph's marginal counts as
    independent. None when fewer than two stretches drive :data:`MIN_JACKKNIFE_STRETCH_M` or more.
    """
    T = np.asarray(T_knots, dtype=float)
    if T.shape[0] < 2 * segments + 1:
        return None
    z = np.einsum("nij,nj->ni", np.linalg.inv(T[:-1]), T[1:, :, 3])[:, 0]  # forward motion of the knots
    M = EdgeMotions(steps, np.asarray(knot_idx, dtype=int)).at(1.0, s_w)[0]
    m = M[:, 0, 3]
    return _stretch_ratio_jackknife(z, m, segments, MIN_JACKKNIFE_STRETCH_M)


def _stretch_ratio_jackknife(z: np.ndarray, m: np.ndarray, segments: int, min_total: float) -> float | None:
    """Jackknife sigma of the least-squares ratio sum(z m) / sum(m^2) over ``segments`` consecutive stretches of the
    edges. Stretches whose sum |m| is below ``min_total`` (the robot hardly drives or turns there: their ratio is
    noise over noise) take no part; None with fewer than two that do, or with non-finite input."""
    if z.shape != m.shape or not (np.all(np.isfinite(z)) and np.all(np.isfinite(m))):
        return None
    part = np.array_split(np.arange(m.size), segments)
    zm = np.array([np.sum(z[i] * m[i]) for i in part])
    mm = np.array([np.sum(m[i] ** 2) for i in part])
    used = np.array([np.sum(np.abs(m[i])) >= min_total for i in part])
    g = int(np.count_nonzero(used))
    if g < 2:
        return None
    zm, mm = zm[used], mm[used]
    loo = (zm.sum() - zm) / (mm.sum() - mm)
    return float(np.sqrt((g - 1) / g * np.sum((loo - loo.mean()) ** 2)))


MIN_JACKKNIFE_STRETCH_RAD = 0.1  # turned left or right, summed over a stretch's edges


def turn_scale_jackknife(T_knots: np.ndarray, steps: PlanarSteps, knot_idx: np.ndarray,
                         segments: int = 10) -> float | None:
    """Jackknife sigma of the turn scale s_w over ``segments`` consecutive stretches of knots.

    Per odometry edge, the knots' heading change (the yaw of X_a^-1 X_b) against the nominal odometry's; the scale
    is their least-squares ratio. As :func:`speed_scale_jackknife` for the forward motion: the spread of the
    leave-one-stretch-out ratios holds slip (and whatever else bends the turns) correlated within a stretch, which
    the marginal counts as independent edges. None when fewer than two stretches turn
    :data:`MIN_JACKKNIFE_STRETCH_RAD` or more.
    """
    T = np.asarray(T_knots, dtype=float)
    if T.shape[0] < 2 * segments + 1:
        return None
    rel = np.einsum("nji,njk->nik", T[:-1, :3, :3], T[1:, :3, :3])
    z = np.arctan2(rel[:, 1, 0], rel[:, 0, 0])  # the knots' heading change per edge
    m = EdgeMotions(steps, np.asarray(knot_idx, dtype=int)).heading_change
    if z.shape == m.shape and np.all(np.isfinite(z)) and np.all(np.isfinite(m)) and np.any(m):
        # The knots' yaw is known modulo a turn; an edge that turns more than half a turn (sparse knots) is unwrapped
        # around what the odometry's turn at the recording's scale predicts.
        pred = m * float(np.sum(z * m) / np.sum(m * m))
        z = pred + (z - pred + np.pi) % (2.0 * np.pi) - np.pi
    return _stretch_ratio_jackknife(z, m, segments, MIN_JACKKNIFE_STRETCH_RAD)


def frame_jackknife(graph, values: gtsam.Values, n_frames: int, segments: int = 10,
                    steps: dict | None = None) -> np.ndarray | None:
    """Jackknife sigma (7,) of the calibration, in base axes (rotation about base x, y, z in rad, translation along
    them in m, td in s), over ``segments`` consecutive stretches of the camera frames.

    ``graph``'s first ``n_frames`` factors are the frames' reprojection factors in time order (as _build_graph adds
    them: one per frame with points); ``values`` its solution. The graph is linearized once there; leaving out one
    stretch's factors, one Gauss-Newton step (its linear system solved) is that stretch's leave-one-out change of the
    calibration, to first order. The spread of those changes holds errors shared within a stretch, which the
    marginal covariance, counting each frame as independent, does not. None with fewer than two frames per stretch.
    ``steps`` (a dict), when given, gets the step on the whole graph as ``"whole"`` (7,, then the odometry scales'
    when the graph has them): :func:`focal_sensitivity` takes it as its own.
    """
    if segments < 2 or n_frames < 2 * segments:
        return None
    lin = graph.linearize(values)
    C = values.atPose3(KEY_CAM).matrix()
    J = user_axes_jacobian(C[:3, :3])

    def solve(drop: set[int]):
        g = gtsam.GaussianFactorGraph()
        for i in range(lin.size()):
            if i not in drop:
                g.push_back(lin.at(i))
        return g.optimize()

    def step(drop: set[int]) -> np.ndarray:
        d = solve(drop)
        return J @ np.r_[d.at(KEY_CAM), d.at(KEY_TD)]

    whole = solve(set())
    base = J @ np.r_[whole.at(KEY_CAM), whole.at(KEY_TD)]  # ~0 at a converged solution; out of each stretch's step
    if steps is not None:
        steps["whole"] = np.r_[base, whole.at(KEY_SCALE) if values.exists(KEY_SCALE) else np.zeros(0)]
    loo = np.array([step(set(part.tolist())) - base for part in np.array_split(np.arange(n_frames), segments)])
    if not np.all(np.isfinite(loo)):
        return None
    g = loo.shape[0]
    return np.sqrt((g - 1) / g * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0))


def focal_sensitivity(prob: _Problem, rows: np.ndarray, td_bracket: float, opt: RefinementOptions,
                      values: gtsam.Values, graph_args: tuple, graph_kwargs: dict, extra: list,
                      rel: float = 0.01, whole_step: np.ndarray | None = None) -> np.ndarray | None:
    """How far the calibration moves (7,: base axes, as :func:`frame_jackknife`; then the odometry's speed and turn
    scales when the graph has them) for a focal length ``rel`` (relative) longer than the camera model's, to first
    order (:func:`camera_sensitivity`). A focal length errs alike in x and y, so both are scaled."""
    cam = prob.frames.camera
    K = cam.K.copy()
    K[0, 0] *= 1.0 + rel
    K[1, 1] *= 1.0 + rel
    return camera_sensitivity(prob, rows, td_bracket, opt, values, graph_args, graph_kwargs, extra,
                              replace(cam, K=K), whole_step)


def camera_sensitivity(prob: _Problem, rows: np.ndarray, td_bracket: float, opt: RefinementOptions,
                       values: gtsam.Values, graph_args: tuple, graph_kwargs: dict, extra: list,
                       camera: CameraModel, whole_step: np.ndarray | None = None) -> np.ndarray | None:
    """How far the calibration moves (7,: base axes, as :func:`frame_jackknife`; then the odometry's speed and turn
    scales when the graph has them) with ``camera`` in place of the camera model, to first order: one Gauss-Newton
    step from the solution ``values`` on the graph built with it (the same frames, brackets, noise and robust weights;
    ``graph_args`` / ``graph_kwargs`` as :func:`_build_graph` takes them, ``extra`` factors added, e.g. the held
    directions' prior), less the step on the graph as it is (~0 at a converged solution; ``whole_step``, when the
    frame jackknife solved it already). None when a step cannot be solved."""
    other = replace(prob, frames=replace(prob.frames, camera=camera))
    C = values.atPose3(KEY_CAM).matrix()
    J = user_axes_jacobian(C[:3, :3])
    scales = values.exists(KEY_SCALE)

    def step(d) -> np.ndarray:
        return np.r_[J @ np.r_[d.at(KEY_CAM), d.at(KEY_TD)], d.at(KEY_SCALE) if scales else np.zeros(0)]

    steps = [] if whole_step is None else [np.asarray(whole_step, dtype=float)]
    for p in ((prob, other) if whole_step is None else (other,)):
        g, batch, _ = _build_graph(p, rows, td_bracket, opt, *graph_args, **graph_kwargs)
        for f in extra:
            g.add(f)
        with batch.evaluated_at(values, jacobians=True):  # every frame at once (see _levenberg_marquardt)
            lin = g.linearize(values)
        steps.append(step(lin.optimize()))
    if steps[0].size != steps[1].size:
        return None
    move = steps[1] - steps[0]
    return move if np.all(np.isfinite(move)) else None


#: A warning says so when the knots' spacing moves yaw, x, y or td by more than this many times its other sigmas.
KNOT_WARN_FACTOR = 2.0


def _send_solution(on_solution: Callable[[SimpleNamespace], None] | None, values: gtsam.Values,
                   frame_t: np.ndarray, batch: FrameBatch, knot_t: np.ndarray) -> bool:
    """``on_solution`` (see :func:`refine`) called with the solution in ``values`` (and the residuals of the frames
    ``frame_t`` the ``batch`` holds, and the base at the knots ``knot_t``, as the result keeps them); whether it was
    called. What it raises is logged: work beside the refinement must not cost it."""
    if on_solution is None:
        return False
    C = values.atPose3(KEY_CAM).matrix()
    try:
        residual = batch.evaluate_all(values, False).residual.astype(np.float32)
        on_solution(SimpleNamespace(T_base_cam=C, R_base_cam=C[:3, :3], td=float(values.atVector(KEY_TD)[0]),
                                    T_world_board=values.atPose3(KEY_BOARD).matrix(), observability=None,
                                    residual_t=frame_t.copy(), residual_px=residual, knot_t=knot_t.copy(),
                                    T_world_base=np.stack([values.atPose3(knot_key(i)).matrix()
                                                           for i in range(knot_t.size)])))
    except Exception as exc:  # noqa: BLE001
        from ..core.processes import reraise_interrupt

        reraise_interrupt(exc)
        log.warning("after the refinement's solve: %s", exc)
    return True


def _wants_knot_probe(opt: RefinementOptions) -> bool:
    """Whether the refinement asks for the knots' second opinion (:func:`knot_spacing_sensitivity`)."""
    return bool(opt.marginals and opt.knot_rate_hz and opt.knot_sensitivity_factor and opt.knot_sensitivity_factor > 1)


def _start_knot_probe(camera_track: CameraTrack, base_track: BaseTrack, camera: CameraModel, opt: RefinementOptions,
                      td_given: float, td_search: float, knot_tds: tuple[float, float] | None, values: gtsam.Values,
                      prob: _Problem, frozen: list, rejected: np.ndarray, vib_var: float, odo_var, planar_var,
                      anchor: tuple, scale0: tuple[float, float], t_opt: float,
                      detector_var: dict[str, float] | None = None) -> _Beside:
    """The knots' second opinion (:func:`denser_solution`) started from the solution in ``values``: in a second
    process when ``opt.workers`` > 1, else solved when its result is asked for (the same answer)."""
    C = values.atPose3(KEY_CAM).matrix()
    td = float(values.atVector(KEY_TD)[0])
    T_knots = np.stack([values.atPose3(knot_key(i)).matrix() for i in range(prob.knot_t.size)])
    scales = tuple(float(x) for x in values.atVector(KEY_SCALE)) if prob.steps is not None else scale0
    warm = dict(B=values.atPose3(KEY_BOARD).matrix(), knot_t=prob.knot_t, T_world_base=T_knots, odo_var=odo_var,
                planar_var=planar_var, frozen=list(frozen), vib_var=vib_var, adapt=opt.adapt_odometry_noise,
                anchor=anchor, rejected_t=prob.frame_t[rejected], detector_var=dict(detector_var or {}))
    job = _Beside(denser_solution, (camera_track, base_track, camera, opt, td_given, td_search, knot_tds, C, td,
                                    scales, warm), opt.workers > 1, deadline_s=max(300.0, 20.0 * t_opt))
    return job


def knot_warning(change: np.ndarray, spacing: tuple[float, float]) -> str:
    """The warning for an answer that moves with the knots' spacing (``change`` and ``spacing`` (s, this solve's and
    the denser one's) as knot_spacing_sensitivity gives them)."""
    return (f"the answer depends on how the base's path between knots is modelled: with a knot every "
            f"{1e3 * spacing[1]:.0f} ms instead of {1e3 * spacing[0]:.0f} ms yaw moves by "
            f"{np.degrees(change[2]):.2f} deg, the lever arm by {1e3 * change[3]:.0f} / {1e3 * change[4]:.0f} mm "
            f"(x / y) and td by {1e3 * change[6]:.1f} ms; the sigmas hold this. The wheel odometry's heading likely "
            "changes at a few hertz in ways the camera does not see (a vibrating or chattering base, stamps that "
            "jitter); drive more smoothly or on a harder floor to narrow it")


#: Convergence tolerance of the denser knots' solve: only the size of its change is wanted. Against 1e-6 it halves
#: the solve's time (0.43 -> 0.19 s on the 20 s benchmark recording) and moves the change by 1 % (yaw, x) to 5 % (td).
KNOT_PROBE_RELATIVE_TOL = 1e-4


class _Beside:
    """``fn(*args)`` solved in a forked process while this one goes on (``beside``), else here when its result is
    asked for. The result is the same either way; a child that fails, dies or gives no answer within ``deadline_s``
    (a fork can leave a lock held by another thread locked in the child) is replaced by solving it here.
    ``solved_here`` says whether the result came from this process."""

    def __init__(self, fn: Callable, args: tuple, beside: bool, deadline_s: float = 300.0):
        self.fn, self.args, self.proc, self.conn = fn, args, None, None
        self.deadline_s, self.solved_here = float(deadline_s), True
        if not beside:
            return
        import multiprocessing as mp

        send = None
        try:
            ctx = mp.get_context("fork")
            self.conn, send = ctx.Pipe(duplex=False)
            self.proc = ctx.Process(target=_beside_main, args=(send, fn, args, os.getpid()), daemon=True)
            self.proc.start()
        except (OSError, ValueError, RuntimeError, AssertionError) as exc:  # AssertionError: a daemonic process
            log.info("refine: no second process (%s); the second opinion is solved here", exc)
            self.proc = None
            if self.conn is not None:
                self.conn.close()
        finally:
            if send is not None:
                send.close()

    def result(self):
        if self.proc is None:
            return self.fn(*self.args)
        end = time.monotonic() + self.deadline_s
        try:
            while not self.conn.poll(0.2):
                if not self.proc.is_alive() and not self.conn.poll(0):
                    raise EOFError("the process ended without a result")
                if time.monotonic() > end:
                    raise TimeoutError(f"no result within {self.deadline_s:.0f} s")
            ok, value = self.conn.recv()
        except Exception as exc:  # noqa: BLE001 - any trouble with the child: solved here
            ok, value = False, f"{type(exc).__name__}: {exc}"
        finally:
            self.discard()
        if ok:
            self.solved_here = False
            return value
        log.info("refine: the second opinion's process failed (%s); solved here", value)
        return self.fn(*self.args)

    def discard(self) -> None:
        if self.proc is not None:
            if self.proc.is_alive():
                self.proc.terminate()
            self.proc.join(5.0)
            self.conn.close()
            self.proc = None


class _Deferred:
    """A refinement's result with its knots' second opinion, to be finished if it is the one reported."""

    def __init__(self, finish: Callable, job: _Beside, args: tuple):
        self.finish, self.job, self.args = finish, job, args

    def result(self) -> RefinementResult:
        return self.finish(self.job, *self.args)[0]

    def discard(self) -> None:
        self.job.discard()


def _beside_main(conn, fn: Callable, args: tuple, parent_pid: int | None = None) -> None:
    from ..core.processes import end_with_parent

    end_with_parent(parent_pid)  # a daemonic process outlives a parent killed by SIGKILL otherwise
    try:
        out = (True, fn(*args))
    except BaseException as exc:  # noqa: BLE001 - reported to the parent, which solves it itself
        out = (False, f"{type(exc).__name__}: {exc}")
    try:
        conn.send(out)
    except OSError:  # the parent stopped listening (it discarded the job): nothing to say
        pass
    finally:
        conn.close()


def knot_spacing_sensitivity(camera_track: CameraTrack, base_track: BaseTrack, camera: CameraModel,
                             opt: RefinementOptions, td_given: float, td_search: float,
                             knot_tds: tuple[float, float] | None, C: np.ndarray, td: float,
                             scales: tuple[float, float], warm: dict
                             ) -> tuple[np.ndarray | None, tuple[float, float] | None]:
    """|change| (7,) of the calibration (base axes, as :func:`noise_model_sensitivity`) when the refinement that
    ended at ``C``, ``td``, ``scales`` (its board, knots, noise factors, frozen directions, priors' anchors and
    outlier frames in ``warm``, see :func:`_refine_from`) is solved again from there with knots about
    ``opt.knot_sensitivity_factor`` times denser, its noise model adapted again at that spacing (``warm["adapt"]``)
    as the refinement adapts it; and the two knot spacings (s, median). (None, None) when the odometry's samples
    allow no denser knots, or when that solve fails or does not converge (then nothing is added).

    The knots carry the base trajectory; between them it follows the odometry. Denser knots let it follow the camera
    more closely, and where the odometry and the camera disagree at short time scales (a base vibrating in roll and
    pitch, slip, stamps that jitter) the extrinsic and td the data favour move with the spacing, by more than the
    marginals allow. How far they move is an uncertainty of the model itself. Knots sit on odometry samples, so the
    denser spacing is a whole number of samples: with 50 Hz wheels 0.04 s against 0.1 s."""
    return knot_change(denser_solution(camera_track, base_track, camera, opt, td_given, td_search, knot_tds, C, td,
                                       scales, warm), warm["knot_t"], C, td)


def denser_solution(camera_track: CameraTrack, base_track: BaseTrack, camera: CameraModel,
                    opt: RefinementOptions, td_given: float, td_search: float,
                    knot_tds: tuple[float, float] | None, C: np.ndarray, td: float,
                    scales: tuple[float, float], warm: dict) -> SimpleNamespace | None:
    """The solve of :func:`knot_spacing_sensitivity` with the denser knots, started from ``C``, ``td``, ``scales`` and
    ``warm``: its T_base_cam, td, knot_t, iterations, seconds and whether it converged; None when the odometry's
    samples allow no denser knots or the solve fails."""
    dt = float(np.median(np.diff(base_track.t)))
    step = max(1, int(round(1.0 / (float(opt.knot_rate_hz) * dt))))
    # Twice the passes: with denser knots a smaller move of td re-brackets the frames, which takes a pass each.
    denser = replace(opt, knot_rate_hz=float(opt.knot_rate_hz) * float(opt.knot_sensitivity_factor),
                     knot_sensitivity_factor=None, relative_tol=max(opt.relative_tol, KNOT_PROBE_RELATIVE_TOL),
                     max_passes=2 * opt.max_passes)
    if max(1, int(round(1.0 / (denser.knot_rate_hz * dt)))) >= step:
        log.info("refine: the knots are as dense as the odometry's samples allow; no knot-spacing second opinion")
        return None
    try:
        alt = _refine_from(camera_track, base_track, camera, denser, None, C, td, td_given, td_search, scales, None,
                           knot_tds, time.perf_counter(), probe=True, warm=warm)[0]
    except Exception as exc:  # noqa: BLE001 - a second opinion never costs the answer
        from ..core.processes import reraise_interrupt

        reraise_interrupt(exc)
        log.info("refine: the solve with denser knots failed (%s); no knot-spacing second opinion", exc)
        return None
    return SimpleNamespace(T_base_cam=alt.T_base_cam, td=alt.td, knot_t=alt.knot_t, iterations=alt.iterations,
                           seconds=alt.timing["total_s"], converged=alt.converged)


def knot_change(alt: SimpleNamespace | None, knot_t: np.ndarray, C: np.ndarray, td: float
                ) -> tuple[np.ndarray | None, tuple[float, float] | None]:
    """:func:`knot_spacing_sensitivity`'s answer from the denser solve ``alt`` (:func:`denser_solution`) and the
    answer ``C``, ``td`` it is compared with, solved on the knots at ``knot_t``."""
    if alt is None:
        return None, None
    change = noise_model_sensitivity(alt.T_base_cam, alt.td, C, td)
    if not np.all(np.isfinite(change)):
        log.info("refine: the solve with denser knots ended at a non-finite answer; no knot-spacing second opinion")
        return None, None
    if not alt.converged:
        # Where the denser model does not settle, the answer depends on the knots at least as far as it wandered:
        # its last answer is used (leaving the second opinion out here would drop it where it matters most).
        log.info("refine: the solve with denser knots did not converge; its last answer is used")
    spacing = (float(np.median(np.diff(knot_t))), float(np.median(np.diff(alt.knot_t))))
    log.info("refine: with a knot every %.0f ms (%d iterations, %.2f s) the calibration moves by %.3f deg, %.1f mm, "
             "%.2f ms", 1e3 * spacing[1], alt.iterations, alt.seconds,
             np.degrees(np.linalg.norm(change[:3])), 1e3 * np.linalg.norm(change[3:6]), 1e3 * change[6])
    return change, spacing


def noise_model_sensitivity(C: np.ndarray, td: float, C_held: np.ndarray, td_held: float) -> np.ndarray:
    """|change| (7,) of the calibration between the solve under the model's own noise and the adapted one, in base
    axes: rotation about base x, y, z (rad), translation along them (m), td (s)."""
    d_rot = so3_log(C[:3, :3] @ C_held[:3, :3].T)
    return np.abs(np.r_[d_rot, C[:3, 3] - C_held[:3, 3], td - td_held])


def _is_odometry(f) -> bool:
    """An odometry between-factor (plain or with the intrinsics' scale key)."""
    return isinstance(f, gtsam.BetweenFactorPose3) or (
        isinstance(f, gtsam.CustomFactor) and f.dim() == 6 and len(f.keys()) == 3
        and gtsam.Symbol(f.keys()[2]).chr() == ord("s"))


def _odometry_factors(graph) -> list:
    """The odometry between-factors of a graph (plain or with the intrinsics' scale key)."""
    return [graph.at(i) for i in range(graph.size()) if _is_odometry(graph.at(i))]


def odometry_noise_factor(graph, values: gtsam.Values, split: bool = False, tilt: bool = False) -> float | np.ndarray:
    """How much more variance the odometry's planar errors (heading, along, across; whitened) have than their model
    gives them: the median of their squares over the chi-square(1) median 0.455 (robust to a few resets or bumps;
    at least 1) times their integrated autocorrelation time over the edges (an error correlated over k edges adds
    up like k times its variance). Measured at a solution under the model's own noise. With ``split``, two factors:
    the heading's and the two distances' (along, across); with ``tilt`` also a third, the roll's and pitch's (the
    floor's shape between knots)."""
    w = np.array([f.whitenedError(values)[:5] for f in _odometry_factors(graph)])
    if len(w) < 10:
        return np.ones(2 + bool(tilt)) if split else 1.0
    out = []
    groups = (w[:, 2:3], w[:, 3:5]) if split else (w[:, 2:5],)
    for x in groups + ((w[:, :2],) if split and tilt else ()):
        msq = float(np.median(np.square(x)) / 0.455)
        out.append(max(msq, 1.0) * autocorrelation_time(x))
    return np.array(out) if split else out[0]


def influence_variance(graph, values: gtsam.Values, series: list[tuple[list[int], list[int]]],
                       keys: tuple[int, ...]) -> list[tuple[np.ndarray, np.ndarray]]:
    """How much variance each series of factors adds to the estimate of ``keys``: what the graph counts for it and
    what its residuals at the solution ``values`` say. ``series``: per series, the graph indices of its factors in
    time order and the rows of each factor to take. The components are those of ``keys``' tangent spaces (in
    order). Returns per series (measured, counted), two covariance matrices.

    A factor's whitened error e_k moves the estimate by G A_k^T e_k (G: the estimate's rows of the inverse
    information matrix; A_k: the factor's whitened Jacobian). The graph counts sum_k g_k g_k^T for the series
    (g_k = G A_k^T, unit noise, independent); the graph's covariance is the sum of that over all its factors.
    Measured: the same sum with the errors of each row an AR(1) process over the series, whose variance (robust
    mean square) and integrated autocorrelation time tau are the residuals' at the solution:
    sum_{k,l} g_k g_l^T v a^|k-l|, a = (tau - 1) / (tau + 1). For a mean (constant gains) this is v tau times
    what the graph counts, as the residuals' autocorrelation time says; where the gains turn over the series (the
    heading turning a floor's tilt about the camera), the correlated errors' pushes cancel and it is much less.
    The correlation is modelled rather than summed from the residuals' products: the part of the errors the
    estimate absorbed is not in the residuals, and a sum over few effective samples would miss it."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    lin = graph.linearize(values)
    zero = values.zeroVectors()
    start, n = {}, 0
    for k in sorted(int(k) for k in values.keys()):  # the sparse Jacobian's columns: keys in order
        start[k] = n
        n += zero.at(k).size
    first = np.zeros(lin.size() + 1, dtype=np.int64)
    for f in range(lin.size()):
        first[f + 1] = first[f] + lin.at(f).rows()
    S = lin.sparseJacobian_()  # (i, j, s), 1-based, the error vector as the last column
    aug = sp.csr_matrix((S[2], (S[0].astype(np.int64) - 1, S[1].astype(np.int64) - 1)),
                        shape=(int(first[-1]), n + 1))
    A, b = aug[:, :n].tocsc(), aug[:, n].toarray().ravel()
    cols = np.concatenate([start[int(k)] + np.arange(zero.at(int(k)).size) for k in keys])
    E = np.zeros((n, cols.size))
    E[cols, np.arange(cols.size)] = 1.0
    X = splu((A.T @ A).tocsc()).solve(E)  # the inverse information's columns at ``keys``
    M = np.asarray(A @ X)  # each row's gain on the estimate
    out = []
    for idx, rows in series:
        r = np.array([first[f] + np.asarray(rows) for f in idx], dtype=np.int64).reshape(len(idx), -1)
        g = M[r]  # (K, rows, components)
        counted = np.einsum("kra,krb->ab", g, g)
        tau = autocorrelation_time(b[r])
        a = (tau - 1.0) / (tau + 1.0)
        measured = np.zeros_like(counted)
        for c in range(r.shape[1]):
            v = float(np.median(b[r[:, c]] ** 2) / 0.455)  # robust to a few bumps, like the noise factors
            measured += v * (g[:, c].T @ ar1_filter(g[:, c], a))
        out.append((0.5 * (measured + measured.T), counted))
    return out


def ar1_filter(x: np.ndarray, a: float) -> np.ndarray:
    """sum_l a^|k-l| x_l for each k (rows of ``x``, time first): the AR(1) correlation matrix times ``x``, by a
    forward and a backward first-order recursion."""
    x = np.asarray(x, dtype=float)
    fwd, bwd = x.copy(), x.copy()
    for k in range(1, len(x)):
        fwd[k] += a * fwd[k - 1]
    for k in range(len(x) - 2, -1, -1):
        bwd[k] += a * bwd[k + 1]
    return fwd + bwd - x


def tilt_influence_correction(graph, values: gtsam.Values, keys: tuple[int, ...]) -> tuple[np.ndarray, dict]:
    """What the floor's tilt adds to the joint covariance of ``keys`` (tangent axes) beyond what ``graph`` counts
    for it: for the planar prior's tilt rows and the odometry edges' roll and pitch rows, the covariance their
    residuals add (measured) minus what the graph counts (influence_variance); added to the graph's covariance it
    takes the place of their share. Also, per series, the ratio of the two on the camera's roll and pitch."""
    planar = [i for i in range(graph.size()) if _is_planar(graph.at(i))]
    edges = [i for i in range(graph.size()) if _is_odometry(graph.at(i))]
    names, series = [], []
    for name, idx, rows in (("planar", planar, [1, 2]), ("edges", edges, [0, 1])):
        if len(idx) >= 10:
            names.append(name)
            series.append((idx, rows))
    if not series:
        return np.zeros((sum(values.zeroVectors().at(int(k)).size for k in keys),) * 2), {}
    got = influence_variance(graph, values, series, keys=keys)
    J = user_axes_jacobian(values.atPose3(KEY_CAM).rotation().matrix())[:2]  # roll, pitch of the tangent's first 7
    ratio = {}
    for name, (m, c) in zip(names, got, strict=True):
        ratio[name] = float(np.trace(J @ m[:7, :7] @ J.T) / max(float(np.trace(J @ c[:7, :7] @ J.T)), 1e-300))
    return sum(m - c for m, c in got), ratio


def _is_planar(f) -> bool:
    """A planar factor (height, roll, pitch of one knot)."""
    return isinstance(f, gtsam.CustomFactor) and f.dim() == 3 and len(f.keys()) == 1


def floor_tilt_rms_deg(values: gtsam.Values, n_knots: int) -> float | None:
    """How far the base tilts from the floor's plane along the drive: the RMS over the knots of their roll and pitch
    (deg) at the solution, about their mean. Near 0.03 deg on a flat floor (what the camera resolves); an undulating
    floor shows its slope (0.2-0.6 deg on the built 0.3-0.6 deg floors)."""
    T = [values.atPose3(knot_key(k)).matrix() for k in range(n_knots) if values.exists(knot_key(k))]
    if len(T) < 3:
        return None
    T = np.array(T)
    t = np.stack([T[:, 2, 1], -T[:, 2, 0]], axis=1)
    return float(np.degrees(np.sqrt(np.mean(np.sum((t - t.mean(axis=0)) ** 2, axis=1)))))


def planar_noise_factors(graph, values: gtsam.Values) -> np.ndarray:
    """As odometry_noise_factor for the planar factors (height; roll and pitch together): how much more variance
    the knots' departures from the floor plane have than the prior gives them, magnitude x autocorrelation over the
    knots (a floor's undulation tilts many consecutive knots alike)."""
    w = [graph.at(i).whitenedError(values) for i in range(graph.size()) if _is_planar(graph.at(i))]
    if len(w) < 10:
        return np.ones(2)
    w = np.array(w)
    out = []
    for cols in ([0], [1, 2]):
        x = w[:, cols]
        msq = max(float(np.median(np.square(x)) / 0.455), 1.0)
        out.append(msq * autocorrelation_time(x))
    return np.array(out)


def correlation_inflation(graph, batch: FrameBatch, values: gtsam.Values, opt: RefinementOptions,
                          sigma_px: float | np.ndarray | None = None) -> dict:
    """Autocorrelation times of the reprojection residuals (over frames) and of the whitened odometry residuals
    (over edges), each capped at ``max_inflation``: the covariance is that of the graph whose reprojection and
    odometry variances are multiplied by them (information / effective-sample-size correction per source)."""
    sig = np.asarray(opt.sigma_px if sigma_px is None else sigma_px, dtype=float)
    r = batch.evaluate_all(values, False).residual / (sig[:, None, None] if sig.ndim else sig)  # (m, N, 2)
    tau_rep = autocorrelation_time(r.reshape(r.shape[0], -1))
    odo = [f.whitenedError(values) for f in _odometry_factors(graph)]
    tau_odo = autocorrelation_time(np.array(odo)) if len(odo) >= 4 else 1.0
    return {"reprojection_autocorrelation_time": float(np.clip(tau_rep, 1.0, opt.max_inflation)),
            "odometry_autocorrelation_time": float(np.clip(tau_odo, 1.0, opt.max_inflation))}


def disagreement_with_seed(res_T: np.ndarray, res_td: float, cov_base: np.ndarray, seed_T: np.ndarray,
                           seed_td: float, opt: RefinementOptions, limit: float = 3.0,
                           rotation: bool = True) -> dict[str, float]:
    """Quantities (roll, pitch, yaw, td) on which the refinement and its seed differ by more than ``limit``
    combined sigmas (the refinement's and the assumed ``seed_sigma_*`` of the closed form), in those sigmas.
    Without ``rotation`` only td is compared (a closed form solved at a wrong time offset is no reference for the
    rotation)."""
    d = so3_log(res_T[:3, :3] @ seed_T[:3, :3].T)  # base axes
    out = {}
    for k, ax in enumerate(("roll", "pitch", "yaw") if rotation else ()):
        z = abs(float(d[k])) / float(np.sqrt(cov_base[k, k] + opt.seed_sigma_rot**2))
        if z > limit:
            out[ax] = round(z, 2)
    z = abs(res_td - seed_td) / float(np.sqrt(cov_base[6, 6] + opt.seed_sigma_td**2))
    if z > limit:
        out["td"] = round(z, 2)
    return out


def odometry_given_calibration(joint: np.ndarray, k: np.ndarray, td_floor: float) -> np.ndarray:
    """The joint (9 x 9) covariance of (calibration in base axes, s_v, s_w) once the calibration's reported
    uncertainty is larger than the marginal's: the second opinions (per-axis factors ``k`` >= 1) and the time
    offset's model floor ``td_floor`` carried over to the odometry intrinsics through their regression on the
    calibration.

    The intrinsics were estimated together with the extrinsic: where the two are correlated (the lever arm along
    the base's forward axis and the turn scale, through the camera's sideways motion in turns), an extrinsic that
    is more uncertain than the marginal says makes the intrinsics more uncertain too. With B = S_sc S_cc^-1 (the
    regression of the intrinsics on the calibration), S_ss gains B (S_cc' - S_cc) B^T, S_sc becomes B S_cc', where
    S_cc' = K S_cc K + td_floor^2 on td, S_cc = ``joint[:7, :7]`` (the marginal the factors were measured against).
    """
    J = np.array(joint, dtype=float)
    S_cc = 0.5 * (J[:7, :7] + J[:7, :7].T)
    k = np.asarray(k, dtype=float)
    S_new = S_cc * np.outer(k, k)
    S_new[6, 6] += (k[6] * td_floor) ** 2  # the reported td variance: the floor is added before k is measured
    delta = S_new - S_cc
    if not np.any(delta) or not np.all(np.isfinite(delta)):
        return J
    # Solved in the calibration's own scale (the axes span metres, radians and seconds).
    d = np.sqrt(np.maximum(np.diag(S_cc), 1e-300))
    B = np.linalg.lstsq(S_cc / np.outer(d, d), J[7:, :7].T / d[:, None], rcond=1e-12)[0].T / d[None, :]
    out = J.copy()
    # K S K - S is indefinite when correlated axes are inflated unequally; only its positive part adds uncertainty
    lam, V = np.linalg.eigh(0.5 * (delta + delta.T) / np.outer(d, d))
    delta_p = (V * np.maximum(lam, 0.0)) @ V.T * np.outer(d, d)
    out[7:, 7:] = J[7:, 7:] + B @ delta_p @ B.T
    out[7:, :7] = B @ S_new
    out[:7, 7:] = out[7:, :7].T
    out[:7, :7] = S_new
    return out


def _check_scale(scale) -> tuple[float, float]:
    if scale is None:
        return (1.0, 1.0)
    s = np.asarray(scale, dtype=float).ravel()
    if s.size != 2 or not np.all(np.isfinite(s)) or np.any(s <= 0.2) or np.any(s >= 5.0):
        raise InputError(f"seed_odometry_scale must be two finite factors (speed, turn rate) in (0.2, 5), got {scale}")
    return float(s[0]), float(s[1])


def odometry_report(values: gtsam.Values, joint: np.ndarray | None, info: dict, opt: RefinementOptions,
                    seed: tuple[float, float], joint_data: np.ndarray | None = None) -> dict:
    """The odometry intrinsics the refinement estimated: scale factors, effective wheel radius and track width
    (when the nominal ones are known), their sigmas and how much the data (not the prior) determined them
    (judged on ``joint_data``, the covariance without the model floor, when given).

    ``wheel_radius = r0 s_v`` and ``track_width = b0 s_v / s_w`` (the closed form's definition). Status per
    intrinsic as for the calibration: posterior / prior sigma <= 0.1 observable, >= 0.5 unobservable.
    """
    s = values.atVector(KEY_SCALE)
    s_v, s_w = float(s[0]), float(s[1])
    out: dict = {"speed_scale": s_v, "turn_scale": s_w, "seed_speed_scale": seed[0], "seed_turn_scale": seed[1],
                 "wheel_radius_model_sigma_rel": float(opt.speed_scale_model_sigma)}
    S = None if joint is None else joint[7:, 7:]
    if S is not None:
        out["speed_scale_sigma"] = float(np.sqrt(S[0, 0]))
        out["turn_scale_sigma"] = float(np.sqrt(S[1, 1]))
    r0, b0 = info.get("wheel_radius"), info.get("track_width")
    if r0 and b0:
        out["wheel_radius_nominal_m"] = float(r0)
        out["track_width_nominal_m"] = float(b0)
        out["wheel_radius_m"] = float(r0 * s_v)
        out["track_width_m"] = float(b0 * s_v / s_w)
        if S is not None:
            jb = np.array([b0 / s_w, -b0 * s_v / s_w**2])
            out["wheel_radius_sigma_m"] = float(r0 * np.sqrt(S[0, 0]))
            out["track_width_sigma_m"] = float(np.sqrt(jb @ S @ jb))
    if S is not None:
        from .observability import OBSERVABLE_RATIO, UNOBSERVABLE_RATIO

        if joint_data is not None:
            S = joint_data[7:, 7:]

        def status(ratio: float) -> str:
            return "observable" if ratio <= OBSERVABLE_RATIO else "unobservable" if ratio >= UNOBSERVABLE_RATIO \
                else "weak"

        # Relative sigma of the radius (= that of s_v) and of the track (s_v / s_w) against their priors.
        rel_b = float(np.sqrt(np.array([1 / s_v, -1 / s_w]) @ S @ np.array([1 / s_v, -1 / s_w])))
        out["status"] = {"wheel_radius": status(float(np.sqrt(S[0, 0])) / opt.speed_scale_prior_sigma),
                         "track_width": status(rel_b / opt.turn_scale_prior_sigma)}
    return out


def _prior_notes(opt: RefinementOptions, frozen: list[np.ndarray], held: list[dict] | None = None) -> dict[str, str]:
    notes: dict[str, str] = {}
    if opt.camera_height is not None:
        notes["z"] = f"Camera height is held by the measured-height prior ({opt.camera_height:.3f} m)."
    if opt.board_height is not None or opt.board_vertical:
        notes["z"] = (notes.get("z", "") + " The board-on-the-floor prior informs the camera height through the "
                      "board.").strip()
    if opt.rotation_prior_sigma is not None:
        for ax in ("roll", "pitch", "yaw"):
            deg = np.degrees(opt.rotation_prior_sigma)
            notes[ax] = f"A closed-form rotation prior (sigma {deg:.2g} deg) is active."
    from ..gate import _sigma_text

    for f in frozen:
        share = (f / np.linalg.norm(f)) ** 2
        ax = AXES[int(np.argmax(share))]
        sigma = held_weakly(held or [], ax)
        if sigma is not None:
            # Determined, but too weakly to be used: say how well, so that "more data" reads as the remedy.
            notes[ax] = (notes.get(ax, "") + " Held at the seed value during the solve: the data determine it only "
                         f"to about {_sigma_text(ax, sigma)} (a direction the data determine worse than "
                         f"{opt.freeze_ratio:g} of the prior's sigma is held). A longer drive with more turning in "
                         "front of the board determines it better"
                         + (" (a calibration writes z as 0: unknown)." if ax == "z" else ".")).strip()
            continue
        notes[ax] = (notes.get(ax, "") + " Not observable: held at the seed value during the solve"
                     + (" (a calibration writes z as 0: unknown)." if ax == "z" else ".")).strip()
    return notes
