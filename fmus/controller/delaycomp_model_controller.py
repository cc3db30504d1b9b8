"""FMU slave template: predictor-based controller of a user model (Theorems 2.1 and 3.2).

``delaycomp build --model FILE.py`` generates a subclass naming the model module. The maths
is ``delaycomp.maths.nlcontrol``. See README.md beside this file.
"""

from __future__ import annotations

import importlib

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Variability, Integer

from delaycomp.fmu.sampling import HeldSampleMixin
from delaycomp.fmu.slave import (
    TableSlave,
    check_finite,
    check_inputs,
    check_model_parameters,
    is_roundoff_step,
    state_count,
    state_number,
    state_refused,
    state_rows,
    state_vector,
)
from delaycomp.maths.grid import grid_step, same_step
from delaycomp.maths.model import CONTROLS, from_module
from delaycomp.maths.nlcontrol import (
    PREDICTORS,
    ContinuousController,
    ZOHModelController,
    make_controller,
)
from delaycomp.maths.predictors import DEFAULT_TOL, IntegrationError


class ModelControllerSlave(HeldSampleMixin, TableSlave):
    """Controller of a user model; ``model_module`` is set by the generated subclass."""

    model_module = ""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.model = model = from_module(importlib.import_module(self.model_module),
                                         self.config.get("model_name"))
        self.description = (f"predictor-based sampled-data controller of model {model.name} "
                            f"({model.control})")
        n, m = model.n, model.m
        self.T, self.r, self.tau, self.N = 1.0, 0.0, 0.0, 100
        self.mode = model.control
        self.predictor = "closed" if model.predictor is not None else "numerical"
        self.tolerance = DEFAULT_TOL
        self.pad = False
        self.u0, self.z0, self.y = np.zeros(m), np.zeros(n), np.zeros(n)
        self.t0 = 0.0
        self.ctrl: ContinuousController | ZOHModelController | None = None  # made by _setup
        self._declare_settings()
        self._declare_model_variables(model)

    def _declare_settings(self):
        """The controller's settings: T, r, tau, N, mode, predictor, tolerance, pad."""
        for name, text in (("T", "sampling period [s], > 0"),
                           ("r", "measurement delay [s], >= 0, a multiple of T/N"),
                           ("tau", "input delay [s], >= 0, a multiple of T/N (zoh: of T, "
                                   "unless pad)")):
            get, put = (lambda a=name: getattr(self, a)), (lambda v, a=name: setattr(self, a, v))
            self.parameter(name, get, put, text)
        self.register_variable(Integer(
            "N", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
            getter=lambda: self.N, setter=lambda v: setattr(self, "N", v),
            description="communication steps per sampling period; every step is T/N"))
        self.string_parameter("mode", lambda: self.mode, lambda v: setattr(self, "mode", v),
                              "continuous (Theorem 2.1) or zoh (Theorem 3.2)", CONTROLS)
        self.string_parameter("predictor", lambda: self.predictor,
                              lambda v: setattr(self, "predictor", v),
                              "closed (the model's closed form), numerical (ODE solve) or "
                              "none (no prediction: the uncompensated baseline)", PREDICTORS)
        self.parameter("tolerance", lambda: self.tolerance,
                       lambda v: setattr(self, "tolerance", v),
                       "rtol = atol of numerical solves, in (0, 1)")
        self.register_variable(Boolean(
            "pad", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
            getter=lambda: self.pad, setter=lambda v: setattr(self, "pad", bool(v)),
            description="zoh: pad tau up to the next multiple of T (Remark 3.3(b))"))

    def _declare_model_variables(self, model):
        """The model's parameters, the histories u0 and z0, the held sample, the
        measured inputs and the control outputs."""
        self.values: dict = {}
        self.model_parameters(self.values, model.parameters, model.choices)
        for j, s in enumerate(model.inputs):
            get, put = (lambda j=j: float(self.u0[j])), (lambda v, j=j: self.u0.__setitem__(j, v))
            self.parameter(f"u0[{j + 1}]", get, put,
                           f"history of {s}, constant on [t0 - r - tau, t0)")
        for i, s in enumerate(model.states):
            get, put = (lambda i=i: float(self.z0[i])), (lambda v, i=i: self.z0.__setitem__(i, v))
            self.parameter(f"z0[{i + 1}]", get, put,
                           f"continuous mode: initial predictor state for {s}")
        self.register_held_sample()
        inputs = [f"y_{s}" for s in model.states]
        self.input_names = inputs

        def set_y(i):
            return lambda v: self.y.__setitem__(i, v)

        for i, (name, s) in enumerate(zip(inputs, model.states)):
            self.real_input(name, (lambda i=i: float(self.y[i])), set_y(i),
                            f"measurement {s}(t - r), read at t0 + iT")
        for j, name in enumerate(model.inputs):
            self.real_output(name, (lambda j=j: float(self._output()[j])), "control",
                             depends_on=inputs)

    def _setup(self):
        for name in ("T", "r", "tau", "tolerance"):
            check_finite(name, getattr(self, name))
        for label, vec in (("u0", self.u0), ("z0", self.z0)):
            for i, v in enumerate(vec):
                check_finite(f"{label}[{i + 1}]", float(v))
        if self.mode not in CONTROLS:
            self.fail(f"mode = {self.mode!r} is not allowed: must be one of "
                      f"{', '.join(CONTROLS)}")
        if not 0 < self.tolerance < 1:
            self.fail(f"tolerance = {self.tolerance!r} is not allowed: must be in (0, 1)")
        check_model_parameters(self.model, self.values)
        if self.predictor not in PREDICTORS:
            self.fail(f"predictor = {self.predictor!r} is not allowed: must be one of "
                      f"{', '.join(PREDICTORS)}")
        try:
            self.ctrl = make_controller(self.model, self.values, self.T, self.r, self.tau,
                                        int(self.N), self.u0, self.z0, self.mode,
                                        self.predictor, self.tolerance, self.pad)
        except ValueError as exc:
            self.fail(str(exc))
        if isinstance(self.ctrl, ZOHModelController) and self.ctrl.padding:
            self.log(f"input delay padded from tau = {self.tau!r} to "
                     f"{self.ctrl.tau_effective!r}: the controller delays its output by "
                     f"{self.ctrl.padding!r} s")
        if hasattr(self.ctrl, "t0"):
            self.ctrl.t0 = self.t0
        self._y_held = None

    def _hidden_state(self) -> dict:
        assert self.ctrl is not None  # saved only when initialized: _setup() made it
        return {"ctrl": self.ctrl.get_state(),
                "y_held": self._held_state()}

    def _restore_hidden(self, hidden: dict) -> None:
        assert self.ctrl is not None  # called after _setup() made it
        ctrl = hidden.get("ctrl")
        if not isinstance(ctrl, dict):
            raise state_refused("hidden.ctrl", ctrl, "an object (k_tick, history, ...)")
        n, m = self.model.n, self.model.m
        checked = {"k_tick": state_count("hidden.ctrl.k_tick", ctrl.get("k_tick")),
                   "history": state_rows("hidden.ctrl.history", ctrl.get("history"),
                                         self.ctrl.history.W, m, False)}
        if hasattr(self.ctrl, "pad_line"):  # zero-order hold
            checked["held"] = state_vector("hidden.ctrl.held", ctrl.get("held"), m, False)
            checked["pad_line"] = state_rows("hidden.ctrl.pad_line", ctrl.get("pad_line"),
                                             self.ctrl.pad_line.D, m, False)
        else:  # continuous input: the controller's own copy of the plant
            checked["z"] = state_vector("hidden.ctrl.z", ctrl.get("z"), n, False)
            checked["t0"] = state_number("hidden.ctrl.t0", ctrl.get("t0"))
        y_held = self._checked_held(hidden.get("y_held"))
        self.ctrl.set_state(checked)
        self._restore_held(y_held)

    def _output(self):
        if self.ctrl is None:
            return self.u0
        if self.error is None:
            t = self.t0 + self.ctrl.k_tick * self.ctrl.h
            try:
                with np.errstate(all="ignore"):  # non-finite results are checked below
                    u = self.ctrl.output(self._sample())
            except BaseException as exc:  # noqa: BLE001 - nothing may raise into pythonfmu
                self._refuse(f"computing the control at t = {t!r} failed: "
                             f"{type(exc).__name__}: {exc}")
            else:
                # a non-finite measurement is refused by the next doStep, naming the input
                if np.all(np.isfinite(u)) or not np.all(np.isfinite(self.y)):
                    return u
                self._refuse(f"control {list(self.model.inputs)} = {u.tolist()} at t = {t!r} "
                             "is not allowed: must be finite (the predictor or the feedback "
                             "diverged)")
        return np.full(self.model.m, np.nan)

    def _step(self, t, h):
        assert self.ctrl is not None  # steps follow _setup(), which made it
        expected = self.t0 + self.ctrl.k_tick * self.ctrl.h
        if is_roundoff_step(h, self.ctrl.h) and abs(t + h - expected) <= 1e-9 * max(
                self.T, abs(t)):
            return  # the master's round-off (fmuslave.ROUNDOFF_STEP_FRACTION): nothing moves
        # the step is T/N up to round-off (same_step) or ends on the grid up to a host's
        # drift (t += h: grid.grid_step); it starts where this controller stands
        one_step = same_step(h, self.ctrl.h, t) or grid_step(t, h, self.ctrl.h, self.t0)
        if not one_step or abs(t - expected) > 1e-9 * max(self.T, abs(t)):
            self.fail(f"step ({t!r}, {h!r}) is not allowed: this controller steps from "
                      f"{expected!r} by exactly T/N = {self.ctrl.h!r}")
        check_inputs(self.input_names, self.y, t)
        try:
            self.ctrl.advance(self._sample())
        except IntegrationError as exc:
            self.fail(f"predictor ODE solve at t = {t!r} failed: {exc}")
        self._hold()
