"""Standalone GTSAM factors (``gtsam.CustomFactor`` residuals with analytic Jacobians) for camera-on-robot
calibration: board reprojection with a time offset (``reprojection``), odometry between-factors (``odometry``), a
planar-motion prior (``planar``) and calibration priors (``priors``). Needs gtsam and numpy only; ``lie`` holds the
SO(3)/SE(3) maps and Jacobians they share."""
