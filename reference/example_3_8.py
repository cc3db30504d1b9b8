"""Reference traces for Example 3.8 (2-D strict-feedforward plant, zero-order hold),
computed without the delaycomp package.

Plant (3.27): ``x1' = x2 + p(x2) u(t - tau)``, ``x2' = u(t - tau)``; ``P(w) = int_0^w p``,
``Theta(x) = (x1 - P(x2), x2)`` (3.28). Measurement ``y_i = x(iT - r)`` at ``t_i = iT``;
controller (Theorem 3.2, (3.3)-(3.4)) ``u(t) = u_i = k(Phi(y_i, u on [iT - r - tau, iT)))``
on ``[iT, (i+1)T)``, ``tau = l T``, with the nominal feedback (3.29)
``k(x) = -(x1 - P(x2)) / T^2 - 3 x2 / (2T)``. Initial histories ``x = x0`` on ``[-r, 0]``,
``u = u0`` on ``[-r - tau, 0)``: a measurement with ``iT - r <= 0`` reads ``x0``, and the plant
input is ``u0`` for ``t < tau``.

Method (exact flow, method of steps): under a constant input ``v`` for a time ``s``,
``x2(s) = x2 + v s`` and, since ``d/dt P(x2) = p(x2) v``,
``x1(s) = x1 + x2 s + v s^2 / 2 + P(x2 + v s) - P(x2)``. The plant input is constant on
every cell ``[jT, (j+1)T)`` (``u_{j-l}``, or ``u0`` for ``j < l``), so the state on the base
grid, the measurement ``x(iT - r)`` (``r = qT + r~``, ``q = [r/T]``) and the predictor ``Phi``
(the plant flow from ``iT - r``, state ``y_i``, to ``iT + tau`` over the stored inputs: the
last ``r~`` seconds of cell ``i - q - 1``, then whole cells ``i - q .. i + l - 1``; definition
before (2.1)) are all this closed form. P(w) = w^3 / 3 for p(w) = w^2 and 1 - cos w for
p(w) = sin w.

Tolerance: the traces are exact to round-off. ``python reference/example_3_8.py --check``
compares them with a direct ``solve_ivp`` (DOP853, rtol = atol = 1e-12) of (3.27) itself
(with ``p``, not ``P``), ``Phi`` also by ``solve_ivp`` from a time-indexed input history, and
checks (3.30) against the ``Phi``-based law for the ``default`` case (r < T, tau = 0); the
measured differences are <= 1.3e-14. ``RelTol`` in the ``.opt`` files is the tolerance of that
check.

Run ``python reference/example_3_8.py`` from the repository root to regenerate
``reference/example-3.8/``.
"""

from __future__ import annotations

import math
from itertools import pairwise
from pathlib import Path

import numpy as np
from reftools import main, solve, split_delay, write_trace
from scipy.integrate import quad

OUT = Path(__file__).resolve().parent / "example-3.8"
CHECK_TOL = 1e-12

#: p -> (p, P = int_0^w p)
NONLINEARITIES = {
    "w^2": (lambda w: w * w, lambda w: w ** 3 / 3.0),
    "sin": (math.sin, lambda w: 1.0 - math.cos(w)),
}

#: name -> nonlinearity p, period T, measurement delay r, input delay tau = l T, initial
#: state x0 (constant on [-r, 0]), initial input u0 (constant on [-r - tau, 0)), base steps
#: per period N, stop time
CASES = {
    "default": dict(p="w^2", T=1.0, r=0.5, tau=0.0, x0=(1.0, -1.0), u0=0.0, N=100, stop=10.0),
    "delayed": dict(p="w^2", T=1.0, r=1.5, tau=1.0, x0=(1.0, -1.0), u0=0.0, N=100, stop=10.0),
    "sin": dict(p="sin", T=1.0, r=0.5, tau=0.0, x0=(1.0, -1.0), u0=0.0, N=100, stop=10.0),
}


def make_flow(p):
    """The exact flow of (3.27) under a held input, for the nonlinearity ``p``: ``flow(x, v,
    s)``."""
    _, P = NONLINEARITIES[p]

    def flow(x, v, s):
        x1, x2 = x
        x2n = x2 + v * s
        return (x1 + x2 * s + v * s * s / 2.0 + (P(x2n) - P(x2)), x2n)

    return flow


def feedback(p, T):
    """The dead-beat feedback (3.29) for the nonlinearity ``p`` and period ``T``."""
    _, P = NONLINEARITIES[p]
    return lambda x: -(x[0] - P(x[1])) / T ** 2 - 3.0 * x[1] / (2.0 * T)


def simulate(p, T, r, tau, x0, u0, N, stop):
    """Exact closed loop: ``xs[j] = x(jT)``, ``us[i] = u_i``, ``ys[i] = y_i``, ``v(j)`` the
    plant input on ``[jT, (j+1)T)`` and the flow."""
    flow = make_flow(p)
    k = feedback(p, T)
    lag = round(tau / T)
    assert abs(lag * T - tau) < 1e-12 * max(1.0, tau), "tau must be a multiple of T"
    q, rt = split_delay(r, T)
    x0 = tuple(float(c) for c in x0)
    xs, us, ys = [x0], [], []

    def v(j):
        return u0 if j < lag else us[j - lag]

    for i in range(round(stop / T) + 1):
        if i <= q:                       # iT - r <= 0: the initial function
            y = x0
        elif rt == 0.0:
            y = xs[i - q]
        else:                            # iT - r = (i - q - 1) T + (T - r~)
            y = flow(xs[i - q - 1], v(i - q - 1), T - rt)
        z = y                            # Phi: from iT - r to iT + tau
        if rt > 0.0:
            z = flow(z, v(i - q - 1), rt)
        for j in range(i - q, i + lag):
            z = flow(z, v(j), T)
        ys.append(y)
        us.append(k(z))
        xs.append(flow(xs[i], v(i), T))
    return xs, us, ys, v, flow


def trace(p, T, r, tau, x0, u0, N, stop):
    """Rows ``(t, x1, x2, u)`` at ``t_k = (k // N) T + (k % N) T / N``, ``k = 0 .. stop N/T``."""
    xs, us, _, v, flow = simulate(p, T, r, tau, x0, u0, N, stop)
    rows = []
    for k in range(round(stop / T) * N + 1):
        j, m = divmod(k, N)
        x = xs[j] if m == 0 else flow(xs[j], v(j), m * T / N)
        rows.append((j * T + m * T / N, x[0], x[1], us[j]))
    return rows


def write(name: str, case: dict) -> None:
    """Write case ``name``'s trace and settings files (``reftools.write_trace``)."""
    write_trace(OUT, name, ("time", "plant.x1", "plant.x2", "controller.u"), trace(**case),
                case["stop"], case["T"] / case["N"], CHECK_TOL)


# ----------------------------------------------------------------------------- checks


def _ivp(rhs, y0, t0, t1):
    return solve(rhs, y0, t0, t1, CHECK_TOL)


def direct(p, T, r, tau, x0, u0, N, stop):
    """The same loop with (3.27) integrated by ``solve_ivp`` (``p`` itself, no ``P``) and
    ``Phi`` from the time-indexed history ``u(sigma)``; ``k`` from (3.29) as printed."""
    pf, _ = NONLINEARITIES[p]
    x0 = np.array(x0, dtype=float)
    us = []

    def u_at(sig):
        return u0 if sig < 0 else us[math.floor(sig / T + 1e-9)]

    def solve_plant(x, t0, t1):
        cuts = [t0] + [c * T + tau for c in range(-1, round(t1 / T) + 2)
                       if t0 + 1e-12 < c * T + tau < t1 - 1e-12] + [t1]
        for a, b in pairwise(cuts):
            val = u_at(0.5 * (a + b) - tau)
            x = _ivp(lambda t, y, val=val: np.array([y[1] + pf(y[1]) * val, val]), x, a, b)
        return x

    def k329(x):  # (3.29) with int_0^{x2} p by adaptive quadrature (signed)
        Pint = quad(pf, 0.0, x[1], epsabs=1e-15, epsrel=1e-12)[0]
        return -x[0] / T ** 2 + Pint / T ** 2 - 3.0 * x[1] / (2.0 * T)

    h = T / N
    periods = round(stop / T)
    x = x0.copy()
    xk = [x0.copy()]
    for i in range(periods + 1):
        ti = i * T
        tm = ti - r
        if tm <= 1e-12:
            y = x0
        else:
            kk = math.floor(tm / h + 1e-9)
            y = solve_plant(xk[kk], kk * h, tm)
        us.append(k329(solve_plant(y, tm, ti + tau)))
        if i == periods:
            break
        for m in range(N):
            x = solve_plant(x, ti + m * h, ti + (m + 1) * h)
            xk.append(x)
    return [(kk * h, *xv, us[kk // N]) for kk, xv in enumerate(xk)]


def check():
    """Print the checks: the trace against a direct solve, the dead-beat time, (3.30) against the
    Phi-based law."""
    for name, case in CASES.items():
        ref = np.array(trace(**case))
        d = np.array(direct(**case))
        err = np.abs(d - ref).max(axis=0)
        print(f"{name}: direct solve_ivp vs closed form: max |diff| per column {err.tolist()}")
        xn = np.hypot(ref[:, 1], ref[:, 2])
        k0 = next(k for k in range(len(xn)) if xn[k:].max() < 1e-9)
        N = case["N"]
        print(f"{name}: |x| < 1e-9 from t = {float(ref[k0, 0])!r}, "
              f"max |x| after: {xn[k0:].max():.1e}; |x| one period earlier "
              f"{xn[k0 - N]:.2e}; |x(stop)| = {xn[-1]:.1e}")
    # (3.30): r < T, tau = 0, q = l = 0
    case = CASES["default"]
    T, r = case["T"], case["r"]
    _, P = NONLINEARITIES[case["p"]]
    _, us, ys, _, _ = simulate(**case)
    u330 = []
    for i, y in enumerate(ys):
        u_prev = case["u0"] if i == 0 else us[i - 1]
        u330.append(-y[0] / T ** 2 + P(y[1]) / T ** 2 - (3 * T + 2 * r) / (2 * T ** 2) * y[1]
                    - r * (r + 3 * T) / (2 * T ** 2) * u_prev)
    print(f"default: (3.30) vs Phi-based u_i: max |diff| {np.abs(np.array(u330) - us).max():.1e}")


if __name__ == "__main__":
    main(OUT, CASES, write, {"--check": check})
