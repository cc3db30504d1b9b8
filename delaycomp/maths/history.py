"""The controller's record of its own outputs over the predictor window.

The plant receives the controller output ``u`` delayed by ``tau``, held constant over each
base step ``h`` (FMI 2.0 co-simulation holds inputs over a communication step). The
predictor at time ``t`` needs ``u`` on ``[t - r - tau, t)``: exactly ``W = (r + tau) / h``
held values. ``InputHistory`` keeps those (a bounded buffer) and hands them out as
segments ``(duration, u)``, oldest first, with equal neighbours merged, so a zero-order-hold
history of period ``T`` becomes a few segments of length ``T``.
"""

from __future__ import annotations

from collections import deque

import numpy as np


class InputHistory:
    """Held inputs of the last ``W`` base steps, initially the constant ``u_init``."""

    def __init__(self, W: int, h: float, u_init):
        if W < 0:
            raise ValueError(f"window must be >= 0 steps, got {W}")
        self.W, self.h = W, float(h)
        init = tuple(float(v) for v in np.ravel(u_init))
        self.m = len(init)
        self.values: deque[tuple[float, ...]] = deque([init] * W, maxlen=W)

    def push(self, u) -> None:
        """Append the value held over the base step just taken."""
        if self.W:
            self.values.append(tuple(float(v) for v in np.ravel(u)))

    def segments(self) -> list[tuple[float, np.ndarray]]:
        """``[(duration, u), ...]`` covering the window, oldest first, neighbours merged."""
        out: list[tuple[int, tuple[float, ...]]] = []
        for v in self.values:
            if out and out[-1][1] == v:
                out[-1] = (out[-1][0] + 1, v)
            else:
                out.append((1, v))
        return [(count * self.h, np.array(v)) for count, v in out]

    def get_state(self) -> list:
        """The stored inputs, oldest first, as lists (for the FMU state)."""
        return [list(v) for v in self.values]

    def set_state(self, state: list) -> None:
        """Restore the inputs ``get_state`` returned."""
        self.values = deque((tuple(v) for v in state), maxlen=self.W)
