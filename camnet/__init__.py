"""camnet: true-to-scale auto calibration of camera networks."""

__version__ = "0.1.0"
