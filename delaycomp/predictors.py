"""Predictor maps Phi for nonlinear plants: numerical, and the paper's closed forms.

``Phi(x, segments)`` is the state reached from ``x`` when the plant is driven over the
input segments ``(duration, u)`` (oldest first) that cover the window ``[t - r - tau, t)``.

- :func:`integrate` solves the ODE over the segments (DOP853, stated tolerances): the
  numerical Phi for any forward-complete ``f``, and the plant step when no exact step is
  known.
- :func:`bilinear_predictor`: Remark 2.2(d)(ii), ``x' = A x + B u + u C x`` with
  ``AC = CA``.
- :func:`chain_predictor`: Corollary 3.7, a system diffeomorphic to a chain of
  integrators by ``z = Theta(x)``: ``Phi = Theta^{-1}(flow of the chain from Theta(x))``.
The closed forms of Example 2.4 and of the unicycle live with their models in
:mod:`delaycomp.models`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.integrate import ode
from scipy.linalg import expm

from .lti import flow, predict_by_integration

#: Default tolerance of numerical solves (relative and absolute).
DEFAULT_TOL = 1e-10

Segments = Sequence[tuple[float, np.ndarray]]


class IntegrationError(RuntimeError):
    """An ODE solve failed; the message says where."""


def integrate(f: Callable, p: dict, x, segments: Segments, rtol: float = DEFAULT_TOL,
              atol: float = DEFAULT_TOL) -> np.ndarray:
    """Solve ``x' = f(x, u, p)`` over piecewise-constant input segments.

    One solve per segment, so the integrator never steps over an input discontinuity.
    The solver is Hairer's DOP853 (explicit Runge-Kutta 8(5,3) with step control), through
    scipy's Fortran binding, restarted at each segment: per segment it costs a few
    microseconds plus the evaluations of ``f``, where ``solve_ivp``'s Python stepping cost
    five to eight times more (measured). Raises :class:`IntegrationError` if a solve fails
    or the state stops being finite.
    """
    z = np.array(x, dtype=float)
    solver = ode(lambda _t, s, u: f(s, u, p)).set_integrator(
        "dop853", rtol=rtol, atol=atol, nsteps=_MAX_STEPS)
    elapsed = 0.0
    for duration, u in segments:
        if duration <= 0:
            continue
        u = np.asarray(u, dtype=float)
        try:
            solver.set_initial_value(z, 0.0).set_f_params(u)
            z = solver.integrate(duration)
            ok = solver.successful()
            reason = _DOP853_MESSAGES.get(solver.get_return_code(), "unknown failure")
        except Exception as exc:  # noqa: BLE001 - f raised, or a solver warning as error
            ok, reason = False, f"{type(exc).__name__}: {exc}"
        if ok and not np.isfinite(z).all():
            ok, reason = False, "the state is not finite"
        if not ok:
            raise IntegrationError(f"ODE solve failed {elapsed:.6g} s into a window "
                                   f"(input {u.tolist()}): {reason}")
        elapsed += duration
    return np.array(z, dtype=float)


#: DOP853's step budget per segment: a segment is at most a few sampling periods, so this
#: bound is reached only by a solve that cannot progress (stiff or blowing up).
_MAX_STEPS = 100_000
_DOP853_MESSAGES = {1: "computation successful", 2: "computation successful",
                    -1: "input is not consistent", -2: "larger nsteps is needed",
                    -3: "step size becomes too small",
                    -4: "problem is probably stiff (interrupted)"}


def numerical_predictor(f: Callable, rtol: float = DEFAULT_TOL,
                        atol: float = DEFAULT_TOL) -> Callable:
    """Phi by ODE solve, with the stated tolerances."""
    def phi(x, segments, p):
        return integrate(f, p, x, segments, rtol, atol)
    return phi


def bilinear_predictor(A, B, C) -> Callable:
    """Remark 2.2(d)(ii): ``x' = A x + B u + u C x`` with scalar ``u`` and ``AC = CA``.

    ``Phi = e^{A D} e^{C S} x + int e^{-Aw} e^{C int_w^0 u} B u(w) dw`` with ``D = r + tau``
    and ``S = int u``. For piecewise-constant ``u`` each segment's integral is an exact
    exponential, because ``A`` and ``C`` commute.
    """
    A, B, C = (np.atleast_2d(np.asarray(M, dtype=float)) for M in (A, B, C))
    n = A.shape[0]
    B = B.reshape(n, 1)
    if not np.allclose(A @ C, C @ A, atol=1e-12 * (1 + np.abs(A).max() * np.abs(C).max())):
        raise ValueError("bilinear closed form needs AC = CA")

    def phi(x, segments, p):
        del p
        D = sum(d for d, _ in segments)
        S = sum(d * float(np.ravel(u)[0]) for d, u in segments)
        out = expm(A * D) @ expm(C * S) @ np.asarray(x, dtype=float).reshape(n)
        # window [-D, 0); segment j spans [w_a, w_b) with constant u_j;
        # int_w^0 u = S_after + u_j (w_b - w), S_after = int_{w_b}^0 u
        w_a, S_after_total = -D, S
        for d, u in segments:
            uj = float(np.ravel(u)[0])
            w_b = w_a + d
            S_after = S_after_total - uj * d
            # int_{w_a}^{w_b} e^{-Aw} e^{C (S_after + uj (w_b - w))} dw B uj
            #   = e^{C (S_after + uj w_b)} int e^{-(A + uj C) w} dw B uj
            M = -(A + uj * C)
            _, G = flow(M, B, d)  # int_0^d e^{M s} ds B
            integral = expm(M * w_a) @ G
            out = out + expm(C * (S_after + uj * w_b)) @ integral.ravel() * uj
            w_a, S_after_total = w_b, S_after
        return out
    return phi


def chain_predictor(theta: Callable, theta_inv: Callable, n: int) -> Callable:
    """Corollary 3.7: Phi for ``x' = f(x, u)`` with ``DTheta f = A0 Theta + B0 u``.

    In ``z = Theta(x)`` the plant is a chain of ``n`` integrators, whose flow over
    piecewise-constant segments is exact; ``Phi = Theta^{-1}(z(tau))``.
    """
    A0 = np.eye(n, k=1)
    B0 = np.zeros((n, 1))
    B0[-1, 0] = 1.0

    def phi(x, segments, p):
        z = predict_by_integration(A0, B0, theta(np.asarray(x, dtype=float), p), segments)
        return theta_inv(z, p)
    return phi


def deadbeat_gain(n: int, T: float) -> np.ndarray:
    """Row ``K`` with ``e^{A0 T} + G(T) B0 K`` nilpotent (chain of ``n`` integrators).

    Ackermann's formula for the exact discretization with every pole at zero:
    ``K = -e_n' [Bd, Ad Bd, ..., Ad^{n-1} Bd]^{-1} Ad^n``.
    """
    A0 = np.eye(n, k=1)
    B0 = np.zeros((n, 1))
    B0[-1, 0] = 1.0
    Ad, Bd = flow(A0, B0, T)
    ctrb = np.hstack([np.linalg.matrix_power(Ad, j) @ Bd for j in range(n)])
    e_n = np.zeros((1, n))
    e_n[0, -1] = 1.0
    return -e_n @ np.linalg.solve(ctrb, np.linalg.matrix_power(Ad, n))
