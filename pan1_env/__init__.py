"""pan1-env: multi-arm PAn−1 formation control with robust-CBF safety."""

__version__ = "0.1.0"
