"""FMU slave: the time-stamp predictor-controller for an LTI plant (issue 29, item 2).

The maths is ``delaycomp.maths.stamped.StampedController``: at each sampling instant it
reads the sample ``y`` and its send time ``stamp`` (a network channel's outputs), carries
the newest sample over its actual age plus ``tau`` (or, lost or too old, its last
estimate), and holds ``u = K x_hat`` over the period. See README.md beside this file.
"""

from __future__ import annotations

import numpy as np
from pythonfmu import Fmi2Variability

from delaycomp.fmu.slave import (
    HeldSampleMixin,
    TableSlave,
    check_finite,
    check_inputs,
    ends_on_sample,
    state_count,
    state_number,
    state_refused,
    state_rows,
    state_vector,
)
from delaycomp.maths.lti import MODES
from delaycomp.maths.stamped import StampedController
from delaycomp.names import indexed


class DelaycompControllerStamped(HeldSampleMixin, TableSlave):
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
        self.stamp = 0.0
        self._stamp_held: float | None = None
        self.ctrl: StampedController | None = None
        self._at_sample = True
        self._proposal = None
        for name, text in (
            ("T", "sampling period [s], > 0"),
            ("tau", "input delay [s], >= 0 (constant: a delay, or a channel's play-out "
                    "buffer)"),
            ("age_max", "the largest age of a sample the predictor uses [s], >= 0: it sizes "
                        "the stored inputs; an older sample is not used"),
        ):
            self.parameter(name, (lambda a=name: getattr(self, a)),
                           (lambda v, a=name: setattr(self, a, v)), text)
        self.string_parameter("mode", lambda: self.mode, lambda v: setattr(self, "mode", v),
                              "compensated (u = K x_hat) or uncompensated (u = K y)", MODES)
        for label, mat, text in (
            ("A", self.A, "plant matrix A used by the predictor"),
            ("B", self.B, "plant matrix B used by the predictor"),
            ("K", self.K, "feedback gain, u = K x"),
        ):
            self.matrix_parameter(label, mat, text)
        self.matrix_parameter("u0", self.u0, "controller output history, constant before t0")
        self.register_held_sample()
        self.input_names = [*indexed("y", n), "stamp"]
        self.output_names = indexed("u", m)

        def set_y(i):
            def setter(v):
                self.y[i] = v
                self._proposal = None
            return setter

        def set_stamp(v):
            self.stamp = v
            self._proposal = None

        for i, name in enumerate(self.input_names[:n]):
            self.real_input(name, (lambda i=i: float(self.y[i])), set_y(i),
                            "sampled measurement y = x(stamp), read at t0 + iT")
        self.real_input("stamp", lambda: self.stamp, set_stamp,
                        "the time [s] the sample y was taken (a channel's stamp), <= t")
        for j, name in enumerate(self.output_names):
            self.real_output(name, (lambda j=j: float(self._output()[j])),
                             "control, held over each sampling period",
                             depends_on=self.input_names,
                             variability=Fmi2Variability.discrete)

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
        self._at_sample = True
        self._proposal = None
        self._y_held = None
        self._stamp_held = None

    def _sampled(self) -> tuple[np.ndarray, float]:
        """The sample and its stamp read now (``held_sample``: those held over the step
        that just ended)."""
        if self.held_sample and self._stamp_held is not None:
            return self._sample(), self._stamp_held
        return self.y, self.stamp

    def _hidden_state(self) -> dict:
        assert self.ctrl is not None  # saved only when initialized
        return {"ctrl": self.ctrl.get_state(), "at_sample": self._at_sample,
                "y_held": self._held_state(), "stamp_held": self._stamp_held}

    def _restore_hidden(self, hidden: dict) -> None:
        assert self.ctrl is not None  # called after _setup() built it
        ctrl = hidden.get("ctrl")
        if not isinstance(ctrl, dict):
            raise state_refused("hidden.ctrl", ctrl, "an object (held, history, i, z, stamp)")
        z, stamp = ctrl.get("z"), ctrl.get("stamp")
        checked = {
            "held": state_vector("hidden.ctrl.held", ctrl.get("held"), self.m, False),
            "history": state_rows("hidden.ctrl.history", ctrl.get("history"), self.ctrl.L,
                                  self.m, False),
            "i": state_count("hidden.ctrl.i", ctrl.get("i")),
            "z": None if z is None else state_vector("hidden.ctrl.z", z, self.n),
            "stamp": None if stamp is None else state_number("hidden.ctrl.stamp", stamp)}
        if (z is None) != (checked["i"] == 0):
            raise state_refused("hidden.ctrl.z", z, "null exactly before the first instant")
        if stamp is not None and not stamp <= self.t0 + checked["i"] * self.T:
            raise state_refused("hidden.ctrl.stamp", stamp, "a time before the instant")
        at_sample = hidden.get("at_sample")
        if not isinstance(at_sample, bool):
            raise state_refused("hidden.at_sample", at_sample, "true or false")
        y_held = self._checked_held(hidden.get("y_held"))
        stamp_held = hidden.get("stamp_held")
        if (stamp_held is None) != (y_held is None):
            raise state_refused("hidden.stamp_held", stamp_held, "given with y_held")
        if stamp_held is not None:
            stamp_held = state_number("hidden.stamp_held", stamp_held)
        self.ctrl.set_state(checked)
        self._at_sample = at_sample
        self._restore_held(y_held)
        self._stamp_held = stamp_held
        self._proposal = None

    def _output(self) -> np.ndarray:
        if self.ctrl is None:
            return self.u0
        if not self._at_sample:
            return self.ctrl.held
        if self._proposal is None:
            y, stamp = self._sampled()
            try:
                with np.errstate(all="ignore"):  # checked below
                    u = self.ctrl.propose(y, stamp)
            except ValueError as exc:  # a stamp from the future
                if self.error is None:
                    self._refuse(str(exc))
                return self.ctrl.held
            if not np.all(np.isfinite(u)) and np.all(np.isfinite(y)) and self.error is None:
                t = self.t0 + self.ctrl.i * self.T
                self._refuse(f"control {self.output_names} = {u.tolist()} at t = {t!r} is "
                             "not allowed: must be finite (the feedback diverged: overflow)")
            self._proposal = u
        return self._proposal

    def _step(self, current_time: float, step_size: float) -> None:
        check_inputs(self.input_names, [*self.y, self.stamp], current_time)
        assert self.ctrl is not None  # steps only when initialized
        if self._at_sample:
            y, stamp = self._sampled()
            try:
                u = self._proposal if self._proposal is not None else self.ctrl.propose(y, stamp)
                self.ctrl.commit(u, y, stamp)
            except ValueError as exc:  # a stamp from the future
                self.fail(str(exc))
            self._proposal = None
        self._at_sample = ends_on_sample(current_time, step_size, self.t0, self.T, self.ctrl.i)
        if self._hold():
            self._stamp_held = self.stamp
            self._proposal = None
