"""FMU slave template: the plant ``x' = f(x, u)`` of a user model (delaycomp.maths.model).

``delaycomp build --model FILE.py`` generates a subclass naming the model module (bundled
under a name unique to the model's content). See README.md beside this file.
"""

from __future__ import annotations

import importlib
import math

import numpy as np

from delaycomp.fmu.slave import (
    TableSlave,
    check_finite,
    check_inputs,
    check_model_parameters,
    state_vector,
)
from delaycomp.maths.model import from_module
from delaycomp.maths.nlcontrol import ModelPlant, StateNotFinite
from delaycomp.maths.predictors import DEFAULT_TOL, IntegrationError


class ModelPlantSlave(TableSlave):
    """Plant of a user model; ``model_module`` is set by the generated subclass."""

    model_module = ""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.model = from_module(importlib.import_module(self.model_module),
                                 self.config.get("model_name"))
        self.description = f"plant of model {self.model.name}: x' = f(x, u)"
        n, m = self.model.n, self.model.m
        self.values: dict = {}
        self.model_parameters(self.values, self.model.parameters, self.model.choices)
        self.x0 = np.zeros(n)
        self.tolerance = DEFAULT_TOL
        self.u = np.zeros(m)
        self.plant: ModelPlant | None = None
        for i, s in enumerate(self.model.states):
            get, put = (lambda i=i: float(self.x0[i])), (lambda v, i=i: self.x0.__setitem__(i, v))
            self.parameter(f"x0[{i + 1}]", get, put,
                           f"initial state {s}(t0)")
        self.parameter("tolerance", lambda: self.tolerance,
                       lambda v: setattr(self, "tolerance", v),
                       "rtol = atol of the ODE solver when the model has no exact step, > 0")
        for j, name in enumerate(self.model.inputs):
            self.real_input(name, (lambda j=j: float(self.u[j])),
                            (lambda v, j=j: self.u.__setitem__(j, v)),
                            "plant input, held constant over each communication step")
        for i, name in enumerate(self.model.states):
            self.real_output(name, (lambda i=i: float(self._state()[i])), "plant state")

    def _state(self):
        return self.plant.x if self.plant is not None else self.x0

    def _setup(self):
        for i, v in enumerate(self.x0):
            check_finite(f"x0[{i + 1}]", float(v))
        check_finite("tolerance", self.tolerance)
        if not 0 < self.tolerance < 1:
            self.fail(f"tolerance = {self.tolerance!r} is not allowed: must be in (0, 1)")
        check_model_parameters(self.model, self.values)
        self.plant = ModelPlant(self.model, self.values, self.x0, self.tolerance)

    def _hidden_state(self) -> dict:
        assert self.plant is not None  # saved only when initialized: _setup() built it
        return {"x": self.plant.x.tolist()}

    def _restore_hidden(self, hidden: dict) -> None:
        assert self.plant is not None  # called after _setup() built it
        self.plant.x = np.array(state_vector("hidden.x", hidden.get("x"), self.model.n),
                                dtype=float)

    def _step(self, t, h):
        if not (math.isfinite(h) and h > 0):
            self.fail(f"step size {h!r} at t = {t!r} is not allowed: must be a finite "
                      "number > 0")
        check_inputs(self.model.inputs, self.u, t)
        assert self.plant is not None  # steps follow _setup(), which built it
        try:
            self.plant.step(self.u, h)
        except IntegrationError as exc:
            self.fail(f"plant step at t = {t!r} failed: {exc}")
        except StateNotFinite as exc:
            self.fail(f"state {list(self.model.states)} at t = {t + h!r} is not allowed: "
                      f"must be finite (the plant diverged: {exc})")
        except Exception as exc:  # noqa: BLE001 - the model's own code: a failure, named
            self.fail(f"plant step at t = {t!r} failed: the model's step raised "
                      f"{type(exc).__name__}: {exc}")
