"""Reference traces for Example 3.6 (Figures 1-3), computed without the delaycomp package.

Independent computation: the method of steps with the exact scalar flow. Over a sampling
period the input is constant, ``x' = x + u_i``, so ``x(iT + s) = e^s (x(iT) + u_i) - u_i``.
The measurement ``x(iT - r)`` is that formula evaluated in the period holding ``iT - r``
(or the initial function ``x0`` for ``iT - r <= 0``). The controllers are written here from
the paper directly:

- uncompensated (3.21): ``u_i = -k x(iT - r)``;
- compensated (3.22), for ``0 <= r < T`` and ``tau = 0``:
  ``u_i = -k e^r x(iT - r) - k (e^r - 1) u_{i-1}``, with ``u_{-1} = u0``.

Only the Python standard library is used (``math.exp``, relative error ~1e-16), so the
traces are exact to round-off. Run ``python reference/example_3_6.py`` from the repository
root to regenerate ``reference/example-3.6/``.
"""

from __future__ import annotations

import math
from pathlib import Path

from reftools import main, write_trace

OUT = Path(__file__).resolve().parent / "example-3.6"

#: name -> (k, T, r, mode, x0, u0, N, stop time), the paper's Figures 1, 2 and 3
CASES = {
    "fig1": dict(k=2.0, T=1.0, r=0.1, mode="uncompensated", x0=1.0, u0=0.0, N=100, stop=20.0),
    "fig2": dict(k=2.0, T=1.0, r=0.3, mode="uncompensated", x0=1.0, u0=0.0, N=100, stop=20.0),
    "fig3": dict(k=2.0, T=1.0, r=0.3, mode="compensated", x0=1.0, u0=4.0, N=100, stop=20.0),
}


def trace(k, T, r, mode, x0, u0, N, stop):
    """Rows ``(t, x, u)`` at ``t = j T / N`` for ``j = 0 .. stop N / T``."""
    periods = round(stop / T)
    xs = [x0]  # x(iT)
    us = []    # u_i

    q = round(r / T) if abs(r / T - round(r / T)) < 1e-12 else math.floor(r / T)
    r_t = r - q * T
    for i in range(periods + 1):
        # sample instant iT - r, written as (i - q) T - r~ to avoid round-off in the period
        y = x0 if i * T - r <= 0 else (
            xs[i - q] if r_t == 0 else math.exp(T - r_t) * (xs[i - q - 1] + us[i - q - 1])
            - us[i - q - 1])
        if mode == "uncompensated":
            u = -k * y
        else:
            assert 0 <= r < T, "(3.22) holds for r < T"
            u_prev = us[i - 1] if i > 0 else u0
            u = -k * math.exp(r) * y - k * (math.exp(r) - 1) * u_prev
        us.append(u)
        xs.append(math.exp(T) * (xs[i] + u) - u)
    rows = []
    for j in range(periods * N + 1):
        i, m = divmod(j, N)
        s = m * T / N
        x = xs[i] if m == 0 else math.exp(s) * (xs[i] + us[i]) - us[i]
        rows.append((i * T + s, x, us[i]))
    return rows


def write(name: str, case: dict) -> None:
    """Write case ``name``'s trace and settings files (``reftools.write_trace``)."""
    write_trace(OUT, name, ("time", "plant.x", "controller.u"), trace(**case), case["stop"],
                case["T"] / case["N"], 1e-09)


if __name__ == "__main__":
    main(OUT, CASES, write)
