"""The zero-order-hold sampled-data controller of Theorem 3.2, for LTI plants.

At each sampling instant ``t_i = t0 + iT`` the controller receives ``y_i = x(t_i - r)``
and computes

- ``compensated``:   ``u_i = K Phi(y_i, u_{i-1}, ..., u_{i-l-q-1})`` (Corollary 3.4, (3.15)),
- ``uncompensated``: ``u_i = K y_i`` (the baseline (3.21)),

and holds ``u_i`` over ``[t_i, t_{i+1})``. The past inputs are the controller's own held
outputs; before ``t0`` they are the initial history ``u0`` (constant on each period).
"""

from __future__ import annotations

from collections import deque

import numpy as np

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
    """

    def __init__(self, A, B, K, T: float, r: float, tau: float, mode: str, u0):
        A, B = as_matrices(A, B)
        self.n, self.m = B.shape
        self.K = np.asarray(K, dtype=float).reshape(self.m, self.n)
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.mode = mode
        self.predictor = LTIPredictor(A, B, T, r, tau)
        u0 = np.asarray(u0, dtype=float).reshape(self.m)
        self.held = u0.copy()
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
        self.held = u
        self.history.appendleft(u)

    # -- state, for FMU get/set state -------------------------------------------------
    def get_state(self) -> dict:
        """The held output and the input history, as JSON-friendly values."""
        return {"held": self.held.tolist(), "history": [h.tolist() for h in self.history]}

    def set_state(self, state: dict) -> None:
        """Restore the state ``get_state`` returned."""
        self.held = np.asarray(state["held"], dtype=float)
        self.history = deque(
            (np.asarray(h, dtype=float) for h in state["history"]), maxlen=self.predictor.L
        )
