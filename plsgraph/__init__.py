"""plsgraph: event camera to wheel-odometry extrinsic and time-offset calibration for ground robots."""

__version__ = "0.1.0"
