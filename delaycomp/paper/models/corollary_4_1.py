"""Corollary 4.1: the unicycle with continuous input and a smooth time-periodic stabilizer.

The nominal feedback is Pomet's smooth, 2 pi-periodic law for the nonholonomic integrator
(1.4) (J.-B. Pomet, "Explicit design of time-varying stabilizing control laws for a class
of controllable systems without drift", Systems & Control Letters 18 (1992) 147-158; its
three-state example), with ``e = x1 + x2 cos t``::

    k1(t, x) = x2 sin t - e,      k2(t, x) = -(e x1 cos t + x1 x2 + x3)

``V = ((x1 + x2 cos t)^2 + x2^2 + x3^2) / 2`` decreases as ``V' = -e^2 - k2^2``; the
periodic LaSalle argument gives uniform global asymptotic stability. Convergence is only
polynomial (about ``|x| ~ t^(-1/2)``). The unicycle's inputs follow (4.8): ``omega = k2``,
``v = k1 + x2 omega`` in the coordinates (4.2) of the controller's state ``z``. The
predictor (4.7) and the plant step are the exact unicycle flow for held inputs.
"""

import math

import numpy as np

from delaycomp.paper.models import unicycle
from delaycomp.paper.models.unicycle import f, predictor, step  # noqa: F401  (model interface)

STATES = unicycle.STATES
INPUTS = unicycle.INPUTS
CONTROL = "continuous"
BATCH = True  # f, k and step also take a batch: x of shape (3, P), u (2, P), t (P,)


def pomet(t, x1, x2, x3):
    """Pomet's law ``(k1, k2)`` for the nonholonomic integrator (1.4)."""
    if np.ndim(t) >= 1:  # a batch
        c = np.cos(t)
        e = x1 + x2 * c
        return x2 * np.sin(t) - e, -(e * x1 * c + x1 * x2 + x3)
    c = math.cos(t)
    e = x1 + x2 * c
    return x2 * math.sin(t) - e, -(e * x1 * c + x1 * x2 + x3)


def lyapunov(t, x1, x2, x3):
    return 0.5 * ((x1 + x2 * math.cos(t)) ** 2 + x2 * x2 + x3 * x3)


def k(t, x, p):
    x1, x2, x3 = unicycle.chained(x)
    k1, k2 = pomet(t, x1, x2, x3)
    return np.array([k1 + x2 * k2, k2])  # (4.8) via (4.3)
