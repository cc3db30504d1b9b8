"""Linear time-invariant plants: exact discretization and the lifted sampled-data loop.

All formulas here use the exact matrix exponential (scipy's Pade approximation with
scaling and squaring), never a numerical ODE solve.

Notation follows Karafyllis & Krstic: plant ``x' = A x + B u(t - tau)``, measurement
``y_i = x(iT - r)``, input held over ``[iT, (i+1)T)``, ``tau = l T``, ``q = [r/T]`` and
``r~ = r - q T``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.linalg import expm

# the base grid is decided in one place; re-exported for the FMUs' imports
from delaycomp.maths.grid import GRID_RTOL, MAX_STEPS, check_steps, periods  # noqa: F401
from delaycomp.maths.grid import split as split_delay
from delaycomp.names import MODES  # the modes, used here and re-exported where the maths lives

Mode = Literal["compensated", "uncompensated"]


def as_matrices(A, B) -> tuple[np.ndarray, np.ndarray]:
    """Return ``A`` (n x n) and ``B`` (n x m) as float arrays, checking their shapes."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.asarray(B, dtype=float)
    n = A.shape[0]
    if A.shape != (n, n):
        raise ValueError(f"A must be square, got shape {A.shape}")
    if B.ndim == 1:
        B = B.reshape(n, -1) if n > 1 else B.reshape(1, -1)
    if B.ndim != 2 or B.shape[0] != n:
        raise ValueError(f"B must have {n} rows, got shape {B.shape}")
    return A, B


def flow(A, B, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact flow of ``x' = A x + B u`` with constant ``u`` over a time ``s >= 0``.

    Returns ``(E, G)`` with ``E = exp(A s)`` and ``G = int_0^s exp(A w) dw B``, so that
    ``x(s) = E x(0) + G u``. Both come from one exponential of the augmented matrix
    ``[[A, B], [0, 0]] s`` (Van Loan), which is exact also for singular ``A``.
    """
    A, B = as_matrices(A, B)
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = B
    F = expm(M * s)
    return F[:n, :n].copy(), F[:n, n:].copy()


def discretize(A, B, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretization ``x_{k+1} = Ad x_k + Bd u_k`` for step ``h``."""
    return flow(A, B, h)



def sampled_radius(A, B, K, T: float) -> float:
    """Spectral radius of the delay-free sampled loop ``x_{i+1} = (Ad + Bd K) x_i`` (the
    plant under ``u = K x`` held over each period ``T``, no delay); NaN where that matrix
    is not finite (``e^(A T)`` overflowed: no radius to speak of).

    >>> sampled_radius([[1e308]], [[1.0]], [[-1.0]], 1.0)
    nan
    """
    with np.errstate(all="ignore"):  # an overflow is the answer NaN, not a warning
        Ad, Bd = discretize(A, B, T)
        K = np.atleast_2d(np.asarray(K, dtype=float))
        M = Ad + Bd @ K
    if not np.all(np.isfinite(M)):
        return math.nan
    return float(np.max(np.abs(np.linalg.eigvals(M))))


@dataclass(frozen=True)
class LiftedLoop:
    """The sampled-data loop as a discrete-time system ``X_{i+1} = M X_i``.

    ``X_i = (x(iT - r), u_{i-1}, ..., u_{i-L})`` with ``L = l + q + 1``: the sampled state
    and the controller outputs still in the delay window.
    """

    M: np.ndarray
    n: int
    m: int
    L: int

    @property
    def spectral_radius(self) -> float:
        """The largest modulus of the eigenvalues of ``M`` (< 1: the sampled loop is stable)."""
        return float(np.max(np.abs(np.linalg.eigvals(self.M))))


def lifted_loop(A, B, K, T: float, r: float, tau: float, mode: str,
                r_true: float | None = None, tau_true: float | None = None) -> LiftedLoop:
    """Lift the loop of Theorem 3.2 / Corollary 3.4 with ``u_i = K Phi`` or ``u_i = K y_i``.

    The controller assumes the delays ``r`` and ``tau = l T``; the loop's true delays are
    ``r_true`` and ``tau_true`` (default: the assumed ones; any values >= 0). Only their sum
    ``D = Q T + D~`` (``0 <= D~ < T``) shapes the plant's input: over
    ``[iT - r_true, (i+1)T - r_true)`` the plant sees ``u_{i-Q-1}`` for ``D~`` time units and
    then ``u_{i-Q}`` for ``T - D~``, hence, with ``x_i = x(iT - r_true) = y_i``,
    ``x_{i+1} = e^{AT} x_i + e^{A(T-D~)} G(D~) u_{i-Q-1} + G(T-D~) u_{i-Q}``.
    Without mismatch ``Q = l + q`` and ``D~ = r~``.
    """
    A, B = as_matrices(A, B)
    n, m = B.shape
    K = np.atleast_2d(np.asarray(K, dtype=float)).reshape(m, n)
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    r_true = r if r_true is None else r_true
    tau_true = tau if tau_true is None else tau_true
    if r_true < 0 or tau_true < 0:
        raise ValueError("true delays must be >= 0")
    l = periods(tau, T)  # noqa: E741 - the paper's name
    q, _ = split_delay(r, T)
    Q, Dt = split_delay(r_true + tau_true, T)
    L = max(l + q + 1, Q + 1)
    dim = n + m * L

    def past(j: int) -> np.ndarray:
        """Selector of u_{i-j} (j >= 1) from X_i."""
        S = np.zeros((m, dim))
        S[:, n + m * (j - 1): n + m * j] = np.eye(m)
        return S

    Sx = np.zeros((n, dim))
    Sx[:, :n] = np.eye(n)
    if mode == "uncompensated":
        F = K @ Sx
    else:
        pred = LTIPredictor(A, B, T, r, tau)
        F = K @ (pred.E @ Sx + sum(pred.QB[p - 1] @ past(p) for p in range(1, pred.L + 1)))

    def u_sel(j: int) -> np.ndarray:
        return F if j == 0 else past(j)

    ET, _ = flow(A, B, T)
    E_rest, G_rest = flow(A, B, T - Dt)
    _, G_Dt = flow(A, B, Dt)
    x_next = ET @ Sx + E_rest @ G_Dt @ u_sel(Q + 1) + G_rest @ u_sel(Q)
    rows = [x_next, F] + [past(j) for j in range(1, L)]
    return LiftedLoop(M=np.vstack(rows), n=n, m=m, L=L)


class LTIPredictor:
    """Closed-form predictor of Corollary 3.4, (3.15)-(3.16).

    ``Phi(y_i, u) = e^{A(r+tau)} y_i + sum_{p=1}^{l+q+1} Q_p B u_{i-p}`` with
    ``Q_p = e^{ApT} int_0^T e^{-As} ds`` for ``p <= l+q`` and
    ``Q_{l+q+1} = e^{A(l+q)T} int_0^{r~} e^{As} ds``. The matrices ``Q_p B`` are computed
    once. ``past[p-1]`` must hold ``u_{i-p}``.
    """

    def __init__(self, A, B, T: float, r: float, tau: float):
        A, B = as_matrices(A, B)
        self.n, self.m = B.shape
        check_steps("r + tau", r + tau, (r + tau) / T, f"sampling periods of T = {T!r}")
        self.l = periods(tau, T)
        self.q, self.r_tilde = split_delay(r, T)
        self.L = self.l + self.q + 1
        self.E = expm(A * (r + tau))
        ET, GT = flow(A, B, T)  # e^{AT}, int_0^T e^{As} ds B
        QB = []
        power = np.eye(self.n)  # e^{A (p-1) T}
        for _ in range(self.l + self.q):
            QB.append(power @ GT)  # = e^{ApT} int_0^T e^{-As} ds B
            power = power @ ET
        _, G_rt = flow(A, B, self.r_tilde)
        QB.append(power @ G_rt)
        self.QB = QB
        self._QB_stack = np.hstack(QB)  # n x (m L)

    def predict(self, y, past) -> np.ndarray:
        """Return ``Phi(y, past)``; ``past`` is a sequence of ``L`` inputs, newest first."""
        stacked = np.asarray(past, dtype=float).reshape(self.L * self.m)
        return self.E @ np.asarray(y, dtype=float).reshape(self.n) + self._QB_stack @ stacked


def predict_by_integration(A, B, y, segments) -> np.ndarray:
    """Predictor by exact integration of a piecewise-constant input history.

    ``segments`` is a sequence of ``(duration, u)`` covering the window
    ``[t - r - tau, t)`` oldest first; the plant, started at ``y = x(t - r)``, is driven
    over those segments (the input the plant sees at ``t - r + s`` is the controller output
    of ``t - r - tau + s``). This is the definition of Phi, computed independently of the
    closed form.
    """
    A, B = as_matrices(A, B)
    x = np.asarray(y, dtype=float).reshape(A.shape[0])
    for duration, u in segments:
        if duration < 0:
            raise ValueError(f"segment duration must be >= 0, got {duration}")
        if duration == 0:
            continue
        E, G = flow(A, B, duration)
        x = E @ x + G @ np.asarray(u, dtype=float).reshape(B.shape[1])
    return x


def critical_delay(
    rho_of_r: Callable[[float], float], r_max: float, step: float, xtol: float = 1e-12
) -> float:
    """Smallest ``r > 0`` at which ``rho_of_r`` reaches 1, scanning from 0 in ``step``.

    The loop is stable for every ``r`` in ``[0, r_c)``; ``r_c`` is found by a scan that
    brackets the first crossing and Brent's method inside the bracket. Raises
    ``ValueError`` if the loop is unstable at ``r = 0`` or stays stable up to ``r_max``.
    """
    # the one root search of the module: scipy.optimize (0.1 s to import) is loaded here,
    # not by the FMUs that import this module for its flows (an FMU instantiates faster)
    from scipy.optimize import brentq

    if rho_of_r(0.0) >= 1.0:
        raise ValueError("the loop is unstable without delay (r = 0)")
    lo = 0.0
    while lo < r_max:
        hi = min(lo + step, r_max)
        if rho_of_r(hi) >= 1.0:
            return brentq(lambda r: rho_of_r(r) - 1.0, lo, hi, xtol=xtol,
                          rtol=4 * np.finfo(float).eps)
        lo = hi
    raise ValueError(f"the loop stays stable for every r up to {r_max}")
