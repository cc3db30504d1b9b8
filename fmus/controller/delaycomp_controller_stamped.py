"""FMU slave: the time-stamp predictor-controller for an LTI plant.

The maths is ``delaycomp.maths.stamped.StampedController``: at each sampling instant it
reads the sample ``y`` and its send time ``stamp`` (a network channel's outputs), carries
the newest sample over its actual age plus ``tau`` (or, lost or too old, its last
estimate), and holds ``u = K x_hat`` over the period. See README.md beside this file.
"""

from __future__ import annotations

import numpy as np

from delaycomp.fmu.sampling import StampedSlaveMixin
from delaycomp.fmu.slave import TableSlave, check_finite
from delaycomp.maths.stamped import StampedController
from delaycomp.names import indexed


class DelaycompControllerStamped(StampedSlaveMixin, TableSlave):
    """u_i = K x_hat(t_i + tau), x_hat from the newest sample at its stamp; held."""

    description = ("sampled-data ZOH controller whose LTI predictor integrates over each "
                   "sample's actual age (its time stamp) plus tau; samples at t0 + iT")
    fp_guarded = True

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        n, m = int(self.config["n"]), int(self.config["m"])
        self.n, self.m = n, m
        self.A = np.zeros((n, n))
        self.B = np.zeros((n, m))
        self.K = np.zeros((m, n))
        self.u0 = np.zeros(m)
        self.T, self.tau, self.age_max = 1.0, 0.0, 0.0
        self.mode = "compensated"
        self.y = np.zeros(n)
        self.ctrl: StampedController | None = None
        self.register_timing("compensated (u = K x_hat) or uncompensated (u = K y)")
        for label, mat, text in (
            ("A", self.A, "plant matrix A used by the predictor"),
            ("B", self.B, "plant matrix B used by the predictor"),
            ("K", self.K, "feedback gain, u = K x"),
        ):
            self.matrix_parameter(label, mat, text)
        self.matrix_parameter("u0", self.u0, "controller output history, constant before t0")
        self.register_held_sample()
        self.register_ports(indexed("y", n),
                            ["sampled measurement y = x(stamp), read at t0 + iT"] * n,
                            indexed("u", m))

    def _setup(self):
        for name in ("T", "tau", "age_max"):
            check_finite(name, getattr(self, name))
        for label, mat in (("A", self.A), ("B", self.B), ("K", self.K), ("u0", self.u0)):
            for idx, v in np.ndenumerate(mat):
                check_finite(f"{label}[{','.join(str(k + 1) for k in idx)}]", float(v))
        try:
            self.ctrl = StampedController(self.A, self.B, self.K, self.T, self.tau,
                                          self.age_max, self.mode, self.u0, self.t0)
        except ValueError as exc:
            self.fail(str(exc))
        self._reset_stamps()
