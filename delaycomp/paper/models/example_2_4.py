"""Example 2.4: the strict-feedforward system (2.15) with continuous input.

    x1' = x2 + x3^2,   x2' = x3 + x3 u,   x3' = u

Nominal feedback: (2.18) corrected as in the errata (``- (1/8) x3^3`` inside the bracket;
the printed ``- (1/4) x3^3`` is kept as ``law = "printed"``, which is not globally
stabilizing). Predictor: the closed form (2.16)-(2.17), evaluated exactly for a
piecewise-constant input history; the exact plant step is the same map over one segment.
"""

import numpy as np

STATES = ("x1", "x2", "x3")
INPUTS = ("u",)
CONTROL = "continuous"
PARAMETERS = {"law": "corrected"}
BATCH = True  # f, k and step also take a batch: x of shape (3, P), u (1, P), h (P,)
LAWS = ("corrected", "printed")
CHOICES = {"law": LAWS}


def f(x, u, p):
    _, x2, x3 = x
    v = u[0]
    return np.array([x2 + x3 * x3, x3 + x3 * v, v])


def k(t, x, p):
    """(2.18); ``law = "corrected"`` (errata item 1) or ``"printed"``."""
    x1, x2, x3 = x
    cubic = 1.0 / 8.0 if p.get("law", "corrected") == "corrected" else 1.0 / 4.0
    bracket = (-4.0 - x1 - 2.0 * x2 + 0.5 * x3 + 0.5 * x2 * x3 + 0.625 * x3**2
               - cubic * x3**3 - 0.375 * (x2 - 0.5 * x3**2) ** 2)
    return np.array([-x1 - 3.0 * x2 - 0.375 * x2**2 + 0.75 * x3 * bracket])


def predictor(x, segments, p):
    """(2.16)-(2.17) with ``U(s) = int_{-r-tau}^s u``, integrated exactly segment by segment.

    Needed integrals over the window ``[-D, 0)``: ``IU = int U``, ``IU2 = int U^2``,
    ``J = int (1 + u) U`` and ``IG = int_{-D}^0 int_{-D}^s (1 + u(w)) U(w) dw ds``.
    """
    x1, x2, x3 = (float(v) for v in x)
    D = U = IU = IU2 = J = IG = 0.0
    for d, u in segments:
        v = float(np.ravel(u)[0])
        IG += J * d + (1.0 + v) * (U * d * d / 2.0 + v * d**3 / 6.0)
        IU += U * d + v * d * d / 2.0
        IU2 += U * U * d + U * v * d * d + v * v * d**3 / 3.0
        J += (1.0 + v) * (U * d + v * d * d / 2.0)
        U += v * d
        D += d
    return np.array([
        x1 + D * x2 + D * x3 * x3 + 0.5 * D * D * x3 + 3.0 * x3 * IU + IG + IU2,
        x2 + D * x3 + x3 * U + J,
        x3 + U,
    ])


def step(x, u, h, p):
    """The predictor over one segment: its terms with ``U = 0`` at the start (the same
    arithmetic as ``predictor`` of one segment), for a point or a batch, and without
    ``float()``, so that delaycomp.fmu.translate traces it."""
    x1, x2, x3 = x
    v, d = u[0], h
    IG = (1.0 + v) * (v * d**3 / 6.0)
    IU = v * d * d / 2.0
    IU2 = v * v * d**3 / 3.0
    J = (1.0 + v) * (v * d * d / 2.0)
    U = v * d
    return np.array([
        x1 + d * x2 + d * x3 * x3 + 0.5 * d * d * x3 + 3.0 * x3 * IU + IG + IU2,
        x2 + d * x3 + x3 * U + J,
        x3 + U,
    ])
