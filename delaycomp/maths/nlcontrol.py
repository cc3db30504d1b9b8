"""Predictor-based controllers for nonlinear plants, on the base grid ``h = T / N``.

Both are stepping objects free of FMI. Contract, at every base tick ``t_k``:

1. ``output(y)`` returns the control at ``t_k``; ``y`` is the measurement ``x(t_k - r)``
   and is read only at sampling instants ``t_i = t0 + iT``. It changes no state and may be
   called again (with another ``y``) at the same tick.
2. ``advance(y)`` commits the tick: the value returned by ``output(y)`` is the one held
   over ``[t_k, t_k + h)`` and recorded in the history; then the controller moves to
   ``t_{k+1}``.

The history (``InputHistory``) holds exactly what the plant will
receive ``tau`` later, so the prediction is exact (to the predictor's tolerance) from the
first sample with ``t_i >= r``.

- ``ContinuousController`` (Theorem 2.1): ``z' = f(z, u)``, ``u = k(t + tau, z)``,
  ``z(t_i) = Phi(y_i, history)`` at every ``t_i`` with ``i >= 1`` (not at ``t0``: there
  ``z = z0``). The input is realised on the base grid: ``u`` is evaluated at each ``t_k``
  and held for ``h`` (FMI 2.0 holds inputs over a communication step), and ``z`` is
  integrated with that held value, so ``z`` stays the plant's state ``tau`` ahead. It
  tends to the paper's continuous law as ``h -> 0``.
- ``ZOHModelController`` (Theorem 3.2): ``u_i = k(Phi(y_i, history))`` held over each
  period. ``tau`` must be ``l T``; with ``pad=True`` a ``tau`` that is not is padded up to
  ``ceil(tau / T) T`` (Remark 3.3(b)): the controller delays its own output by the
  difference and predicts over the padded delay.
"""

from __future__ import annotations

import numpy as np

from delaycomp.errors import DelaycompError
from delaycomp.maths import grid
from delaycomp.maths.delayline import DelayLine
from delaycomp.maths.grid import check_steps, padded_delay
from delaycomp.maths.history import InputHistory
from delaycomp.maths.model import Model
from delaycomp.maths.predictors import DEFAULT_TOL, integrate, numerical_predictor


def grid_steps(value: float, h: float, name: str) -> int:
    """Base steps in ``value`` (``delaycomp.maths.grid.steps_of``)."""
    return grid.steps_of(value, h, name)


class StateNotFinite(DelaycompError, ValueError):
    """A plant step from a finite state and input ended in a state that is not finite
    (the loop diverged: overflow, or a finite-time escape)."""


class ModelPlant:
    """The plant ``x' = f(x, u)`` stepped over held inputs: exact step, else ODE solve."""

    def __init__(self, model: Model, params: dict, x0, tol: float = DEFAULT_TOL):
        self.model, self.p, self.tol = model, dict(params), tol
        self.x = np.asarray(x0, dtype=float).reshape(model.n)

    def step(self, u, h: float) -> np.ndarray:
        """Advance the state over ``h`` with ``u`` held (the exact step, else an ODE solve);
        return the new state."""
        u = np.asarray(u, dtype=float).reshape(self.model.m)
        if self.model.step is not None:
            x = np.asarray(self.model.step(self.x, u, h, self.p), dtype=float)
        else:
            x = integrate(self.model.f, self.p, self.x, [(h, u)], self.tol, self.tol)
        if not np.isfinite(x).all():
            raise StateNotFinite(f"the state is not finite after the step (input "
                                 f"{u.tolist()})")
        self.x = x
        return x


#: the controller's predictor: the model's closed form, an ODE solve over the stored
#: inputs, or none (the uncompensated baseline: the feedback acts on the sample itself)
PREDICTORS = ("closed", "numerical", "none")


def _no_prediction(y, segments, p):
    """Phi = the sample: the loop without delay compensation (``mode = uncompensated``)."""
    return np.asarray(y, dtype=float)


class _Base:
    """What both controller families share: the model, the base grid, the predictor, the
    tick counter; each family sets its input history and its memo of ``output(y)``."""

    history: InputHistory
    _cache: tuple | None

    def __init__(self, model: Model, params: dict, T: float, r: float, tau: float, N: int,
                 u0, predictor: str, tol: float):
        if not T > 0:
            raise ValueError(f"T = {T!r} is not allowed: must be > 0")
        if not r >= 0:
            raise ValueError(f"r = {r!r} is not allowed: must be >= 0")
        if not tau >= 0:
            raise ValueError(f"tau = {tau!r} is not allowed: must be >= 0")
        if not (isinstance(N, int) and N >= 1):
            raise ValueError(f"N = {N!r} is not allowed: must be a positive integer")
        self.model, self.T, self.r, self.tau, self.N = model, float(T), float(r), float(tau), N
        self.h = self.T / N
        self.p = dict(params)
        self.p["T"] = self.T
        self.u0 = np.asarray(u0, dtype=float).reshape(model.m)
        if predictor == "closed":
            if model.predictor is None:
                raise ValueError(f"predictor = 'closed' is not allowed: model {model.name} "
                                 "has no closed-form predictor (use 'numerical')")
            self.phi = model.predictor
        elif predictor == "numerical":
            self.phi = numerical_predictor(model.f, tol, tol)
        elif predictor == "none":  # the uncompensated baseline: the sample itself
            self.phi = _no_prediction
        else:
            raise ValueError(f"predictor = {predictor!r} is not allowed: must be one of "
                             f"{', '.join(PREDICTORS)}")
        self.tol = tol
        self.k_tick = 0  # ticks since t0

    def _flow(self, x, u, h) -> np.ndarray:
        if self.model.step is not None:
            return np.asarray(self.model.step(x, u, h, self.p), dtype=float)
        return integrate(self.model.f, self.p, x, [(h, u)], self.tol, self.tol)

    @property
    def at_sample(self) -> bool:
        return self.k_tick % self.N == 0

    # -- state, for FMU get/set state -------------------------------------------------
    def get_state(self) -> dict:
        """Everything that changes while stepping, as JSON-friendly values."""
        return {"k_tick": self.k_tick, "history": self.history.get_state()}

    def set_state(self, state: dict) -> None:
        self.k_tick = int(state["k_tick"])
        self.history.set_state(state["history"])
        self._cache = None  # a memo of output(y): recomputed from the restored state


class ContinuousController(_Base):
    """Theorem 2.1 on the base grid (see the module docstring)."""

    def __init__(self, model: Model, params: dict, T: float, r: float, tau: float, N: int,
                 u0, z0, predictor: str = "closed", tol: float = DEFAULT_TOL):
        super().__init__(model, params, T, r, tau, N, u0, predictor, tol)
        self.history = InputHistory(grid_steps(r + tau, self.h, "r + tau"), self.h, self.u0)
        self.z = np.asarray(z0, dtype=float).reshape(model.n)
        self.t0 = 0.0
        self._cache: tuple | None = None  # (y, z after reset, u) at the current tick

    def _evaluate(self, y) -> tuple[np.ndarray, np.ndarray]:
        y = np.asarray(y, dtype=float)
        if self._cache is not None and np.array_equal(self._cache[0], y):
            return self._cache[1], self._cache[2]
        z = self.z
        if self.at_sample and self.k_tick > 0:
            z = np.asarray(self.phi(y, self.history.segments(), self.p), dtype=float)
        t = self.t0 + (self.k_tick // self.N) * self.T + (self.k_tick % self.N) * self.h
        u = np.asarray(self.model.k(t + self.tau, z, self.p), dtype=float).reshape(self.model.m)
        self._cache = (y.copy(), z, u)
        return z, u

    def output(self, y) -> np.ndarray:
        """The control at the current tick for the measurement ``y``."""
        return self._evaluate(y)[1]

    def get_state(self) -> dict:
        """Everything that changes while stepping, as JSON-friendly values."""
        return {**super().get_state(), "z": self.z.tolist(), "t0": self.t0}

    def set_state(self, state: dict) -> None:
        """Restore the state ``get_state`` returned."""
        super().set_state(state)
        self.z = np.array(state["z"], dtype=float).reshape(self.model.n)
        self.t0 = float(state["t0"])

    def advance(self, y) -> None:
        """Take the base step: the controller's copy of the plant moves under the control held,
        which enters the history."""
        z, u = self._evaluate(y)
        self.z = self._flow(z, u, self.h)
        self.history.push(u)
        self.k_tick += 1
        self._cache = None


class ZOHModelController(_Base):
    """Theorem 3.2 with any predictor (see the module docstring)."""

    def __init__(self, model: Model, params: dict, T: float, r: float, tau: float, N: int,
                 u0, predictor: str = "closed", tol: float = DEFAULT_TOL, pad: bool = False):
        super().__init__(model, params, T, r, tau, N, u0, predictor, tol)
        tau_eff = padded_delay(tau, T)
        if tau_eff != tau and not pad:
            grid.periods(tau, T, padding=True)  # refuses it, saying what padding gives
        self.tau_effective = tau_eff
        self.padding = tau_eff - tau
        self.pad_line = DelayLine(model.m, grid_steps(self.padding, self.h, "padding"), self.u0)
        # rounded half to even as round() (and the native twin's nearbyint), but a huge
        # tau stays a float (inf) that check_steps refuses, not an OverflowError
        W = grid_steps(r, self.h, "r") + float(np.rint(tau_eff / self.h))
        check_steps("r + tau", r + tau_eff, W, f"base steps of h = {self.h!r}")
        self.history = InputHistory(int(W), self.h, self.u0)
        self.held = self.u0.copy()
        self._cache: tuple | None = None

    def _held_now(self, y) -> np.ndarray:
        if not self.at_sample:
            return self.held
        y = np.asarray(y, dtype=float)
        if self._cache is None or not np.array_equal(self._cache[0], y):
            x_pred = self.phi(y, self.history.segments(), self.p)
            u = np.asarray(self.model.k(np.asarray(x_pred, dtype=float), self.p),
                           dtype=float).reshape(self.model.m)
            self._cache = (y.copy(), u)
        return self._cache[1]

    def output(self, y) -> np.ndarray:
        """The control held now for the measurement ``y`` (after the padding line)."""
        return np.asarray(self.pad_line.output(self._held_now(y)))

    def get_state(self) -> dict:
        """Everything that changes while stepping, as JSON-friendly values."""
        return {**super().get_state(), "held": self.held.tolist(),
                "pad_line": self.pad_line.get_state()}

    def set_state(self, state: dict) -> None:
        """Restore the state ``get_state`` returned."""
        super().set_state(state)
        self.held = np.array(state["held"], dtype=float).reshape(self.model.m)
        self.pad_line.set_state(state["pad_line"])

    def advance(self, y) -> None:
        """Take the base step: the control held enters the history and the padding line."""
        u = self._held_now(y)
        self.held = u
        self.history.push(u)
        self.pad_line.push(u)
        self.k_tick += 1
        self._cache = None


def make_controller(model: Model, params: dict, T: float, r: float, tau: float, N: int, u0,
                    z0=None, mode: str | None = None, predictor: str | None = None,
                    tol: float = DEFAULT_TOL,
                    pad: bool = False) -> ContinuousController | ZOHModelController:
    """The controller for ``model`` in ``mode`` (default: the model's CONTROL)."""
    mode = mode or model.control
    predictor = predictor or ("closed" if model.predictor is not None else "numerical")
    if mode != model.control:
        raise ValueError(f"mode = {mode!r} is not allowed: model {model.name} gives a "
                         f"{model.control} feedback")
    if mode == "continuous":
        if z0 is None:
            raise ValueError("z0 is required for the continuous-input controller")
        return ContinuousController(model, params, T, r, tau, N, u0, z0, predictor, tol)
    return ZOHModelController(model, params, T, r, tau, N, u0, predictor, tol, pad)

