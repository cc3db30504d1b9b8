"""The batch engine's LTI loops: ``run_lti`` (a ``delaycomp.system.LtiBatch``;
``simulate_lti`` takes loose arrays) advances ``x' = A x + B u``, exactly discretized
(per-point matrices, one matrix exponential per distinct ``(A, B, h)``), under the
zero-order-hold controller of Theorem 3.2 with the closed-form predictor of Corollary 3.4
(``compensated``) or ``u = K y`` (``uncompensated``), on any array library with numpy's
API (``delaycomp.studies.batch.backends``).

A group's plan (``LtiPlan``, ``lti_plan``: integer ticks, the discretization and the
predictors, checked) and the per-point coefficients (``coefficients``, ``dot``) are shared
with the channel engine (``delaycomp.studies.batch.channels``); the stepping of one tick or
one period is ``_LtiStepper``'s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from delaycomp.maths.grid import periods as zoh_periods
from delaycomp.maths.lti import MODES, LTIPredictor, discretize
from delaycomp.studies.batch.backends import Backend, get_backend
from delaycomp.studies.batch.base import (
    BatchError,
    BatchResult,
    checked_points,
    count_points,
    grid_ticks,
    merge,
    per_point,
    take,
    trim,
    unique_rows,
)
from delaycomp.studies.batch.metrics import BlockMetrics
from delaycomp.system import LtiBatch


def simulate_lti(A, B, K, T, N, r, tau, x0, u0, mode, stop: float, r_true=None,
                 tau_true=None, *, record: bool = False,
                 backend: Backend | str = "numpy") -> BatchResult:
    """Advance ``P`` LTI loops of Theorem 3.2 / Corollary 3.4 together to ``stop``.

    A convenience over ``run_lti`` for loose arrays: the ingredients are broadcast
    over the points (shared matrices and scalars to every point), checked (shapes, finite
    timing; ``BatchError``) and stacked into a ``delaycomp.system.LtiBatch``.

    Parameters
    ----------
    A, B, K : array_like
        ``(n, n)``, ``(n, m)``, ``(m, n)`` shared by every point, or with a leading axis of
        length ``P``. ``u = K x`` (the paper's sign).
    T, r, tau : float or array_like
        Sampling period, and the delays the controller assumes; ``tau`` a multiple of
        ``T``; ``r``, ``tau`` multiples of ``h = T / N``.
    N : int or array_like of int
        Base steps per period; points with different ``N`` run as separate groups.
    x0, u0 : array_like
        Constant histories of ``x`` on ``[-r, 0]`` and of ``u`` on ``[-r - tau, 0)``.
    mode : str or sequence of str
        ``compensated`` (``u = K Phi``) or ``uncompensated`` (``u = K y``), per point.
    stop : float
        Stop time, a multiple of every point's ``h``.
    r_true, tau_true : float or array_like, optional
        The loop's delays (default: the assumed ones), multiples of ``h``.
    record : bool
        Keep every tick's state and control (memory ``P x ticks``; for tests and plots).
    backend : Backend or str
        Array library (``get_backend``).

    Returns
    -------
    BatchResult

    Examples
    --------
    Shared ``A``, ``B``, ``T``, ``N``; a gain and a delay per point:

    >>> res = simulate_lti([[1.0]], [[1.0]], [[[-2.0]], [[-1.5]]], 1.0, 100, [0.0, 0.3],
    ...                    0.0, [1.0], [0.0], "compensated", 10.0)
    >>> res.stable.tolist()
    [1, 1]
    """
    be = backend if isinstance(backend, Backend) else get_backend(backend)
    A = np.asarray(A, dtype=float)
    P = count_points([A, B, K], [T, r, tau, N, r_true, tau_true], [x0, u0], mode)
    n = A.shape[-1]
    m = np.asarray(B, dtype=float).shape[-1]
    A = per_point(A, P, (n, n), "A")
    B = per_point(B, P, (n, m), "B")
    K = per_point(K, P, (m, n), "K")
    t = checked_points(P, n, m, T, r, tau, N, r_true, tau_true, x0, u0)
    modes = np.broadcast_to(np.asarray(mode, dtype=object), (P,)).copy()
    design = LtiBatch(A, B, K, t.T, t.N, t.r, t.tau, t.r_true, t.tau_true, t.x0, t.u0, modes)
    return run_lti(design, stop, record=record, backend=be)


def run_lti(design: LtiBatch, stop: float, *, record: bool = False,
            backend: Backend | str = "numpy") -> BatchResult:
    """Advance the ``P`` LTI loops of ``design`` together to ``stop`` (Theorem 3.2 with the
    closed-form predictor of Corollary 3.4, or ``u = K y``): the batch engine's core.

    ``design`` is a validated ``delaycomp.system.LtiBatch`` (from
    ``delaycomp.system.lti_designs``, a scenario's or a loop file's ``designs``, or
    ``simulate_lti``), one entry per point; points with different ``N`` run as
    separate groups (``take``), within a group ``T``, the delays and the matrices
    differ freely. ``stop`` is a multiple of every point's ``h = T / N``; ``record`` keeps
    every tick's state and control; ``backend`` is the array library
    (``get_backend``). Raises ``BatchError`` where a mode, a delay or ``stop``
    is not allowed at some point, or a predictor overflows.

    Examples
    --------
    >>> from delaycomp.system import lti_designs
    >>> pts = [dict(A=[[1.0]], B=[[1.0]], K=[[-k]], T=1.0, r=0.3, tau=0.0, N=100,
    ...             mode="compensated", x0=[1.0], u0=[0.0]) for k in (0.5, 2.0, 3.5)]
    >>> run_lti(lti_designs(pts), 20.0).stable.tolist()
    [0, 1, 0]
    """
    be = backend if isinstance(backend, Backend) else get_backend(backend)
    bad = [md for md in set(design.mode.tolist()) if md not in MODES]
    if bad:
        raise BatchError(f"mode = {bad[0]!r} is not allowed: must be one of {', '.join(MODES)}")
    parts = []
    for Nv in np.unique(design.N):
        idx = np.flatnonzero(design.N == Nv)
        parts.append((idx, _lti_group(be, take(design, idx), int(Nv), float(stop), record)))
    return merge(parts, len(design))


@dataclass(frozen=True)
class LtiPlan:
    """One LTI group on the host, checked: its integer ticks, the exact discretization
    and the predictor ``Phi = E y + sum_q QB[q] u_{i-q-1}`` (Corollary 3.4) per point."""

    N: int
    T: np.ndarray
    h: np.ndarray
    stop_k: np.ndarray  # the last tick, per point
    Dr: np.ndarray  # the true measurement delay, in ticks
    Dt: np.ndarray  # the true input delay, in ticks
    Ad: np.ndarray  # (P, n, n): e^(A h)
    Bd: np.ndarray  # (P, n, m)
    E: np.ndarray  # (P, n, n)
    QB: np.ndarray  # (Lmax, P, n, m)


def lti_plan(d: LtiBatch, N: int, stop: float) -> LtiPlan:
    """The plan of the group ``d`` (every point with ``N`` base steps a period), or a
    ``BatchError`` naming the first point off the grid."""
    P = len(d)
    T = d.T
    h = T / N
    stop_k = grid_ticks("stop", np.full(P, stop), h)
    grid_ticks("r", d.r, h)
    Dr = grid_ticks("r_true", d.r_true, h)
    Dt = grid_ticks("tau_true", d.tau_true, h)
    for p in unique_rows(d.tau, T)[0]:
        try:
            zoh_periods(float(d.tau[p]), float(T[p]), hints=True)
        except ValueError as exc:
            raise BatchError(f"{exc} (point {p})") from None
    # exact discretization, once per distinct (A, B, h)
    first, inv = unique_rows(d.A, d.B, h)
    Ad_u, Bd_u = zip(*(discretize(d.A[i], d.B[i], float(h[i])) for i in first))
    E, QB = _predictors(d, d.mode == "compensated")
    return LtiPlan(N, T, h, stop_k, Dr, Dt, np.stack(Ad_u)[inv], np.stack(Bd_u)[inv], E, QB)


def _predictors(d: LtiBatch, comp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``E`` (P, n, n) and ``QB`` (Lmax, P, n, m) of the points' predictors, once per
    distinct ``(A, B, T, r, tau)``; an uncompensated point has ``E = I``, ``QB = 0``,
    hence ``u = K y``. ``BatchError`` where a predictor is not finite."""
    A, B, T, r, tau = d.A, d.B, d.T, d.r, d.tau
    P, n, m = B.shape
    L = np.ones(P, dtype=np.int64)
    E = np.broadcast_to(np.eye(n), (P, n, n)).copy()
    cidx = np.flatnonzero(comp)
    preds = {}
    if cidx.size:
        f2, inv2 = unique_rows(A[cidx], B[cidx], T[cidx], r[cidx], tau[cidx])
        for j, i in enumerate(f2):
            p = cidx[i]
            preds[j] = LTIPredictor(A[p], B[p], float(T[p]), float(r[p]), float(tau[p]))
        for j, p in enumerate(cidx):
            pr = preds[inv2[j]]
            L[p] = pr.L
            E[p] = pr.E
    QB = np.zeros((int(L.max()), P, n, m))
    for j, p in enumerate(cidx):
        pr = preds[inv2[j]]
        for q in range(pr.L):
            QB[q, p] = pr.QB[q]
    if not (np.all(np.isfinite(E)) and np.all(np.isfinite(QB))):
        p = int(np.flatnonzero(~(np.isfinite(E).all(axis=(1, 2))
                                 & np.isfinite(QB).all(axis=(0, 2, 3))))[0])
        raise BatchError(f"A = {A[p].tolist()} (point {p}) is not allowed: must keep the "
                         f"predictor e^(A (r + tau)) finite for r + tau = "
                         f"{float(r[p] + tau[p])!r} (it overflows)")
    return E, QB


def _lti_group(be: Backend, d: LtiBatch, N: int, stop: float, record: bool) -> BatchResult:
    """The points of ``d`` (every one with ``N`` base steps a period) to ``stop``: the
    bookkeeping (plan, metrics a block at a time, the record's end) around the stepping
    of ``_LtiStepper``."""
    plan = lti_plan(d, N, stop)
    run = _LtiStepper(be, plan, d, record)
    acc = BlockMetrics(be, len(d), N, plan.stop_k, int((plan.stop_k // N).max()))
    with np.errstate(all="ignore"):  # overflow is detected per block, as the FMUs refuse
        run.start()
        for i in range(run.kmax // N + 1):
            bad = run.sample(i)
            if bool(run.xp.any(bad)):
                acc.cut(be.to_numpy(bad), i * N, "the control is not finite (the feedback "
                        "diverged: overflow)", plan.T, plan.h)
            run.hold(i)
            rows = run.advance(i)
            acc.block(run.xb[i % run.nb, :rows], i * N, plan.T, plan.h)
    res = acc.finish(plan.T, plan.h)
    res.states, res.inputs = trim(run.states, run.inputs,
                                   np.minimum(acc.cut_at, plan.stop_k + 1))
    return res


def coefficients(plan: LtiPlan, d: LtiBatch, col, Lmax: int) -> tuple:
    """A stepper's per-point coefficients, entry by entry, each ``col`` of its ``(P,)``
    column (contiguous, on the stepper's device): ``(Ad, Bd, K, E, QB, x0, u0)``, ``QB``
    the predictor's first ``Lmax`` blocks."""
    n, m = plan.Bd.shape[1:]
    return ([[col(plan.Ad[:, a, b]) for b in range(n)] for a in range(n)],
            [[col(plan.Bd[:, a, c]) for c in range(m)] for a in range(n)],
            [[col(d.K[:, c, a]) for a in range(n)] for c in range(m)],
            [[col(plan.E[:, a, b]) for b in range(n)] for a in range(n)],
            [[[col(plan.QB[q, :, a, c]) for c in range(m)] for a in range(n)]
             for q in range(Lmax)],
            col(d.x0.T), col(d.u0.T))


class _LtiStepper:
    """The stepping of one LTI group (the maths), on the backend's arrays, the points on
    the last axis: the controller at each sampling tick, the plant's exact step each tick.

    The states of the last ``nb`` periods are kept in blocks of ``N`` ticks,
    ``xb[b, row]`` (the measurement delay's ring); the controller outputs one per period,
    ``U`` (the predictor's window and the input delay's ring).
    """

    def __init__(self, be: Backend, plan: LtiPlan, d: LtiBatch, record: bool):
        xp, dev = be.xp, be.asarray
        P, n, m = d.B.shape
        N = plan.N
        self.be, self.xp, self.plan, self.N, self.n, self.m = be, xp, plan, N, n, m
        self.kmax = int(plan.stop_k.max())
        self.Lmax = plan.QB.shape[0]
        self.nb = int(plan.Dr.max()) // N + 2  # blocks of N ticks kept for the measurement
        self.Ru = max(self.Lmax, int(plan.Dt.max()) // N + 1) + 2
        self.is_np = be.name == "numpy"
        self.scalar = self.is_np and n == 1  # the hot path: two ufunc calls a tick

        def col(a):  # a per-point coefficient as a contiguous (P,) array
            return dev(np.ascontiguousarray(a))

        self.Ad, self.Bd, self.K, self.E, self.QB, self.x0, self.u0 = coefficients(
            plan, d, col, self.Lmax)
        self.pidx = dev(np.arange(P))
        self.Dr_uniform = bool(np.all(plan.Dr == plan.Dr[0]))
        self.Dt_uniform = bool(np.all(plan.Dt == plan.Dt[0]))
        self.Dr_d = dev(plan.Dr)
        self.xb = xp.zeros((self.nb, N, n, P))  # states of the last nb blocks of N ticks
        self.U = xp.zeros((self.Ru, m, P))  # controller outputs, one per period
        self.x = [self.x0[a] for a in range(n)]
        self.v = self.held = self.u0
        self.tmp = np.empty(P) if self.is_np else None
        self.states = np.full((P, self.kmax + 1, n), np.nan) if record else None
        self.inputs = np.full((P, self.kmax + 1, m), np.nan) if record else None
        # the plant input changes at the ticks k with (k - Dt) % N == 0: rows Dt % N
        self.change_rows = {int(c) for c in np.unique(plan.Dt % N)}
        self.Dt_rows = plan.Dt % N
        self.bv = self.forced(self.v)

    def start(self) -> None:
        """Tick 0's state into the ring."""
        for a in range(self.n):
            self.xb = self.be.put(self.xb, (0, 0, a), self.x[a])

    def forced(self, v) -> list:
        """``Bd v``, per state component."""
        return [dot(self.Bd[a], v) for a in range(self.n)]

    def sample(self, i: int):
        """The controller at the sampling tick ``i N``: ``held = K Phi(y)``, ``y`` the
        state ``Dr`` ticks before; returns where it is not finite from a finite ``y``."""
        xp, N, n, k0, bi = self.xp, self.N, self.n, i * self.N, i % self.nb
        if not self.is_np and i > 0:  # row 0 of this block: the last step's result
            self.xb = self.be.put(self.xb, (bi, 0), xp.stack(self.x))
        xb, U, u0 = self.xb, self.U, self.u0
        if self.Dr_uniform:
            src = k0 - int(self.plan.Dr[0])
            y = xb[(src // N) % self.nb, src % N] if src >= 0 else self.x0
        else:
            src = k0 - self.Dr_d
            y = xp.where(src >= 0, xb[(src // N) % self.nb, src % N, :, self.pidx].T,
                         self.x0)
        phi = [dot(self.E[a], y) for a in range(n)]
        for q in range(self.Lmax):
            past = U[(i - q - 1) % self.Ru] if i - q - 1 >= 0 else u0
            for a in range(n):
                phi[a] = phi[a] + dot(self.QB[q][a], past)
        self.held = xp.stack([dot(self.K[c], phi) for c in range(self.m)])
        return ~xp.all(xp.isfinite(self.held), axis=0) & xp.all(xp.isfinite(y), axis=0)

    def hold(self, i: int) -> None:
        """The controller output of period ``i`` into its ring."""
        self.U = self.be.put(self.U, i % self.Ru, self.held)

    def plant_input(self, k: int, row: int, v):
        """``v`` at tick ``k``: the controller output of tick ``k - Dt``."""
        if row not in self.change_rows:
            return v, False
        N, Dt, U, Ru = self.N, self.plan.Dt, self.U, self.Ru
        if self.Dt_uniform:
            s = k - int(Dt[0])
            return (U[(s // N) % Ru], True) if s >= 0 else (v, False)
        due = (self.Dt_rows == row) & (k - Dt >= 0)
        if not due.any():
            return v, False
        s = np.maximum(k - Dt, 0)
        dev = self.be.asarray
        return self.xp.where(dev(due), U[dev((s // N) % Ru), :, self.pidx].T, v), True

    def advance(self, i: int) -> int:
        """The plant through the ticks of period ``i`` (each recorded first, with
        ``record``), its states into block ``i % nb`` of the ring; returns their number."""
        xp, be, N, n, kmax = self.xp, self.be, self.N, self.n, self.kmax
        Ad, xb, tmp = self.Ad, self.xb, self.tmp
        k0, bi = i * N, i % self.nb
        rows = min(N, kmax - k0 + 1)
        x, v, bv = self.x, self.v, self.bv
        later = []  # other libraries: rows 1.. of this block, written once at its end
        for row in range(rows):
            k = k0 + row
            v, changed = self.plant_input(k, row, v)
            if changed:
                bv = self.forced(v)
            if self.states is not None and self.inputs is not None:
                self.states[:, k] = be.to_numpy(xp.stack(x)).T
                self.inputs[:, k] = be.to_numpy(self.held).T
            if k == kmax:
                break
            # the plant's step to tick k + 1, into its row of the block ring
            bi1, row1 = (bi, row + 1) if row + 1 < N else ((i + 1) % self.nb, 0)
            if self.scalar:  # n = 1 on numpy: the hot path, two ufunc calls a tick
                out = xb[bi1, row1, 0]
                np.multiply(Ad[0][0], x[0], out=out)
                np.add(out, bv[0], out=out)
                x = [out]
            elif self.is_np:
                assert tmp is not None  # the scratch row of numpy
                for a in range(n):
                    out = xb[bi1, row1, a]
                    np.multiply(Ad[a][0], x[0], out=out)
                    for b in range(1, n):
                        np.multiply(Ad[a][b], x[b], out=tmp)
                        np.add(out, tmp, out=out)
                    np.add(out, bv[a], out=out)
                x = [xb[bi1, row1, a] for a in range(n)]
            else:  # JAX arrays are immutable: one write a block, not one a tick
                x = [dot(Ad[a], x) + bv[a] for a in range(n)]
                if row1:
                    later.append(xp.stack(x))
        if later:
            self.xb = be.put(xb, (bi, slice(1, 1 + len(later))), xp.stack(later))
        self.x, self.v, self.bv = x, v, bv
        return rows


def dot(row, vec):
    """``sum_j row[j] * vec[j]`` over per-point arrays, left to right (no ``0 +``)."""
    acc = row[0] * vec[0]
    for j in range(1, len(row)):
        acc = acc + row[j] * vec[j]
    return acc

