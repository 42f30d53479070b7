"""The factor library's error type."""


class FactorInputError(ValueError):
    """Data or settings handed to a factor builder are inconsistent (shapes, sigmas, names)."""
