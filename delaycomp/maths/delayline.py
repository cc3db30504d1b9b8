"""A transport delay on a fixed communication grid, in the manner of a discrete delay line.

Difference equation, for a grid ``t_k = t0 + k h`` and a delay ``d = D h`` (``D`` a
non-negative integer)::

    y_k = u_{k-D}            with u_j = u_init for j < 0

``u_k`` is the input value at ``t_k``. For a signal that is piecewise constant on the
grid (held over ``[t_k, t_{k+1})``) this is exactly ``y(t) = u(t - d)``; for a continuous
signal it is exact at the grid points. The line does not interpolate. With ``D >= 1`` the
output at ``t_k`` depends only on inputs of earlier grid points (no direct feedthrough);
with ``D = 0`` it is the input itself.
"""

from __future__ import annotations

from collections import deque

from delaycomp.maths import grid


def steps_of(delay: float, h: float) -> int:
    """Return ``D`` with ``delay = D h``; raise ``ValueError`` if there is none."""
    return grid.steps_of(delay, h, "delay", f"the communication step {h!r}")


class DelayLine:
    """``n`` channels delayed by ``D`` grid steps.

    Contract: ``output(u)`` gives ``y_k`` for the current input ``u_k`` without changing
    state; ``push(u)`` stores ``u_k`` when the grid advances from ``t_k`` to ``t_{k+1}``.
    """

    def __init__(self, n: int, D: int, u_init):
        if D < 0:
            raise ValueError(f"D must be >= 0, got {D}")
        self.n = n
        self.D = D
        init = tuple(float(v) for v in u_init)
        if len(init) != n:
            raise ValueError(f"u_init must have {n} values, got {len(init)}")
        self.buffer: deque[tuple[float, ...]] = deque([init] * D, maxlen=D)

    def output(self, u) -> tuple[float, ...]:
        """The output now: the input of D steps ago (``u`` itself when ``D = 0``)."""
        if self.D == 0:
            return tuple(map(float, u))
        return self.buffer[0]

    def push(self, u) -> None:
        """Take this step's input ``u`` (the oldest value leaves)."""
        if self.D:
            self.buffer.append(tuple(map(float, u)))

    def get_state(self) -> list:
        """The buffer, oldest first, as lists (for the FMU state)."""
        return [list(v) for v in self.buffer]

    def set_state(self, state: list) -> None:
        """Restore the buffer ``get_state`` returned."""
        self.buffer = deque((tuple(v) for v in state), maxlen=self.D)
