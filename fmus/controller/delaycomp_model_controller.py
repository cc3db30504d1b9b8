"""FMU slave template: predictor-based controller of a user model (Theorems 2.1 and 3.2).

``delaycomp build --model FILE.py`` generates a subclass naming the model module. The maths
is :mod:`delaycomp.nlcontrol`. See README.md beside this file.
"""

from __future__ import annotations

import importlib

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Variability, Integer

from delaycomp.fmuslave import SAMPLING_HELP, SAMPLINGS, TableSlave, check_finite
from delaycomp.model import CONTROLS, from_module
from delaycomp.nlcontrol import make_controller
from delaycomp.predictors import DEFAULT_TOL


class ModelControllerSlave(TableSlave):
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
        self.sampling = "instant"
        self._y_held = None  # the input held over the last base step (sampling)
        self.u0, self.z0, self.y = np.zeros(m), np.zeros(n), np.zeros(n)
        self.t0 = 0.0
        self.ctrl = None
        for name, text in (("T", "sampling period [s], > 0"),
                           ("r", "measurement delay [s], >= 0, a multiple of T/N"),
                           ("tau", "input delay [s], >= 0, a multiple of T/N (zoh: of T, "
                                   "unless pad)")):
            self.parameter(name, (lambda a=name: getattr(self, a)),
                           (lambda v, a=name: setattr(self, a, v)), text)
        self.register_variable(Integer(
            "N", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
            getter=lambda: self.N, setter=lambda v: setattr(self, "N", v),
            description="communication steps per sampling period; every step is T/N"))
        self.string_parameter("mode", lambda: self.mode, lambda v: setattr(self, "mode", v),
                              "continuous (Theorem 2.1) or zoh (Theorem 3.2)")
        self.string_parameter("predictor", lambda: self.predictor,
                              lambda v: setattr(self, "predictor", v),
                              "closed (the model's closed form) or numerical (ODE solve)")
        self.parameter("tolerance", lambda: self.tolerance,
                       lambda v: setattr(self, "tolerance", v),
                       "rtol = atol of numerical solves, in (0, 1)")
        self.register_variable(Boolean(
            "pad", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
            getter=lambda: self.pad, setter=lambda v: setattr(self, "pad", bool(v)),
            description="zoh: pad tau up to the next multiple of T (Remark 3.3(b))"))
        self.string_parameter("sampling", lambda: self.sampling,
                              lambda v: setattr(self, "sampling", v), SAMPLING_HELP)
        self.values: dict = {}
        self.model_parameters(self.values, model.parameters)
        for j, s in enumerate(model.inputs):
            self.parameter(f"u0[{j + 1}]", (lambda j=j: float(self.u0[j])),
                           (lambda v, j=j: self.u0.__setitem__(j, v)),
                           f"history of {s}, constant on [t0 - r - tau, t0)")
        for i, s in enumerate(model.states):
            self.parameter(f"z0[{i + 1}]", (lambda i=i: float(self.z0[i])),
                           (lambda v, i=i: self.z0.__setitem__(i, v)),
                           f"continuous mode: initial predictor state for {s}")
        inputs = [f"y_{s}" for s in model.states]

        def set_y(i):
            return lambda v: self.y.__setitem__(i, v)

        for i, (name, s) in enumerate(zip(inputs, model.states)):
            self.real_input(name, (lambda i=i: float(self.y[i])), set_y(i),
                            f"measurement {s}(t - r), read at t0 + iT")
        for j, name in enumerate(model.inputs):
            self.real_output(name, (lambda j=j: float(self._output()[j])), "control",
                             depends_on=inputs)

    def setup_experiment(self, start_time, stop_time, tolerance):
        self.t0 = float(start_time)

    def _setup(self):
        for name in ("T", "r", "tau", "tolerance"):
            check_finite(name, getattr(self, name))
        for label, vec in (("u0", self.u0), ("z0", self.z0)):
            for i, v in enumerate(vec):
                check_finite(f"{label}[{i + 1}]", float(v))
        if self.mode not in CONTROLS:
            self.fail(f"mode = {self.mode!r} is not allowed: must be one of "
                      f"{', '.join(CONTROLS)}")
        if self.sampling not in SAMPLINGS:
            self.fail(f"sampling = {self.sampling!r} is not allowed: must be one of "
                      f"{', '.join(SAMPLINGS)}")
        self._y_held = None
        if not 0 < self.tolerance < 1:
            self.fail(f"tolerance = {self.tolerance!r} is not allowed: must be in (0, 1)")
        try:
            self.ctrl = make_controller(self.model, self.values, self.T, self.r, self.tau,
                                        int(self.N), self.u0, self.z0, self.mode,
                                        self.predictor, self.tolerance, self.pad)
        except ValueError as exc:
            self.fail(str(exc))
        if getattr(self.ctrl, "padding", 0.0):
            self.log(f"input delay padded from tau = {self.tau!r} to "
                     f"{self.ctrl.tau_effective!r}: the controller delays its output by "
                     f"{self.ctrl.padding!r} s")
        if hasattr(self.ctrl, "t0"):
            self.ctrl.t0 = self.t0

    def _output(self):
        if self.ctrl is None:
            return self.u0
        if self.error is None:
            try:
                return self.ctrl.output(self._sample())
            except Exception as exc:  # noqa: BLE001 - a getter must not raise into pythonfmu
                self._refuse(f"computing the control failed: {type(exc).__name__}: {exc}")
        return np.full(self.model.m, np.nan)

    def _step(self, t, h):
        expected = self.t0 + self.ctrl.k_tick * self.ctrl.h
        if abs(h - self.ctrl.h) > 1e-9 * self.ctrl.h or abs(t - expected) > 1e-9 * max(
                self.T, abs(t)):
            self.fail(f"step ({t!r}, {h!r}) is not allowed: this controller steps from "
                      f"{expected!r} by exactly T/N = {self.ctrl.h!r}")
        y = self._sample()
        if not np.all(np.isfinite(y)):
            self.fail(f"measurement {y.tolist()} at t = {t!r} is not allowed: must be "
                      "finite")
        self.ctrl.advance(y)
        self._y_held = self.y.copy()

    def _sample(self) -> np.ndarray:
        """The measurement read at a sampling instant (see ``sampling``)."""
        if self.sampling == "instant" or self._y_held is None:
            return self.y
        return self._y_held
