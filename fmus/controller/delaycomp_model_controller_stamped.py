"""FMU slave template: the time-stamp predictor-controller of a user model.

The model's zero-order-hold law ``k(x, p)`` (``CONTROL = "zoh"``) on the estimate of
``delaycomp.maths.stamped.StampedModelController``: at each sampling instant it reads the
sample ``y_<state>`` and its send time ``stamp`` (a network channel's outputs), carries the
newest sample over its actual age plus ``tau`` through the model's ODE (or, lost or too
old, its last estimate), and holds ``u = k(x_hat)`` over the period. The build generates a
subclass naming the model module, as for ``delaycomp_model_controller.py``; a model whose
``CONTROL`` is ``continuous`` is refused at the build. See README.md beside this file.
"""

from __future__ import annotations

import importlib

import numpy as np

from delaycomp.fmu.sampling import StampedSlaveMixin
from delaycomp.fmu.slave import TableSlave, check_finite, check_model_parameters
from delaycomp.maths.model import from_module
from delaycomp.maths.predictors import DEFAULT_TOL
from delaycomp.maths.stamped import StampedModelController


class StampedModelControllerSlave(StampedSlaveMixin, TableSlave):
    """u_i = k(x_hat(t_i + tau)), x_hat from the newest sample at its stamp; held.
    ``model_module`` is set by the generated subclass."""

    model_module = ""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.model = model = from_module(importlib.import_module(self.model_module),
                                         self.config.get("model_name"))
        self.description = (f"sampled-data ZOH controller of model {model.name} whose "
                            "predictor integrates over each sample's actual age (its time "
                            "stamp) plus tau; samples at t0 + iT")
        self.n, self.m = n, m = model.n, model.m
        self.u0, self.y = np.zeros(m), np.zeros(n)
        self.T, self.tau, self.age_max = 1.0, 0.0, 0.0
        self.mode = "compensated"
        self.tolerance = DEFAULT_TOL
        self.ctrl: StampedModelController | None = None
        self.register_timing("compensated (u = k(x_hat)) or uncompensated (u = k(y))")
        self.parameter("tolerance", lambda: self.tolerance,
                       lambda v: setattr(self, "tolerance", v),
                       "rtol = atol of the predictor's ODE solves, in (0, 1)")
        self.values: dict = {}
        self.model_parameters(self.values, model.parameters, model.choices)
        for j, s in enumerate(model.inputs):
            self.parameter(f"u0[{j + 1}]", (lambda j=j: float(self.u0[j])),
                           (lambda v, j=j: self.u0.__setitem__(j, v)),
                           f"history of {s}, constant before t0")
        self.register_held_sample()
        self.register_ports([f"y_{s}" for s in model.states],
                            [f"sampled measurement {s}(stamp), read at t0 + iT"
                             for s in model.states], list(model.inputs))

    def _setup(self):
        for name in ("T", "tau", "age_max", "tolerance"):
            check_finite(name, getattr(self, name))
        for j, v in enumerate(self.u0):
            check_finite(f"u0[{j + 1}]", float(v))
        check_model_parameters(self.model, self.values)
        try:
            self.ctrl = StampedModelController(self.model, self.values, self.T, self.tau,
                                               self.age_max, self.mode, self.u0, self.t0,
                                               self.tolerance)
        except ValueError as exc:
            self.fail(str(exc))
        self._reset_stamps()
