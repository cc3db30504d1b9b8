"""The zero-order-hold sampled-data controller of Theorem 3.2, for LTI plants.

At each sampling instant ``t_i = t0 + iT`` the controller receives ``y_i = x(t_i - r)``
and computes

- ``compensated``:   ``u_i = K Phi(y_i, u_{i-1}, ..., u_{i-l-q-1})`` (Corollary 3.4, (3.15)),
- ``uncompensated``: ``u_i = K y_i`` (the baseline (3.21)),

and holds ``u_i`` over ``[t_i, t_{i+1})``. The past inputs are the controller's own held
outputs; before ``t0`` they are the initial history ``u0`` (constant on each period).

``tau`` must be ``l T``; with ``pad=True`` a ``tau`` that is not is padded up to
``tau_eff = ceil(tau / T) T`` (Remark 3.3(b), as ``delaycomp.maths.nlcontrol``'s
``ZOHModelController``): the predictor predicts over ``tau_eff`` and the controller's
output is delayed by ``padding = tau_eff - tau < T``, so that ``u_i`` reaches the output
at ``t_i + padding`` (the ``pad_line``, here one value: the output held before it). The
plant then sees ``u(t - tau_eff)``: the loop is the unpadded loop with ``tau = tau_eff``.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from delaycomp.maths import grid
from delaycomp.maths.grid import padded_delay
from delaycomp.maths.lti import MODES, LTIPredictor, as_matrices


class ZOHController:
    """Stepping object of the ZOH controller, free of any FMI concern.

    Contract:

    1. ``propose(y)`` returns the output at a sampling instant from the measurement ``y``
       and the stored history, without changing any state (it may be called again with
       another ``y`` at the same instant).
    2. ``commit(u)`` makes ``u`` the held output of the current period and shifts it into
       the history; it is called exactly once per sampling instant.
    3. ``held`` is the output between sampling instants (``u0`` before the first commit).
    4. With padding (``pad``, ``padding > 0``) the output is ``held`` from ``t_i +
       padding`` on and ``pad_line[0]`` (the value held before the last commit) before
       it: ``output(released)`` says which.
    """

    def __init__(self, A, B, K, T: float, r: float, tau: float, mode: str, u0,
                 pad: bool = False):
        A, B = as_matrices(A, B)
        self.n, self.m = B.shape
        self.K = np.asarray(K, dtype=float).reshape(self.m, self.n)
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.mode = mode
        tau_eff = padded_delay(tau, T) if tau >= 0 else tau
        if tau_eff != tau and not pad:
            grid.periods(tau, T, padding=True)  # refuses it, saying what padding gives
        self.tau_effective = tau_eff
        self.padding = tau_eff - tau
        self.predictor = LTIPredictor(A, B, T, r, tau_eff)
        u0 = np.asarray(u0, dtype=float).reshape(self.m)
        self.held = u0.copy()
        # the output held before the last commit, shown until t_i + padding (none: no pad)
        self.pad_line: list[np.ndarray] = [u0.copy()] if self.padding > 0 else []
        # history[0] = u_{i-1}, history[1] = u_{i-2}, ...
        self.history: deque[np.ndarray] = deque(
            [u0.copy() for _ in range(self.predictor.L)], maxlen=self.predictor.L
        )

    def propose(self, y) -> np.ndarray:
        """The control ``u_i = K Phi(y)`` (compensated) or ``K y`` for the sample ``y``, not yet
        held."""
        y = np.asarray(y, dtype=float).reshape(self.n)
        if self.mode == "uncompensated":
            return self.K @ y
        return self.K @ self.predictor.predict(y, self.history)

    def commit(self, u) -> None:
        """Hold ``u`` over the period and store it in the input history."""
        u = np.array(u, dtype=float).reshape(self.m)
        if self.pad_line:
            self.pad_line[0] = self.held
        self.held = u
        self.history.appendleft(u)

    def output(self, released: bool = True) -> np.ndarray:
        """The output between sampling instants: ``held``, or with padding before ``t_i +
        padding`` (``released`` false) the value held before it."""
        return self.held if released or not self.pad_line else self.pad_line[0]

    # -- state, for FMU get/set state -------------------------------------------------
    def get_state(self) -> dict:
        """The held output, the input history and the padding line, as JSON-friendly
        values."""
        return {"held": self.held.tolist(), "history": [h.tolist() for h in self.history],
                "pad_line": [u.tolist() for u in self.pad_line]}

    def set_state(self, state: dict) -> None:
        """Restore the state ``get_state`` returned."""
        self.held = np.asarray(state["held"], dtype=float)
        self.history = deque(
            (np.asarray(h, dtype=float) for h in state["history"]), maxlen=self.predictor.L
        )
        self.pad_line = [np.asarray(u, dtype=float) for u in state.get("pad_line", [])]
