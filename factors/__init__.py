"""Custom GTSAM factors (residuals with analytic Jacobians) used by plsgraph.refine.graph."""
