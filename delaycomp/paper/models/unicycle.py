"""The unicycle (4.1) and its exact flow under constant inputs (shared by Section 4's models).

    x' = v cos(theta),   y' = v sin(theta),   theta' = omega

Under constant ``(v, omega)`` for a time ``s``: ``theta+ = theta + omega s`` and
``(x, y)+ = (x, y) + v s sinc(omega s / 2) (cos, sin)(theta + omega s / 2)`` (errata), so the
predictor (4.5)/(4.12) over a piecewise-constant history is a composition of exact steps.
``chained`` is the coordinate change (4.2) to the nonholonomic integrator (1.4).
"""

import math

import numpy as np

STATES = ("x", "y", "theta")
INPUTS = ("v", "omega")


def dynamics(s, u):
    if np.ndim(s) == 2:  # a batch: (3, P)
        return np.array([u[0] * np.cos(s[2]), u[0] * np.sin(s[2]), u[1]])
    return np.array([u[0] * math.cos(s[2]), u[0] * math.sin(s[2]), u[1]])


def select(cond, a, b):
    """``a`` where ``cond`` else ``b``, for one point: a Python choice of the very value
    (its type and its NaN too) for a number, ``np.where`` (an ``if_else``) for the CasADi
    symbol that delaycomp.fmu.translate traces. Both ``a`` and ``b`` are computed: guard what
    the branch not taken would divide by."""
    if isinstance(cond, (bool, np.bool_)):
        return a if cond else b
    return np.where(cond, a, b)


def flow(s, u, h):
    """The exact step of (4.1) from ``s`` over ``h`` with ``u = (v, omega)`` held.

    For a point it is written so that delaycomp.fmu.translate traces it (the plant's ``step``
    in C): no ``float()`` of the input and no Python ``if`` on it; ``sinc`` (1 where
    ``omega h / 2 == 0``) is chosen with ``np.where``, its denominator guarded so that the
    branch not taken never divides by zero. ``math``'s functions stay (the tracer accepts
    them; numpy's may differ from them in the last bit), so a point's arithmetic is the
    former ``float()`` and ``if`` version's, bit for bit.
    """
    if np.ndim(s) == 2:  # a batch: s (3, P), u (2, P), h (P,)
        v, w = u[0], u[1]
        half = 0.5 * w * h
        still = half == 0.0
        sinc = np.where(still, 1.0, np.sin(half) / np.where(still, 1.0, half))
        heading = s[2] + half
        return np.array([s[0] + v * h * sinc * np.cos(heading),
                         s[1] + v * h * sinc * np.sin(heading), s[2] + w * h])
    v, w = np.asarray(u)[:2].tolist()  # Python floats (symbols when traced), as float() gave
    half = 0.5 * w * h
    still = half == 0.0
    sinc = select(still, 1.0, math.sin(half) / select(still, 1.0, half))
    heading = s[2] + half
    return np.array([s[0] + v * h * sinc * math.cos(heading),
                     s[1] + v * h * sinc * math.sin(heading), s[2] + w * h])


def predict(s, segments):
    s = np.asarray(s, dtype=float)
    for d, u in segments:
        if d > 0:
            s = flow(s, np.ravel(u), d)
    return s


def chained(s):
    """(4.2): ``x1 = x cos + y sin``, ``x2 = x sin - y cos``, ``x3 = theta``."""
    if np.ndim(s) == 2:
        c, sn = np.cos(s[2]), np.sin(s[2])
        return np.array([s[0] * c + s[1] * sn, s[0] * sn - s[1] * c, s[2]])
    c, sn = math.cos(s[2]), math.sin(s[2])
    return np.array([s[0] * c + s[1] * sn, s[0] * sn - s[1] * c, s[2]])


# The model-interface functions shared by the unicycle models (Corollary 4.1, Prop. 4.2).
def f(x, u, p):
    return dynamics(x, u)


def step(x, u, h, p):
    return flow(x, u, h)


def predictor(x, segments, p):
    return predict(x, segments)
