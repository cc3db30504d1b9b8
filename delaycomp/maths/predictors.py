"""Predictor maps Phi for nonlinear plants: numerical, and the paper's closed forms.

``Phi(x, segments)`` is the state reached from ``x`` when the plant is driven over the
input segments ``(duration, u)`` (oldest first) that cover the window ``[t - r - tau, t)``.

- ``integrate`` solves the ODE over the segments (DOP853, stated tolerances): the
  numerical Phi for any forward-complete ``f``, and the plant step when no exact step is
  known.
- ``bilinear_predictor``: Remark 2.2(d)(ii), ``x' = A x + B u + u C x`` with
  ``AC = CA``.
- ``chain_predictor``: Corollary 3.7, a system diffeomorphic to a chain of
  integrators by ``z = Theta(x)``: ``Phi = Theta^{-1}(flow of the chain from Theta(x))``.
The closed forms of Example 2.4 and of the unicycle live with their models in
``delaycomp.paper.models``.

scipy is imported by the predictor that uses it, when it is first used: ``scipy.integrate``
by the ODE solves, ``scipy.linalg`` (through ``delaycomp.maths.lti``) by the two matrix closed
forms. A model FMU whose model has its own exact step and Phi (Example 2.4) so loads
numpy only: 0.1 s to instantiate instead of 0.38 s (``bench/run.py``, section 7).
"""

from __future__ import annotations

import functools
import math
import threading
import warnings
from collections.abc import Callable, Sequence
from fractions import Fraction
from typing import cast

import numpy as np

from delaycomp.errors import DelaycompError

#: Default tolerance of numerical solves (relative and absolute).
DEFAULT_TOL = 1e-10

Segments = Sequence[tuple[float, np.ndarray]]


class IntegrationError(DelaycompError, RuntimeError):
    """An ODE solve failed; the message says where."""


def integrate(f: Callable, p: dict, x, segments: Segments, rtol: float = DEFAULT_TOL,
              atol: float = DEFAULT_TOL) -> np.ndarray:
    """Solve ``x' = f(x, u, p)`` over piecewise-constant input segments.

    One solve per segment, so the integrator never steps over an input discontinuity.
    The solver is Hairer's DOP853 (explicit Runge-Kutta 8(5,3) with step control), through
    scipy's compiled binding, restarted at each segment: per segment it costs a few
    microseconds plus the evaluations of ``f``, where ``solve_ivp``'s Python stepping cost
    five to eight times more (measured). One solver object per thread and tolerance pair
    is reused for every call (see ``_solver``): a solver per call is never freed by
    scipy and grew memory by about 1.5 KiB per call. Where the compiled DOP853 gives up
    with "step size becomes too small" on a state whose scaled error underflows (a state
    near 1e-150 with these tolerances; the band 2e-155 .. 3e-148 measured), or spends its
    step budget on a state below 1e-100 (seen at 1e-156 in a long run), the segment is
    solved again by the same method in scipy's Python implementation
    (``solve_ivp(method="DOP853")``, same tolerances). A segment whose state and input
    are all below 1e-100 is solved for ``z / 2^k`` instead (``_scaled_segment``),
    where neither implementation's error norm underflows. Raises
    ``IntegrationError`` if a solve fails or the state stops being finite; the
    message names the model's own exception when ``f`` raised.

    Parameters
    ----------
    f : callable
        Right-hand side ``f(x, u, p) -> dx/dt``.
    p : dict
        Parameters handed to ``f``.
    x : array_like
        Initial state.
    segments : sequence of (float, array_like)
        ``(duration, u)`` pairs, oldest first; non-positive durations are skipped.
    rtol, atol : float
        Relative and absolute tolerances of each solve.

    Returns
    -------
    numpy.ndarray
        The state at the end of the last segment.
    """
    z = np.array(x, dtype=float)
    slot = _solver(rtol, atol)
    if slot.busy:
        # f itself integrates: the compiled DOP853 is not re-entrant (measured: a nested
        # call fails with "larger nsteps is needed"), so the inner solve is Python's
        return _nested(f, p, z, segments, rtol, atol)
    slot.busy = True
    try:
        slot.f, slot.p = f, p
        elapsed = 0.0
        for duration, u in segments:
            if duration <= 0:
                continue
            u = np.asarray(u, dtype=float)
            z = _segment(slot, z, duration, u, elapsed)
            elapsed += duration
    finally:
        slot.f = slot.p = None  # hold no user objects between calls
        slot.busy = False
    return np.array(z, dtype=float)


def _nested(f, p, z, segments, rtol, atol) -> np.ndarray:
    """``integrate`` by scipy's Python DOP853 only (a solve inside a solve)."""
    slot = _Slot.__new__(_Slot)
    slot.f, slot.p, slot.rtol, slot.atol = f, p, rtol, atol
    elapsed = 0.0
    for duration, u in segments:
        if duration <= 0:
            continue
        u = np.asarray(u, dtype=float)
        ok, reason, z_end = _python_dop853(slot, z, duration, u)
        z = _checked(ok, reason, z_end, elapsed, u)
        elapsed += duration
    return np.array(z, dtype=float)


def _segment(slot: _Slot, z: np.ndarray, duration: float, u: np.ndarray,
             elapsed: float, rescale: bool = True) -> np.ndarray:
    size = max(np.max(np.abs(z), initial=0.0), np.max(np.abs(u), initial=0.0))
    if rescale and 0.0 < size < _TINY:
        return _scaled_segment(slot, z, duration, u, elapsed, size)
    solver = slot.solver
    code = None
    slot.raised = None
    try:
        with warnings.catch_warnings():
            # scipy warns about a failed solve; the return code below says it too
            warnings.simplefilter("ignore", UserWarning)
            solver.set_initial_value(z, 0.0).set_f_params(u)
            z_end = solver.integrate(duration)
        code = solver.get_return_code()
        ok = solver.successful()
        reason = _DOP853_MESSAGES.get(code, "unknown failure")
    except BaseException as exc:  # noqa: BLE001 - f raised, or a solver warning as error
        ok, reason, z_end = False, f"{type(exc).__name__}: {exc}", z
    if slot.raised is not None:
        # f raised (scipy then reports its own error, "Function to integrate must not
        # return a tuple", or none): the caller hears f's exception
        ok, reason, z_end = False, (f"the model's f raised {type(slot.raised).__name__}: "
                                    f"{slot.raised}"), z
    elif not ok and (code == -3 or (code == -2 and np.max(np.abs(z), initial=0.0) < _TINY)):
        # step size too small, or the step budget spent on a tiny state: the scaled error
        # underflowed (a failure of a solve that can progress is retried in vain, fast)
        ok, reason, z_end = _python_dop853(slot, z, duration, u)
    return _checked(ok, reason, z_end, elapsed, u)


def _checked(ok: bool, reason: str, z_end: np.ndarray, elapsed: float,
             u: np.ndarray) -> np.ndarray:
    """``z_end`` of a solve that succeeded with a finite state; else IntegrationError."""
    if ok and not np.isfinite(z_end).all():
        ok, reason = False, "the state is not finite"
    if not ok:
        raise IntegrationError(f"ODE solve failed {elapsed:.6g} s into a window "
                               f"(input {u.tolist()}): {reason}")
    return z_end


def _scaled_segment(slot: _Slot, z, duration, u, elapsed, size) -> np.ndarray:
    """A segment whose state and input are all below ``_TINY``, solved for ``y = z /
    s`` with ``s`` the power of two nearest ``size``: ``y' = f(s y, u) / s`` is the same
    ODE (multiplying and dividing by a power of two is exact above the subnormals), and
    its tolerances, applied to ``y``, are tighter than the caller's on ``z``. Both DOP853
    implementations square the scaled error of a step; for a state near 1e-150 with
    tolerances near 1e-10 those squares underflow to 0 and the step control breaks down
    ("step size becomes too small", "larger nsteps is needed", a 0/0 error norm)."""
    s = 2.0 ** round(math.log2(size))
    f = slot.f
    assert f is not None  # integrate set it for this solve

    def scaled(y, u_, p_):
        return np.asarray(f(y * s, u_, p_), dtype=float) / s
    slot.f = scaled
    try:
        y_end = _segment(slot, z / s, duration, u, elapsed, rescale=False)
    finally:
        slot.f = f
    return y_end * s


def _python_dop853(slot: _Slot, z, duration, u):
    """The same segment by scipy's Python DOP853 (same tolerances)."""
    from scipy.integrate import solve_ivp  # loaded by the slot already: a dict lookup

    f, p = cast(Callable, slot.f), slot.p  # set by the caller for this solve
    try:
        # its error norm may divide 0 by 0 on such states (a warning, then a smaller step)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            sol = solve_ivp(lambda _t, s: f(s, u, p), (0.0, duration), z, method="DOP853",
                            rtol=slot.rtol, atol=slot.atol)
    except BaseException as exc:  # noqa: BLE001 - f raised
        return False, f"the model's f raised {type(exc).__name__}: {exc}", z
    if not sol.success:
        return False, sol.message, z
    return True, "", sol.y[:, -1]


class _Slot:
    """A reusable DOP853 solver whose right-hand side reads ``f`` and ``p`` from here."""

    def __init__(self, rtol: float, atol: float):
        from scipy.integrate import ode  # the first numerical solve (module docstring)

        self.rtol, self.atol = rtol, atol
        self.f: Callable | None = None
        self.p: dict | None = None
        self.busy = False
        #: the exception the model's f raised in the current solve, if any
        self.raised: BaseException | None = None
        slot = self  # the closure holds the slot, not a bound method per call

        def rhs(_t, s, u):
            if slot.raised is not None:
                # the solve is lost, but the compiled DOP853 cannot be stopped from here:
                # it goes on calling until its step budget is spent (1.2e6 calls of f,
                # seconds, measured). NaN ends it within a few thousand cheap calls
                # ("step size becomes too small"); the caller reports f's exception.
                return np.full(len(s), np.nan)
            assert slot.f is not None  # the solver calls rhs only within integrate's solve
            try:
                return slot.f(s, u, slot.p)
            except BaseException as exc:
                slot.raised = exc
                raise

        self.solver = ode(rhs).set_integrator("dop853", rtol=rtol, atol=atol,
                                              nsteps=MAX_ODE_STEPS)
        # scipy (1.17 measured) hands ``self._solout``, a new bound method at every
        # set_initial_value, to its compiled DOP853, which keeps a reference to it: about
        # 64 bytes that are never freed per segment. One plain function instead.
        integrator = getattr(self.solver, "_integrator", None)
        if integrator is not None and hasattr(integrator, "_solout"):
            integrator._solout = _no_output


def _no_output(_x, _y):
    return 1  # continue (DOP853's dense output is off: iout = 0)


_SOLVERS = threading.local()

#: below this size a state's scaled error (squares of state / tolerance) can underflow
_TINY = 1e-100
#: DOP853's step budget per segment: a segment is at most a few sampling periods, so this
#: bound is reached only by a solve that cannot progress (stiff or blowing up).
MAX_ODE_STEPS = 100_000
_DOP853_MESSAGES = {1: "computation successful", 2: "computation successful",
                    -1: "input is not consistent", -2: "larger nsteps is needed",
                    -3: "step size becomes too small",
                    -4: "problem is probably stiff (interrupted)"}


def _solver(rtol: float, atol: float) -> _Slot:
    """This thread's reusable solver for the tolerances ``(rtol, atol)``."""
    cache = getattr(_SOLVERS, "by_tol", None)
    if cache is None:
        cache = _SOLVERS.by_tol = {}
    slot = cache.get((rtol, atol))
    if slot is None:
        slot = cache[(rtol, atol)] = _Slot(rtol, atol)
    return slot


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
    from scipy.linalg import expm  # a matrix closed form (module docstring)

    from delaycomp.maths.lti import flow

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
    from delaycomp.maths.lti import (
        predict_by_integration,  # a matrix closed form (module docstring)
    )

    A0 = np.eye(n, k=1)
    B0 = np.zeros((n, 1))
    B0[-1, 0] = 1.0

    def phi(x, segments, p):
        z = predict_by_integration(A0, B0, theta(np.asarray(x, dtype=float), p), segments)
        return theta_inv(z, p)
    return phi


def deadbeat_gain(n: int, T: float) -> np.ndarray:
    """Row ``K`` with ``e^{A0 T} + G(T) B0 K`` nilpotent (chain of ``n`` integrators).

    Ackermann's formula for the exact discretization with every pole at zero,
    ``K = -e_n' [Bd, Ad Bd, ..., Ad^{n-1} Bd]^{-1} Ad^n``, evaluated in exact rational
    arithmetic: for ``T = 1`` the entries of ``Ad = e^{A0}`` and ``Bd`` are ``1/k!``, and the
    time scaling ``xi_j(s) = T^{j-1} x_j(T s)`` turns the chain with period ``T`` into the one
    with period 1, so ``K_j(T) = K_j(1) / T^{n-j+1}`` (``T`` is taken as the exact rational
    its float is). Each entry is the float nearest the exact gain: the same on every
    machine, whatever its BLAS or libm.

    Parameters
    ----------
    n : int
        Number of integrators, ``n >= 1``.
    T : float
        Sampling period, ``T > 0``.

    Returns
    -------
    numpy.ndarray
        The gain, shape ``(1, n)``, for ``u = K x``.

    Examples
    --------
    >>> deadbeat_gain(3, 1.0).tolist()
    [[-1.0, -2.0, -1.8333333333333333]]
    >>> deadbeat_gain(2, 0.5).tolist()       # -(1/T^2, 3/(2T))
    [[-4.0, -3.0]]
    """
    t = Fraction(T)
    return np.array([[float(k / t ** (n - j)) for j, k in enumerate(_unit_deadbeat_gain(n))]])


@functools.cache
def _unit_deadbeat_gain(n: int) -> tuple[Fraction, ...]:
    """The dead-beat gain of ``deadbeat_gain`` for ``T = 1``, as exact rationals."""
    Ad = [[Fraction(1, math.factorial(j - i)) if j >= i else Fraction(0) for j in range(n)]
          for i in range(n)]
    Bd = [Fraction(1, math.factorial(n - i)) for i in range(n)]

    def mat_vec(M, v):
        return [sum((a * b for a, b in zip(row, v)), Fraction(0)) for row in M]

    # the controllability matrix's columns Ad^j Bd, j = 0..n-1
    cols, v = [], Bd
    for _ in range(n):
        cols.append(v)
        v = mat_vec(Ad, v)
    # e_n' C^{-1} = w' with C' w = e_n: solve by Gaussian elimination (C is invertible:
    # the chain is controllable)
    aug = [[cols[i][j] for j in range(n)] + [Fraction(int(i == n - 1))] for i in range(n)]
    for c in range(n):
        piv = next(r for r in range(c, n) if aug[r][c] != 0)
        aug[c], aug[piv] = aug[piv], aug[c]
        for r in range(n):
            if r != c and aug[r][c] != 0:
                f = aug[r][c] / aug[c][c]
                aug[r] = [x - f * y for x, y in zip(aug[r], aug[c])]
    w = [aug[i][n] / aug[i][i] for i in range(n)]
    # K(1) = -w' Ad^n; Ad^n = e^{n A0} has entries n^(j-i) / (j-i)!
    adn = [[Fraction(n ** (j - i), math.factorial(j - i)) if j >= i else Fraction(0)
            for j in range(n)] for i in range(n)]
    return tuple(-sum((w[i] * adn[i][j] for i in range(n)), Fraction(0)) for j in range(n))
