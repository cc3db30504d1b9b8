"""Proposition 4.2: the unicycle under zero-order hold on (v, omega), dead-beat.

As printed, (4.9)-(4.11) holds ``(v, omega)`` constant, which is not holding ``(u1, u2)``:
no dead-beat, and some initial states diverge (errata item 2). ``law = "corrected"`` (the
default) is the errata's zero-order-hold law for ``(v, omega)`` itself, in the coordinates
(4.2) of the predicted state ``(x1, x2, x3)``:

- ``x2 != 0``: ``a = min(sqrt|x2|, pi/2)``, ``b = -a (x1 sin a + x2 cos a) / (1 - cos a)``,
  ``(v, omega) = (b/T, a/T)``, which makes ``x2(T) = 0``;
- else ``x1 != 0``: ``(v, omega) = (-x1/T, 0)``;
- else: ``(v, omega) = (0, -x3/T)``.

Dead-beat in 3T without delay. ``law = "printed"`` is (4.9) with (4.10)-(4.11). The sets
are classified with scaled tolerances (``SET_TOL * max(1, |x|)`` for linear quantities,
``SET_TOL * max(1, |x|^2)`` for quadratic ones): exact ``== 0`` tests fail in floating point
(errata, implementation points).
"""

import math

import numpy as np

from delaycomp.paper.models import unicycle
from delaycomp.paper.models.unicycle import (  # noqa: F401  (f, predictor, step: the interface)
    f,
    predictor,
    select,
    step,
)

STATES = unicycle.STATES
INPUTS = unicycle.INPUTS
CONTROL = "zoh"
PARAMETERS = {"law": "corrected"}
LAWS = ("corrected", "printed")
CHOICES = {"law": LAWS}
SET_TOL = 1e-12
BATCH = True  # f, k and step also take a batch: x of shape (3, P), u (2, P), p["T"] (P,)


def _tols(x1, x2, x3):
    """(linear, quadratic) set tolerances for the state (x1, x2, x3).

    ``select(y > 1.0, y, 1.0)`` is Python's ``max(1.0, y)`` (NaN included), written so that
    delaycomp.fmu.translate traces it (no Python branch on the state)."""
    sq = x1 * x1 + x2 * x2 + x3 * x3
    root = math.sqrt(sq)
    return SET_TOL * select(root > 1.0, root, 1.0), SET_TOL * select(sq > 1.0, sq, 1.0)


def corrected(x1, x2, x3, T):
    """The corrected law at a point.

    Written so that delaycomp.fmu.translate traces it: the three sets are chosen with
    ``select`` (``np.where`` for symbols), not ``if``, and
    ``min`` is a ``select`` too; ``math``'s functions stay. Every set's values are computed
    as before (``1 - cos a``, the first set's denominator, is replaced by 1 where that set
    is not taken: ``x2 = 0`` must not divide by zero): the set taken gives the same
    numbers as the former ``if`` version, bit for bit."""
    tol, _ = _tols(x1, x2, x3)
    c1 = abs(x2) > tol
    c2 = abs(x1) > tol
    root = math.sqrt(abs(x2))
    a = select(math.pi / 2 < root, math.pi / 2, root)  # min(root, pi/2)
    b = -a * (x1 * math.sin(a) + x2 * math.cos(a)) / select(c1, 1.0 - math.cos(a), 1.0)
    return (select(c1, b / T, select(c2, -x1 / T, 0.0)),
            select(c1, a / T, select(c2, 0.0, -x3 / T)))


def printed(x1, x2, x3, T):
    """(4.9) in the order C3, C2, C1 with a scaled tolerance; then (4.10)-(4.11).

    The sets are chosen with ``select``, not ``if``, so
    that delaycomp.fmu.translate traces it; C2's denominator is replaced by 1 where C2 is not
    taken (``x1 = x3 = 0`` must not divide by zero): the set taken gives the same numbers
    as the former ``if`` version, bit for bit."""
    lin, quad = _tols(x1, x2, x3)
    c3 = abs(2 * x2 - x1 * x3) <= quad
    c2 = np.logical_and(abs(x2) <= lin, abs(x1 * x3) > quad)
    den = select(c2, T * (x1 * x1 + x3 * x3), 1.0)
    root = math.sqrt(abs(x2))
    k1 = select(c3, -x1 / T, select(c2, -x1 * x3 * x3 / den,
                                    -2.0 / T * math.copysign(root, x2) - 2.0 / T * x1))
    k2 = select(c3, -x3 / T, select(c2, x3 * x1 * x1 / den, root / T))
    return k1 + x2 * k2, k2  # v = u1 + x2 omega (4.3)


def corrected_batch(x1, x2, x3, T):
    """``corrected`` for arrays of points (the same sets, chosen with ``np.where``)."""
    tol = SET_TOL * np.maximum(1.0, np.sqrt(x1 * x1 + x2 * x2 + x3 * x3))
    c1 = np.abs(x2) > tol
    c2 = ~c1 & (np.abs(x1) > tol)
    a = np.minimum(np.sqrt(np.abs(x2)), math.pi / 2)
    b = -a * (x1 * np.sin(a) + x2 * np.cos(a)) / np.where(c1, 1.0 - np.cos(a), 1.0)
    v = np.where(c1, b / T, np.where(c2, -x1 / T, 0.0))
    omega = np.where(c1, a / T, np.where(c2, 0.0, -x3 / T))
    return v, omega


def printed_batch(x1, x2, x3, T):
    """``printed`` for arrays of points."""
    sq = x1 * x1 + x2 * x2 + x3 * x3
    lin, quad = SET_TOL * np.maximum(1.0, np.sqrt(sq)), SET_TOL * np.maximum(1.0, sq)
    c3 = np.abs(2 * x2 - x1 * x3) <= quad
    c2 = ~c3 & (np.abs(x2) <= lin) & (np.abs(x1 * x3) > quad)
    den = np.where(c2, T * (x1 * x1 + x3 * x3), 1.0)
    root = np.sqrt(np.abs(x2))
    k1 = np.where(c3, -x1 / T, np.where(c2, -x1 * x3 * x3 / den,
                                        -2.0 / T * np.copysign(root, x2) - 2.0 / T * x1))
    k2 = np.where(c3, -x3 / T, np.where(c2, x3 * x1 * x1 / den, root / T))
    return k1 + x2 * k2, k2


def k(x, p):
    x1, x2, x3 = unicycle.chained(x)
    corr = p.get("law", "corrected") == "corrected"
    if np.ndim(x) == 2:
        return np.array((corrected_batch if corr else printed_batch)(x1, x2, x3, p["T"]))
    law = corrected if corr else printed
    return np.array(law(x1, x2, x3, p["T"]))
