"""Reference traces for Corollary 3.7 (chain of integrators, zero-order hold), computed
without the delaycomp package.

Loop (Theorem 3.2, (3.4), with Theta = identity): plant ``x' = A0 x + B0 u(t - tau)``, the
chain of ``n`` integrators; measurement ``y_i = x(iT - r)`` at ``t_i = iT``; controller output
``u(t) = u_i = K Phi(y_i, u on [iT - r - tau, iT))`` on ``[iT, (i+1)T)``, ``tau = l T``.
Initial histories ``x(theta) = x0`` on ``[-r, 0]`` and ``u(theta) = u0`` on ``[-r - tau, 0)``,
so a measurement with ``iT - r <= 0`` reads ``x0`` and the plant input is ``u0`` for ``t < tau``.

Method: the plant input is constant on every cell ``[jT, (j+1)T)`` (it is ``u_{j-l}``, or
``u0`` for ``j < l``), so the exact flow over a time ``s`` is
``x -> E(s) x + G(s) v`` with ``E(s) = exp(A0 s)``, ``G(s) = int_0^s exp(A0 w) dw B0``, both
read off ``scipy.linalg.expm`` of the augmented matrix ``[[A0, B0], [0, 0]] s``. The
measurement ``x(iT - r)``, with ``r = qT + r~`` (``q = [r/T]``), is that flow over ``T - r~``
in cell ``i - q - 1``; the predictor ``Phi`` is the same flow started at ``iT - r`` from
``y_i`` and run to ``iT + tau`` over the stored inputs (first the last ``r~`` seconds of cell
``i - q - 1``, then whole cells ``i - q .. i + l - 1``). This is the definition of ``Phi``
(Section 2, before (2.1)); the explicit sum (3.25) with the ``Q_p`` of (3.16) is not used to
make the traces, only checked against them.

``K`` is the dead-beat gain for the exact discretization ``(Ad, Bd) = (E(T), G(T))``:
Ackermann's formula with characteristic polynomial ``z^n``,
``K = -e_n' [Bd, Ad Bd, .., Ad^{n-1} Bd]^{-1} Ad^n`` (the matrix of Section 3.3 and Corollary
3.4 is ``exp(A0 T)(I + int_0^T exp(-A0 w) dw B0 K) = Ad + Bd K``, nilpotent for this ``K``;
for ``n = 2`` it is ``-(1/T^2, 3/(2T))``).

Tolerance: the traces are exact up to round-off (``expm`` of a nilpotent matrix, relative
error ~1e-16). ``python reference/corollary_3_7.py --check`` verifies them against a direct
``solve_ivp`` (DOP853, rtol = atol = 1e-12) of the same closed loop, with ``Phi`` also
computed by ``solve_ivp`` from a time-indexed input history, and checks (3.25)/(3.16) and the
gain; the measured differences are <= 3e-13 (in ``u``; see the report printed by
``--check``). ``RelTol`` in the ``.opt`` files is the tolerance of that check.

Run ``python reference/corollary_3_7.py`` from the repository root to regenerate
``reference/corollary-3.7/``.
"""

from __future__ import annotations

import math
from itertools import pairwise
from pathlib import Path

import numpy as np
from reftools import main, solve, split_delay, write_trace
from scipy.linalg import expm

OUT = Path(__file__).resolve().parent / "corollary-3.7"
CHECK_TOL = 1e-12

#: name -> chain length n, period T, measurement delay r, input delay tau = l T, initial
#: state x0 (constant on [-r, 0]), initial input u0 (constant on [-r - tau, 0)), base steps
#: per period N, stop time
CASES = {
    "default": dict(n=3, T=1.0, r=0.5, tau=1.0, x0=(1.0, -1.0, 0.5), u0=0.0, N=100,
                    stop=10.0),
    "n2": dict(n=2, T=0.5, r=0.75, tau=0.5, x0=(1.0, -2.0), u0=0.7, N=100, stop=5.0),
}


def chain(n):
    """The chain of ``n`` integrators: ``A`` (ones above the diagonal) and ``B = e_n``."""
    A = np.diag(np.ones(n - 1), 1)
    B = np.zeros(n)
    B[-1] = 1.0
    return A, B


def exact_flow(A, B, s):
    """``(E(s), G(s))``: ``x(s) = E x(0) + G v`` for constant input ``v``."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A
    M[:n, n] = B
    F = expm(M * s)
    return F[:n, :n], F[:n, n]


def deadbeat_gain(n, T):
    """Ackermann for ``(Ad, Bd)`` with all closed-loop eigenvalues at 0."""
    A, B = chain(n)
    Ad, Bd = exact_flow(A, B, T)
    W = np.column_stack([np.linalg.matrix_power(Ad, p) @ Bd for p in range(n)])
    e = np.zeros(n)
    e[-1] = 1.0
    return -np.linalg.solve(W.T, e) @ np.linalg.matrix_power(Ad, n)


def simulate(n, T, r, tau, x0, u0, N, stop):
    """Exact closed loop: ``(xs, us, v)`` with ``xs[j] = x(jT)``, ``us[i] = u_i`` and
    ``v(j)`` the plant input on ``[jT, (j+1)T)``."""
    A, B = chain(n)
    K = deadbeat_gain(n, T)
    lag = round(tau / T)
    assert abs(lag * T - tau) < 1e-12 * max(1.0, tau), "tau must be a multiple of T"
    q, rt = split_delay(r, T)
    flows = {}

    def flow(x, vj, s):
        if s not in flows:
            flows[s] = exact_flow(A, B, s)
        E, G = flows[s]
        return E @ x + G * vj

    x0 = np.array(x0, dtype=float)
    periods = round(stop / T)
    xs = [x0]
    us = []

    def v(j):
        return u0 if j < lag else us[j - lag]

    for i in range(periods + 1):
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
        us.append(float(K @ z))
        xs.append(flow(xs[i], v(i), T))
    return xs, us, v, flow


def trace(n, T, r, tau, x0, u0, N, stop):
    """Rows ``(t, x1 .. xn, u)`` at ``t_k = (k // N) T + (k % N) T / N``, ``k = 0 .. stop N/T``."""
    xs, us, v, flow = simulate(n, T, r, tau, x0, u0, N, stop)
    rows = []
    for k in range(round(stop / T) * N + 1):
        j, m = divmod(k, N)
        x = xs[j] if m == 0 else flow(xs[j], v(j), m * T / N)
        rows.append((j * T + m * T / N, *(float(c) for c in x), us[j]))
    return rows


def write(name: str, case: dict) -> None:
    """Write case ``name``'s trace and settings files (``reftools.write_trace``)."""
    header = ["time", *(f"plant.x{c + 1}" for c in range(case["n"])), "controller.u"]
    write_trace(OUT, name, header, trace(**case), case["stop"], case["T"] / case["N"],
                CHECK_TOL)


# ----------------------------------------------------------------------------- checks


def _ivp(rhs, y0, t0, t1):
    return solve(rhs, y0, t0, t1, CHECK_TOL)


def direct(n, T, r, tau, x0, u0, N, stop):
    """The same loop with every flow by ``solve_ivp`` and ``Phi`` from a time-indexed history
    ``u(sigma)`` (``u0`` for ``sigma < 0``, ``u_i`` on ``[iT, (i+1)T)``)."""
    A, B = chain(n)
    K = deadbeat_gain(n, T)
    x0 = np.array(x0, dtype=float)
    us = []

    def u_at(sig):  # controller output at time sig (sig < current sampling instant)
        return u0 if sig < 0 else us[math.floor(sig / T + 1e-9)]

    def solve_plant(x, t0, t1):
        """Plant from x(t0) to t1 driven by u(t - tau), split where u(. - tau) jumps."""
        cuts = [t0] + [c * T + tau for c in range(-1, round(t1 / T) + 2)
                       if t0 + 1e-12 < c * T + tau < t1 - 1e-12] + [t1]
        for a, b in pairwise(cuts):
            val = u_at(0.5 * (a + b) - tau)
            x = _ivp(lambda t, y, val=val: A @ y + B * val, x, a, b)
        return x

    periods = round(stop / T)
    rows = []
    x = x0.copy()
    xk = [x0.copy()]  # x at base steps
    h = T / N
    for i in range(periods + 1):
        ti = i * T
        # measurement: the stored plant trajectory is at base steps; integrate from the base
        # step just before iT - r (or take x0)
        tm = ti - r
        if tm <= 1e-12:
            y = x0
        else:
            kk = math.floor(tm / h + 1e-9)
            y = solve_plant(xk[kk], kk * h, tm)
        us.append(float(K @ solve_plant(y, tm, ti + tau)))
        if i == periods:
            break
        for m in range(N):
            t0 = ti + m * h
            x = solve_plant(x, t0, t0 + h)
            xk.append(x)
    for k, xv in enumerate(xk):
        rows.append((k * h, *xv, us[k // N]))
    return rows, us


def formula_3_25(n, T, r, tau, x0, u0, N, stop):
    """u_i from (3.25) with Q_p of (3.16) (A0 in place of A), fed the reference y_i."""
    A, B = chain(n)
    K = deadbeat_gain(n, T)
    lag = round(tau / T)
    q, rt = split_delay(r, T)
    xs, us, v, flow = simulate(n, T, r, tau, x0, u0, N, stop)
    # int_0^T exp(-A s) ds and int_0^rt exp(A s) ds via augmented exponentials
    def int_exp(Am, s):
        M = np.zeros((2 * n, 2 * n))
        M[:n, :n] = Am
        M[:n, n:] = np.eye(n)
        return expm(M * s)[:n, n:]
    Q = [None] + [expm(A * p * T) @ int_exp(-A, T) for p in range(1, lag + q + 1)]
    Q.append(expm(A * (lag + q) * T) @ int_exp(A, rt))
    out = []
    for i in range(len(us)):
        if i <= q:
            y = np.array(x0, dtype=float)
        elif rt == 0.0:
            y = xs[i - q]
        else:
            y = flow(xs[i - q - 1], v(i - q - 1), T - rt)
        hist = [u0 if i - p < 0 else us[i - p] for p in range(lag + q + 2)]
        out.append(float(K @ expm(A * (r + tau)) @ y
                         + sum(K @ Q[p] @ B * hist[p] for p in range(1, lag + q + 2))))
    return out, us


def check():
    """Print the checks: the dead-beat gain nilpotent, the trace against a direct solve, (3.25)
    against the Phi-based law."""
    for n, T in [(2, 0.5), (2, 1.0), (3, 1.0), (4, 0.3)]:
        K = deadbeat_gain(n, T)
        Ad, Bd = exact_flow(*chain(n), T)
        M = Ad + np.outer(Bd, K)
        nil = np.abs(np.linalg.matrix_power(M, n)).max()
        print(f"n={n} T={T}: K={K.tolist()}  |(Ad+BdK)^n|={nil:.1e}")
        # the paper's matrix exp(A0 T)(I + int_0^T exp(-A0 w) dw B0 K)
        A, B = chain(n)
        ws = np.linspace(0, T, 2001)
        integ = np.trapezoid([expm(-A * w) for w in ws], ws, axis=0)
        P = expm(A * T) @ (np.eye(n) + np.outer(integ @ B, K))
        print(f"   paper matrix vs Ad+BdK (trapezoid): {np.abs(P - M).max():.1e}")
    K2 = deadbeat_gain(2, 0.5)
    assert np.allclose(K2, [-1 / 0.25, -3 / 1.0], rtol=1e-13)
    for name, case in CASES.items():
        ref = np.array(trace(**case))
        rows, _ = direct(**case)
        d = np.array(rows)
        err = np.abs(d - ref).max(axis=0)
        print(f"{name}: direct solve_ivp vs exact: max |diff| per column {err.tolist()}")
        u325, us = formula_3_25(**case)
        print(f"{name}: (3.25) vs Phi-based u_i: {np.abs(np.array(u325) - us).max():.1e}")
        T, N = case["T"], case["N"]
        xn = np.abs(ref[:, 1:-1]).max(axis=1)
        k0 = next(k for k in range(len(xn)) if xn[k:].max() < 1e-9)
        print(f"{name}: |x| < 1e-9 from t = {float(ref[k0, 0])!r}, max |x| after: "
              f"{xn[k0:].max():.1e}; max |x| one period earlier: {xn[k0 - N]:.2e}")


if __name__ == "__main__":
    main(OUT, CASES, write, {"--check": check})
