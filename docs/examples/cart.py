"""A cart on a frictionless rail: x1' = x2, x2' = u / mass, with a dead-beat sampled-data
feedback (the plant of the tutorial, docs/tutorial.md)."""
import numpy as np

STATES = ("position", "velocity")
INPUTS = ("force",)
CONTROL = "zoh"                      # the feedback is held over each period (Theorem 3.2)
PARAMETERS = {"mass": 2.0}


def f(x, u, p):
    return np.array([x[1], u[0] / p["mass"]])


def k(x, p):
    # dead-beat for the delay-free sampled loop: zero state after two periods
    T = p["T"]
    return np.array([-p["mass"] * (x[0] / T**2 + 1.5 * x[1] / T)])
