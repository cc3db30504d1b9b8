"""FMU slave: zero-order-hold predictor-controller for an LTI plant (Theorem 3.2).

The maths is :class:`delaycomp.controller.ZOHController`. See README.md beside this file.
"""

from __future__ import annotations

import numpy as np
from pythonfmu import Fmi2Variability

from delaycomp.controller import ZOHController
from delaycomp.fmuslave import SAMPLING_HELP, SAMPLINGS, TableSlave, check_finite
from delaycomp.lti import MODES, split_delay
from delaycomp.names import indexed


class DelaycompControllerLTI(TableSlave):
    """u_i = K Phi(y_i, past inputs) (compensated) or u_i = K y_i, held over each period."""

    description = ("sampled-data ZOH controller with the LTI predictor of Corollary 3.4; "
                   "samples y at t0 + iT")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        n, m = int(self.config["n"]), int(self.config["m"])
        self.n, self.m = n, m
        self.A = np.zeros((n, n))
        self.B = np.zeros((n, m))
        self.K = np.zeros((m, n))
        self.u0 = np.zeros(m)
        self.T, self.r, self.tau = 1.0, 0.0, 0.0
        self.mode = "compensated"
        self.sampling = "instant"
        self.y = np.zeros(n)
        self._y_held = None     # the input held over the last base step (sampling)
        self.ctrl: ZOHController | None = None
        self.t0 = 0.0
        self._next = 0          # index of the next sampling instant t0 + i T
        self._at_sample = True  # is the current time a sampling instant not yet committed?
        self._proposal = None   # u_i computed from the current y (cleared when y is set)

        for name, text in (
            ("T", "sampling period [s], > 0"),
            ("r", "measurement delay assumed by the predictor [s], >= 0"),
            ("tau", "input delay assumed by the predictor [s], a multiple of T"),
        ):
            self.parameter(name, (lambda a=name: getattr(self, a)),
                           (lambda v, a=name: setattr(self, a, v)), text)
        self.string_parameter("mode", lambda: self.mode, lambda v: setattr(self, "mode", v),
                              "compensated (u = K Phi) or uncompensated (u = K y)")
        self.string_parameter("sampling", lambda: self.sampling,
                              lambda v: setattr(self, "sampling", v), SAMPLING_HELP)
        for label, mat, rows, cols, text in (
            ("A", self.A, n, n, "plant matrix A used by the predictor"),
            ("B", self.B, n, m, "plant matrix B used by the predictor"),
            ("K", self.K, m, n, "feedback gain, u = K x"),
        ):
            for i in range(rows):
                for j in range(cols):
                    self.parameter(f"{label}[{i + 1},{j + 1}]",
                                   (lambda M=mat, i=i, j=j: float(M[i, j])),
                                   (lambda v, M=mat, i=i, j=j: M.__setitem__((i, j), v)), text)
        for j in range(m):
            self.parameter(f"u0[{j + 1}]", (lambda j=j: float(self.u0[j])),
                           (lambda v, j=j: self.u0.__setitem__(j, v)),
                           "controller output history, constant on [t0 - r - tau, t0)")
        self.input_names = indexed("y", n)
        self.output_names = indexed("u", m)

        def set_y(i):
            def setter(v):
                self.y[i] = v
                self._proposal = None
            return setter

        for i, name in enumerate(self.input_names):
            self.real_input(name, (lambda i=i: float(self.y[i])), set_y(i),
                            "sampled measurement y = x(t - r), read at t0 + iT")
        for j, name in enumerate(self.output_names):
            self.real_output(name, (lambda j=j: float(self._output()[j])),
                             "control, held over each sampling period",
                             depends_on=self.input_names,
                             variability=Fmi2Variability.discrete)

    def setup_experiment(self, start_time, stop_time, tolerance):
        self.t0 = float(start_time)

    def _setup(self):
        for name in ("T", "r", "tau"):
            check_finite(name, getattr(self, name))
        for label, mat in (("A", self.A), ("B", self.B), ("K", self.K), ("u0", self.u0)):
            for idx, v in np.ndenumerate(mat):
                check_finite(f"{label}[{','.join(str(k + 1) for k in idx)}]", float(v))
        if not self.T > 0:
            self.fail(f"T = {self.T!r} is not allowed: must be > 0")
        if self.r < 0:
            self.fail(f"r = {self.r!r} is not allowed: must be >= 0")
        if self.tau < 0 or split_delay(self.tau, self.T)[1] != 0.0:
            self.fail(f"tau = {self.tau!r} is not allowed: must be a multiple l*T, l >= 0, "
                      f"of T = {self.T!r}")
        if self.mode not in MODES:
            self.fail(f"mode = {self.mode!r} is not allowed: must be one of {', '.join(MODES)}")
        if self.sampling not in SAMPLINGS:
            self.fail(f"sampling = {self.sampling!r} is not allowed: must be one of "
                      f"{', '.join(SAMPLINGS)}")
        self.ctrl = ZOHController(self.A, self.B, self.K, self.T, self.r, self.tau,
                                  self.mode, self.u0)
        self._next = 0
        self._at_sample = True
        self._proposal = None
        self._y_held = None

    def _sample(self) -> np.ndarray:
        """The measurement read at a sampling instant (see ``sampling``)."""
        if self.sampling == "instant" or self._y_held is None:
            return self.y
        return self._y_held

    def _output(self) -> np.ndarray:
        if self.ctrl is None:  # not initialized, or refused its parameters
            return self.u0
        if not self._at_sample:
            return self.ctrl.held
        if self._proposal is None:
            self._proposal = self.ctrl.propose(self._sample())
        return self._proposal

    def _step(self, current_time: float, step_size: float) -> None:
        if self._at_sample:
            self.ctrl.commit(self._output())
            self._next += 1
            self._proposal = None
        t_end = current_time + step_size
        t_sample = self.t0 + self._next * self.T
        tol = 1e-9 * self.T + 4 * np.finfo(float).eps * abs(t_end)
        if t_end > t_sample + tol:
            self.fail(f"step [{current_time!r}, {t_end!r}] is not allowed: it passes over the "
                      f"sampling instant {t_sample!r}; steps must end on t0 + iT")
        self._at_sample = abs(t_end - t_sample) <= tol
        self._y_held = self.y.copy()
        self._proposal = None
