"""SciPy's robust losses, for the bundle adjustment's own Levenberg-Marquardt."""

from __future__ import annotations

import numpy as np

from camnet.model.methods import Loss


def robust_loss(z: np.ndarray, loss: Loss) -> tuple[np.ndarray, np.ndarray]:
    """SciPy's robust losses of a squared, scaled residual z: (rho(z), rho'(z))."""
    if loss == Loss.LINEAR:
        return z, np.ones_like(z)
    if loss == Loss.HUBER:
        big = z > 1.0
        s = np.sqrt(np.where(big, z, 1.0))
        return np.where(big, 2.0 * s - 1.0, z), np.where(big, 1.0 / s, 1.0)
    if loss == Loss.SOFT_L1:
        s = np.sqrt(1.0 + z)
        return 2.0 * (s - 1.0), 1.0 / s
    if loss == Loss.CAUCHY:
        return np.log1p(z), 1.0 / (1.0 + z)
    raise ValueError(f"unknown loss {loss!r}; expected one of {tuple(x.value for x in Loss)}")
