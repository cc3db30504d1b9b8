"""The time-stamp predictor-controller for LTI and model plants.

Over a network the measurement's delay varies from packet to packet and packets are
lost, but each sample carries the time it was taken (its **stamp**, the channel's
``stamp`` output, ``delaycomp.maths.channel``). At each sampling instant ``t_i = t0 + i T``
the controller receives ``y = x(s)`` and ``s``; it keeps an estimate ``z_i`` of the plant's
state ``x(t_i)``:

- a **new** sample (``s`` later than the last one used) no older than ``age_max``
  (``t_i - s <= age_max``): ``z_i`` is ``y`` carried from ``s`` to ``t_i`` through the
  plant's flow with the inputs the plant received meanwhile;
- otherwise (the sample was lost, is the one used before, or is too old): ``z_i`` is
  ``z_{i-1}`` carried from ``t_{i-1}`` to ``t_i`` (predicting from the last sample
  received);

and outputs ``u_i = K x_hat``, ``x_hat = z_i`` carried over ``[t_i, t_i + tau]``
(``compensated``), or ``u_i = K y`` (``uncompensated``), held over ``[t_i, t_{i+1})``.

The plant receives the controller's output ``tau`` later (a constant input delay: a
transport delay, or a network channel behind a play-out buffer, ``policy = "playout"``):
over ``[t_j + tau, t_{j+1} + tau)`` it sees ``u_j``, before ``t0 + tau`` the history
``u0``. The flows are exact (``delaycomp.maths.lti.flow``, one matrix exponential per
distinct piece length), so for an LTI plant without disturbance ``x_hat = x(t_i + tau)``
up to round-off, for any delays and losses of the measurement channel. A stamp before
``t0`` is the plant's initial state: the history ``x0`` holds until ``t0``, where the plant
starts (so a sample stamped ``s < t0`` is ``x(t0)``).

``age_max`` sizes the stored inputs: the outputs of the last ``floor((age_max + tau) / T)
+ 2`` periods.

``StampedModelController`` is the same controller for a model plant ``x' = f(x, u)``
(``delaycomp.maths.model``) with a zero-order-hold law ``u_i = k(x_hat)``: the flows are
the model's ODE solved piece by piece (``delaycomp.maths.predictors.integrate``, at the
tolerance ``tol``), so the prediction is exact to that tolerance. Both share the
decisions, the stored outputs and the state (one base class); only the flow and the
feedback differ.

Examples
--------
A scalar plant ``x' = x + u``, its state measured with a delay of 0.3 s, sampled every
0.5 s: the prediction carries the sample over its age plus ``tau``:

>>> import math
>>> c = StampedController([[1.0]], [[1.0]], [[-2.0]], T=0.5, tau=0.0, age_max=1.0,
...                       mode="compensated", u0=[0.0])
>>> x_hat = c.predict([1.0], stamp=0.0)      # at t0 = 0: the sample is x(0)
>>> float(x_hat[0])
1.0
>>> c.commit(c.propose([1.0], 0.0), [1.0], 0.0)
>>> x1 = math.e ** 0.5 * 1.0 + (math.e ** 0.5 - 1.0) * (-2.0)  # x(0.5) under u = -2
>>> x02 = math.e ** 0.2 * 1.0 + (math.e ** 0.2 - 1.0) * (-2.0)  # x(0.2), sent at 0.2
>>> abs(float(c.predict([x02], stamp=0.2)[0]) - x1) < 1e-14
True
"""

from __future__ import annotations

import math
from collections import OrderedDict, deque

import numpy as np

from delaycomp.maths.grid import MAX_STEPS, check_steps
from delaycomp.maths.lti import MODES, as_matrices, flow
from delaycomp.maths.model import Model
from delaycomp.maths.predictors import DEFAULT_TOL, integrate

#: the flows kept, by piece length (the lengths of T and of tau's rest recur; a stamp's
#: first piece varies): a cache, the results do not depend on it
_FLOWS_KEPT = 32
#: how close to a breakpoint of the input (t_j + tau) a time is taken as on it, in T
SNAP = 1e-9


class _StampedCore:
    """What the time-stamp controllers share: the parameters' checks, the stored outputs,
    the input pieces the plant receives, the decision new / too old / lost and the state.
    A subclass sets ``n``, ``m`` and gives the flow over input pieces (``_carry``) and
    the feedback (``_feedback``)."""

    n: int
    m: int

    def _setup(self, T: float, tau: float, age_max: float, mode: str, u0, t0: float) -> None:
        for name, value, low in (("T", T, None), ("tau", tau, 0.0), ("age_max", age_max, 0.0),
                                 ("t0", t0, -math.inf)):
            if not (math.isfinite(value) and (value > 0 if low is None else value >= low)):
                raise ValueError(f"{name} = {value!r} is not allowed: must be a finite number "
                                 + ("> 0" if low is None else f">= {low!r}"))
        if mode not in MODES:
            raise ValueError(f"mode = {mode!r} is not allowed: must be one of "
                             f"{', '.join(MODES)}")
        self.T, self.tau, self.age_max, self.mode, self.t0 = T, tau, age_max, mode, t0
        check_steps("age_max + tau", age_max + tau, (age_max + tau) / T,
                    f"sampling periods of T = {T!r}")
        #: outputs stored: those the plant may have received since a sample of age age_max
        self.L = math.floor((age_max + tau) / T) + 2
        assert self.L <= MAX_STEPS + 2
        self.u0 = np.asarray(u0, dtype=float).reshape(self.m).copy()
        self.held = self.u0.copy()
        # history[0] = u_{i-1}, history[1] = u_{i-2}, ...
        self.history: deque[np.ndarray] = deque([self.u0.copy() for _ in range(self.L)],
                                                maxlen=self.L)
        self.i = 0                       # the current sampling instant t0 + i T
        self.z: np.ndarray | None = None  # the estimate of x(t_{i-1}) (None before t0)
        self.stamp = -math.inf           # the stamp of the newest sample used
        #: this instant's estimate for its sample ((i, stamp, y), result): propose and
        #: commit read it once (it changes only with commit and set_state)
        self._memo: tuple | None = None

    # -- what a subclass gives ---------------------------------------------------------
    def _carry(self, x: np.ndarray, pieces: list[tuple[float, np.ndarray]]) -> np.ndarray:
        """The plant's state after the input ``pieces`` ``(length, u)``, oldest first, from
        ``x`` (a fresh array the method may overwrite)."""
        raise NotImplementedError

    def _feedback(self, x: np.ndarray) -> np.ndarray:
        """The delay-free feedback at the state ``x``."""
        raise NotImplementedError

    # -- the plant's input and flow ----------------------------------------------------
    def _input(self, j: int) -> np.ndarray:
        """``u_j``, the output held over ``[t_j, t_{j+1})`` (``u0`` for ``j < 0``)."""
        if j < 0:
            return self.u0
        back = self.i - 1 - j
        if not 0 <= back < self.L:  # the estimate never reaches beyond age_max + tau
            raise ValueError(f"output {j} is not stored (instant {self.i}, {self.L} kept)")
        return self.history[back]

    def _piece(self, w: float) -> int:
        """The output ``j`` the plant receives just after time ``w``: ``t_j + tau <= w <
        t_{j+1} + tau`` (a time within round-off of a breakpoint is on it)."""
        x = (w - self.t0 - self.tau) / self.T
        j = math.floor(x)
        return j + 1 if x - j > 1.0 - SNAP else j

    def advance(self, x, a: float, b: float) -> np.ndarray:
        """The plant's state at ``b`` from ``x`` at ``a <= b``, with the inputs it receives
        over ``[a, b]``, piece by piece."""
        # a copy: with no piece to walk (a sample taken at the instant) the result is x,
        # which must not alias the caller's array (the FMU's input y, set in place)
        x = np.array(x, dtype=float).reshape(self.n)
        tol = SNAP * self.T
        pieces = []
        while b - a > tol:
            j = self._piece(a)
            end = min(self.t0 + (j + 1) * self.T + self.tau, b)
            pieces.append((end - a, self._input(j)))
            a = end
        return self._carry(x, pieces) if pieces else x

    # -- the controller ----------------------------------------------------------------
    def _time(self) -> float:
        return self.t0 + self.i * self.T

    def estimate(self, y, stamp: float) -> tuple[np.ndarray, bool]:
        """``(z_i, new)``: the estimate of ``x(t_i)`` from the sample ``y`` taken at
        ``stamp`` (``new``: the sample is used) or, where it is not new or too old, from
        the last estimate."""
        t = self._time()
        if not (math.isfinite(stamp) and stamp <= t + SNAP * self.T):
            raise ValueError(f"stamp = {stamp!r} at t = {t!r} is not allowed: must be a finite "
                             "time <= t (the send time of the sample shown)")
        y = np.asarray(y, dtype=float).reshape(self.n)
        key = (self.i, stamp, y.tobytes())
        if self._memo is not None and self._memo[0] == key:
            return self._memo[1]
        s = max(stamp, self.t0)  # before t0: the history x0, the plant's state at t0
        if (stamp > self.stamp and t - s <= self.age_max + SNAP * self.T) or self.z is None:
            # the first instant always uses its sample: a stamp at most t0 (the history)
            got = self.advance(y, s, t), True
        else:
            got = self.advance(self.z, t - self.T, t), False
        self._memo = (key, got)
        return got

    def predict(self, y, stamp: float) -> np.ndarray:
        """``x_hat``, the predicted ``x(t_i + tau)`` (the estimate carried over ``tau``)."""
        t = self._time()
        return self.advance(self.estimate(y, stamp)[0], t, t + self.tau)

    def propose(self, y, stamp: float) -> np.ndarray:
        """The control: the feedback at ``x_hat`` (compensated) or at ``y``, not yet held."""
        if self.mode == "uncompensated":
            return self._feedback(np.asarray(y, dtype=float).reshape(self.n))
        return self._feedback(self.predict(y, stamp))

    def commit(self, u, y, stamp: float) -> None:
        """Hold ``u`` over the period; store it and the estimate of this instant."""
        z, new = self.estimate(y, stamp)
        if new:
            self.stamp = max(stamp, self.stamp)
        self.z = z
        u = np.array(u, dtype=float).reshape(self.m)
        self.held = u
        self.history.appendleft(u)
        self.i += 1

    # -- state, for FMU get/set state -------------------------------------------------
    def get_state(self) -> dict:
        """The held output, the input history, the instant, the estimate and the last
        stamp used, as JSON-friendly values."""
        return {"held": self.held.tolist(), "history": [h.tolist() for h in self.history],
                "i": self.i, "z": None if self.z is None else self.z.tolist(),
                "stamp": None if self.stamp == -math.inf else self.stamp}

    def set_state(self, state: dict) -> None:
        """Restore what ``get_state`` returned (checked by the FMU that holds it)."""
        self.held = np.asarray(state["held"], dtype=float)
        self.history = deque((np.asarray(h, dtype=float) for h in state["history"]),
                             maxlen=self.L)
        self.i = int(state["i"])
        self._memo = None
        self.z = None if state["z"] is None else np.asarray(state["z"], dtype=float)
        self.stamp = -math.inf if state["stamp"] is None else float(state["stamp"])


class StampedController(_StampedCore):
    """Stepping object of the time-stamp controller, free of any FMI concern.

    Contract (as ``delaycomp.maths.zoh.ZOHController``'s, with the stamp):

    1. ``propose(y, stamp)`` returns the output at the current sampling instant from the
       sample ``y`` taken at ``stamp`` and the stored state, without changing it;
    2. ``commit(u, y, stamp)`` holds ``u`` over the period, stores it and the estimate of
       this instant; exactly once per sampling instant;
    3. ``held`` is the output between sampling instants (``u0`` before the first commit).

    Raises
    ------
    ValueError
        A parameter out of its range (named), or a stamp later than the instant.
    """

    def __init__(self, A, B, K, T: float, tau: float, age_max: float, mode: str, u0,
                 t0: float = 0.0):
        A, B = as_matrices(A, B)
        self.A, self.B = A, B
        self.n, self.m = B.shape
        self.K = np.asarray(K, dtype=float).reshape(self.m, self.n)
        self._setup(T, tau, age_max, mode, u0, t0)
        self._flows: OrderedDict[float, tuple[np.ndarray, np.ndarray]] = OrderedDict()

    def _flow(self, length: float) -> tuple[np.ndarray, np.ndarray]:
        got = self._flows.get(length)
        if got is None:
            got = flow(self.A, self.B, length)
            self._flows[length] = got
            if len(self._flows) > _FLOWS_KEPT:
                self._flows.popitem(last=False)
        return got

    def _carry(self, x: np.ndarray, pieces: list[tuple[float, np.ndarray]]) -> np.ndarray:
        """Exact flows, one matrix exponential per distinct piece length (cached)."""
        for length, u in pieces:
            E, G = self._flow(length)
            x = E @ x + G @ u
        return x

    def _feedback(self, x: np.ndarray) -> np.ndarray:
        """``K x``."""
        return self.K @ x


class StampedModelController(_StampedCore):
    """The time-stamp controller for a model plant ``x' = f(x, u)`` (a nonlinear loop).

    The same contract, decisions (new, too old, lost), ``age_max`` rule, stored outputs
    (``L``), ``t0`` and state as ``StampedController``; the flows over the input pieces
    are the model's ODE solved piece by piece (``delaycomp.maths.predictors.integrate``,
    DOP853 at ``rtol = atol = tol``, as the numerical predictor of
    ``delaycomp.maths.nlcontrol.ZOHModelController``), and the feedback is the model's
    zero-order-hold law ``k(x_hat, p)`` (``p``: the parameters with the controller's
    ``T``). The prediction is exact up to the solves' tolerance, for any delays and
    losses of the measurement channel.

    Parameters
    ----------
    model : delaycomp.maths.model.Model
        The plant and its feedback; ``CONTROL = "zoh"`` (``k(x, p)``).
    params : dict or None
        The model's parameters (``None``: its defaults); ``T`` is set to the period.
    T, tau, age_max, mode, u0, t0
        As for ``StampedController``.
    tol : float
        Relative and absolute tolerance of each ODE solve, ``0 < tol < 1``.

    Raises
    ------
    ValueError
        A parameter out of its range (named), a model with a continuous feedback, or a
        stamp later than the instant.

    Examples
    --------
    The scalar plant ``x' = x + u`` of ``StampedController``'s example, written as a
    model: the prediction agrees with the exact one to the solves' tolerance:

    >>> import numpy as np
    >>> from delaycomp.maths.model import Model
    >>> plant = Model("scalar", ("x",), ("u",), "zoh", lambda x, u, p: x + u,
    ...               lambda x, p: -2.0 * x)
    >>> c = StampedModelController(plant, None, T=0.5, tau=0.2, age_max=1.0,
    ...                            mode="compensated", u0=[0.0])
    >>> exact = StampedController([[1.0]], [[1.0]], [[-2.0]], T=0.5, tau=0.2,
    ...                           age_max=1.0, mode="compensated", u0=[0.0])
    >>> for ctrl in (c, exact):
    ...     ctrl.commit(ctrl.propose([1.0], 0.0), [1.0], 0.0)
    >>> a, b = c.predict([0.9], stamp=0.3), exact.predict([0.9], stamp=0.3)
    >>> bool(abs(a[0] - b[0]) < 1e-9)
    True
    """

    def __init__(self, model: Model, params, T: float, tau: float, age_max: float, mode: str,
                 u0, t0: float = 0.0, tol: float = DEFAULT_TOL):
        if model.control != "zoh":
            raise ValueError(f"model = {model.name!r} is not allowed: its CONTROL is "
                             f"{model.control!r}; the time-stamp controller holds k(x, p) "
                             "over each period (CONTROL = 'zoh')")
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0 < tol < 1:
            raise ValueError(f"tol = {tol!r} is not allowed: must be a number > 0 and < 1")
        self.model, self.tol = model, float(tol)
        self.n, self.m = model.n, model.m
        self._setup(T, tau, age_max, mode, u0, t0)
        self.p = model.params() if params is None else dict(params)
        self.p["T"] = float(T)

    def _carry(self, x: np.ndarray, pieces: list[tuple[float, np.ndarray]]) -> np.ndarray:
        """The model's ODE over the pieces (one DOP853 solve each, at ``tol``)."""
        return integrate(self.model.f, self.p, x, pieces, self.tol, self.tol)

    def _feedback(self, x: np.ndarray) -> np.ndarray:
        """``k(x, p)``."""
        return np.asarray(self.model.k(x, self.p), dtype=float).reshape(self.m)
