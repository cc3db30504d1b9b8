"""An independent solution of a sampled, delayed zero-order-hold loop, for the tests.

It shares no code with delaycomp: the plant is integrated with scipy's DOP853 at tight
tolerance over each interval on which its (delayed, held) input is constant (the method of
steps), the sample ``x(t_i - r)`` is read from the dense output, and the prediction
``Phi`` is another DOP853 solve over the window ``[t_i - r, t_i + tau)`` with the inputs
the plant receives there. No matrix exponential, no delay line, no master.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

RTOL, ATOL = 1e-12, 1e-14


def solve_zoh_loop(f, k, T: float, r: float, tau: float, x0, u0, stop: float, N: int,
                   compensated: bool = True):
    """Trajectory of ``x' = f(x, u(t - tau))``, ``u = k(Phi)`` (or ``k(sample)``) held over
    each period, sampled at ``t_k = k T / N``. Returns ``(times, x rows, u rows)``; the
    histories are ``x = x0`` on ``[-r, 0]`` and ``u = u0`` on ``[-r - tau, 0)``."""
    x0 = np.asarray(x0, dtype=float)
    u0 = np.asarray(u0, dtype=float)
    periods = round(stop / T)
    ell = round(tau / T)
    assert abs(ell * T - tau) < 1e-12, "zero-order hold needs tau = l T"
    controls: list[np.ndarray] = []  # u_i for t in [iT, (i+1)T)
    pieces = []  # (t_start, t_end, dense solution)

    def u_ctrl(i: int) -> np.ndarray:
        return u0 if i < 0 else controls[i]

    def x_at(t: float) -> np.ndarray:
        if t <= 0.0:
            return x0 if t < 0.0 or not pieces else pieces[0][2](0.0)
        for a, b, sol in pieces:
            if a <= t <= b + 1e-15:
                return sol(min(t, b))
        raise AssertionError(f"x({t}) not computed yet")

    def flow(x, u, dt):
        if dt <= 0:
            return np.asarray(x, dtype=float)
        sol = solve_ivp(lambda _t, z: f(z, u), (0.0, dt), x, method="DOP853", rtol=RTOL,
                        atol=ATOL)
        return sol.y[:, -1]

    x_now = x0.copy()
    for i in range(periods + 1):
        t_i = i * T
        y = x_at(t_i - r)
        if compensated:
            # the plant's input on [t_i - r, t_i + tau) is u_ctrl(s - tau): piecewise
            # constant with breaks at multiples of T
            z, s = np.asarray(y, dtype=float), t_i - r
            while s < t_i + tau - 1e-12:
                j = math.floor((s - tau) / T + 1e-9)
                end = min((j + 1) * T + tau, t_i + tau)
                z = flow(z, u_ctrl(j), end - s)
                s = end
            controls.append(np.asarray(k(z), dtype=float))
        else:
            controls.append(np.asarray(k(np.asarray(y, dtype=float)), dtype=float))
        if i == periods:
            break
        u_applied = u_ctrl(i - ell)
        sol = solve_ivp(lambda _t, z, u=u_applied: f(z, u), (t_i, t_i + T), x_now,
                        method="DOP853", rtol=RTOL, atol=ATOL, dense_output=True)
        pieces.append((t_i, t_i + T, sol.sol))
        x_now = sol.y[:, -1]
    times = np.arange(periods * N + 1) * (T / N)
    xs = np.array([x_at(t) if t > 0 else x0 for t in times])
    us = np.array([controls[min(math.floor(kk / N), periods)]
                   for kk in range(len(times))])
    return times, xs, us
