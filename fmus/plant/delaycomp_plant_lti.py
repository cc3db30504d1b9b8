"""FMU slave: LTI plant ``x' = A x + B u``, exactly discretized over each step.

The adapter only copies values in and out; the maths is ``delaycomp.maths.lti.discretize``.
See README.md beside this file for the equations and the variable table.
"""

from __future__ import annotations

import math

import numpy as np

from delaycomp.fmu.slave import TableSlave, check_finite, check_inputs, state_vector
from delaycomp.maths.grid import same_step
from delaycomp.maths.lti import discretize
from delaycomp.names import indexed


class DelaycompPlantLTI(TableSlave):
    """LTI plant with n states and m inputs; A, B and x0 are parameters."""

    description = "LTI plant x' = A x + B u, exact zero-order-hold discretization per step"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        n, m = int(self.config["n"]), int(self.config["m"])
        self.n, self.m = n, m
        self.A = np.zeros((n, n))
        self.B = np.zeros((n, m))
        self.x0 = np.zeros(n)
        self.x = np.zeros(n)
        self.u = np.zeros(m)
        self._h: float | None = None  # step size of the cached discretization (same_step keys it)
        self._Ad: np.ndarray | None = None
        self._Bd: np.ndarray | None = None

        def elem(mat, i, j):
            return (lambda: float(mat[i, j])), (lambda v: mat.__setitem__((i, j), v))

        for i in range(n):
            for j in range(n):
                g, s = elem(self.A, i, j)
                self.parameter(f"A[{i + 1},{j + 1}]", g, s, "system matrix A")
        for i in range(n):
            for j in range(m):
                g, s = elem(self.B, i, j)
                self.parameter(f"B[{i + 1},{j + 1}]", g, s, "input matrix B")
        for i in range(n):
            get, put = (lambda i=i: float(self.x0[i])), (lambda v, i=i: self.x0.__setitem__(i, v))
            self.parameter(f"x0[{i + 1}]", get, put, "initial state x(t0)")
        self.input_names = indexed(self.config.get("input", "u"), m)
        self.output_names = indexed(self.config.get("state", "x"), n)
        for j, name in enumerate(self.input_names):
            self.real_input(name, (lambda j=j: float(self.u[j])),
                            (lambda v, j=j: self.u.__setitem__(j, v)),
                            "plant input, held constant over each communication step")
        for i, name in enumerate(self.output_names):
            self.real_output(name, (lambda i=i: float(self.x[i])), "plant state",
                             depends_on=())

    def _setup(self):
        for name, value in self._parameter_values():
            check_finite(name, value)
        self.x = self.x0.copy()
        self._h = None

    def _hidden_state(self) -> dict:
        return {"x": self.x.tolist()}

    def _restore_hidden(self, hidden: dict) -> None:
        self.x = np.array(state_vector("hidden.x", hidden.get("x"), self.n), dtype=float)

    def _parameter_values(self):
        for v in self.vars.values():
            if v.causality.name == "parameter":
                yield v.name, v.getter()

    def _step(self, t: float, step_size: float) -> None:
        if not (math.isfinite(step_size) and step_size > 0):
            self.fail(f"step size {step_size!r} at t = {t!r} is not allowed: must be a "
                      "finite number > 0")
        check_inputs(self.input_names, self.u, t)
        if self._h is None or not same_step(step_size, self._h, t):
            # a step within GRID_RTOL of the cached one is that step (a host's exact grid
            # t0 + k h passes steps that differ in the last bits): Ad(h), Bd(h) serve it,
            # off by ~ |step - h| |x'| (README.md beside this file); another step is
            # discretized and becomes the key
            self._Ad, self._Bd = discretize(self.A, self.B, step_size)
            self._zeros = np.zeros(self.n)
            self._h = step_size
        assert self._Ad is not None and self._Bd is not None  # made with _h, above at the latest
        x = self._Ad.dot(self.x) + self._Bd.dot(self.u)
        # x . 0 is 0 for a finite x and nan as soon as an entry is inf or nan: one cheap
        # test of the whole state on the hot path (np.isfinite(x).all() costs 2.5 times more)
        if math.isnan(x.dot(self._zeros)):
            self.fail(f"state {self.output_names} = {x.tolist()} at t = {t + step_size!r} "
                      "is not allowed: must be finite (the plant diverged: overflow)")
        self.x = x
