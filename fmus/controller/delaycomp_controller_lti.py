"""FMU slave: zero-order-hold predictor-controller for an LTI plant (Theorem 3.2).

The maths is ``delaycomp.maths.zoh.ZOHController``. See README.md beside this file.
"""

from __future__ import annotations

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Variability

from delaycomp.fmu.sampling import HeldSampleMixin, ends_on_sample, reaches_release
from delaycomp.fmu.slave import (
    TableSlave,
    check_finite,
    check_inputs,
    state_count,
    state_flag,
    state_refused,
    state_rows,
    state_vector,
)
from delaycomp.maths.grid import periods
from delaycomp.maths.lti import MODES, check_steps
from delaycomp.maths.zoh import ZOHController
from delaycomp.names import indexed


class DelaycompControllerLTI(HeldSampleMixin, TableSlave):
    """u_i = K Phi(y_i, past inputs) (compensated) or u_i = K y_i, held over each period."""

    description = ("sampled-data ZOH controller with the LTI predictor of Corollary 3.4; "
                   "samples y at t0 + iT")
    fp_guarded = True  # a step commits and compares times; propose() guards itself

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
        self.pad = False
        self.y = np.zeros(n)
        self.ctrl: ZOHController | None = None
        self.t0 = 0.0
        self._next = 0          # index of the next sampling instant t0 + i T
        self._at_sample = True  # is the current time a sampling instant not yet committed?
        self._proposal = None   # u_i computed from the current y (cleared when y is set)
        self._released = True   # pad: is the current time at or after t_{next-1} + padding?

        for name, text in (
            ("T", "sampling period [s], > 0"),
            ("r", "measurement delay assumed by the predictor [s], >= 0"),
            ("tau", "input delay assumed by the predictor [s], a multiple of T (unless "
                    "pad)"),
        ):
            get, put = (lambda a=name: getattr(self, a)), (lambda v, a=name: setattr(self, a, v))
            self.parameter(name, get, put, text)
        self.register_variable(Boolean(
            "pad", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
            getter=lambda: self.pad, setter=lambda v: setattr(self, "pad", bool(v)),
            description="pad tau up to the next multiple of T (Remark 3.3(b))"))
        self.string_parameter("mode", lambda: self.mode, lambda v: setattr(self, "mode", v),
                              "compensated (u = K Phi) or uncompensated (u = K y)", MODES)
        for label, mat, text in (
            ("A", self.A, "plant matrix A used by the predictor"),
            ("B", self.B, "plant matrix B used by the predictor"),
            ("K", self.K, "feedback gain, u = K x"),
        ):
            self.matrix_parameter(label, mat, text)
        self.matrix_parameter("u0", self.u0,
                              "controller output history, constant on [t0 - r - tau, t0)")
        self.register_held_sample()
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
        try:
            check_steps("r + tau", self.r + self.tau, (self.r + self.tau) / self.T,
                        f"sampling periods of T = {self.T!r}")
        except ValueError as exc:
            self.fail(str(exc))
        if not self.pad or self.tau < 0:
            try:
                periods(self.tau, self.T, padding=True)
            except ValueError as exc:
                self.fail(str(exc))
        if self.mode not in MODES:
            self.fail(f"mode = {self.mode!r} is not allowed: must be one of {', '.join(MODES)}")
        try:
            self.ctrl = ZOHController(self.A, self.B, self.K, self.T, self.r, self.tau,
                                      self.mode, self.u0, self.pad)
        except ValueError as exc:
            self.fail(str(exc))
        if self.ctrl.padding:
            self.log(f"input delay padded from tau = {self.tau!r} to "
                     f"{self.ctrl.tau_effective!r}: the controller delays its output by "
                     f"{self.ctrl.padding!r} s")
        pred = self.ctrl.predictor
        if self.mode == "compensated" and not (np.all(np.isfinite(pred.E))
                                               and np.all(np.isfinite(pred._QB_stack))):
            self.fail(f"A = {self.A.tolist()} is not allowed: must keep the predictor "
                      f"e^(A (r + tau)) finite for r + tau = {self.r + self.tau!r} (it "
                      "overflows)")
        self._next = 0
        self._at_sample = True
        self._proposal = None
        self._released = True
        self._y_held = None

    def _hidden_state(self) -> dict:
        assert self.ctrl is not None  # saved only when initialized: _setup() built it
        return {"ctrl": self.ctrl.get_state(), "next": self._next,
                "at_sample": self._at_sample, "released": self._released,
                "y_held": self._held_state()}

    def _restore_hidden(self, hidden: dict) -> None:
        assert self.ctrl is not None  # called after _setup() built it
        ctrl = hidden.get("ctrl")
        if not isinstance(ctrl, dict):
            raise state_refused("hidden.ctrl", ctrl, "an object (held, history, pad_line)")
        L = self.ctrl.predictor.L
        ctrl = {"held": state_vector("hidden.ctrl.held", ctrl.get("held"), self.m, False),
                "history": state_rows("hidden.ctrl.history", ctrl.get("history"), L, self.m,
                                      False),
                "pad_line": state_rows("hidden.ctrl.pad_line", ctrl.get("pad_line"),
                                       len(self.ctrl.pad_line), self.m, False)}
        next_ = state_count("hidden.next", hidden.get("next"))
        at_sample = state_flag("hidden.at_sample", hidden.get("at_sample"))
        released = state_flag("hidden.released", hidden.get("released"))
        y_held = self._checked_held(hidden.get("y_held"))
        self.ctrl.set_state(ctrl)
        self._next = next_
        self._at_sample = at_sample
        self._released = released
        self._restore_held(y_held)
        self._proposal = None  # a cache: recomputed from the restored state

    def _output(self) -> np.ndarray:
        if self.ctrl is None:  # not initialized, or refused its parameters
            return self.u0
        if self.ctrl.pad_line:  # padded: u_i reaches the output at t_i + padding
            return self.ctrl.output(self._released or self._at_sample)
        if not self._at_sample:
            return self.ctrl.held
        return self._proposed()

    def _proposed(self) -> np.ndarray:
        """``u_i`` of the current sample (computed once per measurement), checked finite."""
        assert self.ctrl is not None  # called only when initialized
        if self._proposal is None:
            with np.errstate(all="ignore"):  # checked below
                u = self.ctrl.propose(self._sample())
            if not np.all(np.isfinite(u)) and np.all(np.isfinite(self.y)) \
                    and self.error is None:
                t = self.t0 + self._next * self.T
                self._refuse(f"control {self.output_names} = {u.tolist()} at t = {t!r} is "
                             "not allowed: must be finite (the feedback diverged: overflow)")
            self._proposal = u
        return self._proposal

    def _step(self, current_time: float, step_size: float) -> None:
        check_inputs(self.input_names, self.y, current_time)
        if self._at_sample:
            assert self.ctrl is not None  # steps only when initialized: _setup() built it
            self.ctrl.commit(self._proposed())
            self._next += 1
            self._proposal = None
            self._released = not self.ctrl.pad_line
        if not self._released:
            assert self.ctrl is not None  # steps only when initialized
            release = self.t0 + (self._next - 1) * self.T + self.ctrl.padding
            self._released = reaches_release(current_time, step_size, self.t0, self.T,
                                             release)
        self._at_sample = ends_on_sample(current_time, step_size, self.t0, self.T, self._next)
        if self._hold():
            self._proposal = None  # the held input is sampled at the next instant
