"""Example 3.8: the 2-D strict-feedforward system (3.27) under zero-order hold.

    x1' = x2 + p(x2) u,   x2' = u,      p(w) = w^2 ("square") or sin(w) ("sin")

``Theta(x) = (x1 - P(x2), x2)`` with ``P(w) = int_0^w p`` (3.28) maps it to a chain of two
integrators. Nominal feedback (3.29): ``k(x) = -(x1 - P(x2)) / T^2 - 3 x2 / (2T)``, dead-beat
in 2T without delay. Predictor: the chain's exact flow through Theta (Corollary 3.7);
applying ``k`` to it is (3.25), and for ``tau = 0, r < T`` it is (3.30).
"""

import numpy as np

from delaycomp.maths.predictors import chain_predictor

STATES = ("x1", "x2")
INPUTS = ("u",)
CONTROL = "zoh"
PARAMETERS = {"p": "square"}
SHAPES = ("square", "sin")
CHOICES = {"p": SHAPES}
BATCH = True  # f, k and step also take a batch: x of shape (2, P), u (1, P), h (P,)


def p_of(w, p):
    return w * w if p.get("p", "square") == "square" else np.sin(w)


def P_of(w, p):
    return w**3 / 3.0 if p.get("p", "square") == "square" else 1.0 - np.cos(w)


def f(x, u, p):
    x2 = x[1]
    v = u[0]
    return np.array([x2 + p_of(x2, p) * v, v])


def theta(x, p):
    return np.array([x[0] - P_of(x[1], p), x[1]])


def theta_inv(z, p):
    return np.array([z[0] + P_of(z[1], p), z[1]])


def k(x, p):
    T = p["T"]
    z1, z2 = theta(x, p)
    return np.array([-z1 / T**2 - 3.0 * z2 / (2.0 * T)])


predictor = chain_predictor(theta, theta_inv, 2)


def step(x, u, h, p):
    """Exact: ``x2(s) = x2 + u s``, ``x1(s) = x1 + x2 s + u s^2/2 + P(x2(s)) - P(x2)``."""
    x1, x2 = x
    v = u[0]  # a point or a batch; no float(): delaycomp.fmu.translate traces it
    x2e = x2 + v * h
    return np.array([x1 + x2 * h + v * h * h / 2.0 + P_of(x2e, p) - P_of(x2, p), x2e])
