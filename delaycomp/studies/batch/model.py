"""The batch engine's model loops: ``run_model`` (a model, its parameters and a
``ModelBatch``; ``simulate_model`` takes loose arrays) advances the loops of a model
(``delaycomp.maths.model``) that declares ``BATCH = True`` and has an exact ``step``: its
``f``, ``k`` and ``step`` accept a batch (states of shape ``(n, P)``). Zero-order hold
(Theorem 3.2, with Remark 3.3(b) padding) and continuous input (Theorem 2.1, the
controller's copy ``z`` integrated on the base grid and reset to ``Phi`` at every sample
after the first). ``Phi`` is the composition of exact steps over the stored window (the
per-point engine's closed forms compose the same exact flows). numpy only.

The bookkeeping of a group (its plan, the metrics streamed tick by tick, the failures, the
record) is ``_model_group``'s; the stepping of one tick is ``_ModelStepper``'s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from delaycomp.maths.grid import periods as zoh_periods
from delaycomp.maths.nlcontrol import padded_delay
from delaycomp.studies.batch.backends import Backend, get_backend
from delaycomp.studies.batch.base import (
    BatchError,
    BatchResult,
    ModelBatch,
    checked_points,
    count_points,
    grid_ticks,
    merge,
    take,
    trim,
)
from delaycomp.studies.batch.metrics import rates
from delaycomp.studies.metrics import ZERO


def batchable(model) -> str | None:
    """Why ``model`` cannot run batched (``None`` if it can)."""
    if not getattr(model, "batch", False):
        return f"model {model.name} does not declare BATCH = True"
    if model.step is None:
        return f"model {model.name} has no exact step (the batch engine has no ODE solver)"
    return None


def simulate_model(model, params: dict, T, N, r, tau, x0, u0, stop: float, r_true=None,
                   tau_true=None, *, pad: bool = False, record: bool = False) -> BatchResult:
    """Advance ``P`` loops of a batchable model (``batchable``) together to ``stop``.

    A convenience over ``run_model`` for loose arrays: the per-point timing and
    histories are broadcast over the points, checked (``BatchError``) and gathered
    into one ``ModelBatch``.

    Parameters
    ----------
    model : delaycomp.maths.model.Model
        With ``BATCH = True`` and an exact ``step``.
    params : dict
        The model's parameters, shared by every point (numbers may be arrays of length P).
    T, N, r, tau, x0, u0, stop, r_true, tau_true :
        As in ``simulate_lti``; ``x0`` is also the controller's initial ``z``
        (continuous input).
    pad : bool
        Zero-order hold: pad ``tau`` up to the next multiple of ``T`` (Remark 3.3(b)).
    record : bool
        Keep every tick's state and control.

    Returns
    -------
    BatchResult
    """
    why = batchable(model)
    if why:
        raise BatchError(why)
    P = count_points([], [T, r, tau, N, r_true, tau_true], [x0, u0])
    points = checked_points(P, model.n, model.m, T, r, tau, N, r_true, tau_true, x0, u0)
    return run_model(model, params, points, stop, pad=pad, record=record)


def run_model(model, params: dict, points: ModelBatch, stop: float, *, pad: bool = False,
              record: bool = False) -> BatchResult:
    """Advance the ``P`` loops of a batchable ``model`` (``batchable``) at ``points``
    together to ``stop``: the batch engine's core for model loops.

    ``params`` are the model's parameters, shared by every point (a number may be an array
    of length ``P``, one per point); ``points`` the checked per-point timing and histories
    (``ModelBatch``); points with different ``N`` run as separate groups. ``pad``:
    under zero-order hold, pad ``tau`` up to the next multiple of ``T`` (Remark 3.3(b));
    ``record`` keeps every tick's state and control. Raises ``BatchError`` where the
    model is not batchable or a delay or ``stop`` is not allowed at some point.
    """
    why = batchable(model)
    if why:
        raise BatchError(why)
    P = len(points)
    parts = []
    for Nv in np.unique(points.N):
        idx = np.flatnonzero(points.N == Nv)
        p_idx = {key: (np.asarray(val)[idx] if np.ndim(val) == 1 and np.size(val) == P
                       else val) for key, val in params.items()}
        res = _model_group(model, p_idx, take(points, idx), int(Nv), float(stop), pad,
                           record)
        parts.append((idx, res))
    return merge(parts, P)


@dataclass(frozen=True)
class _ModelPlan:
    """One model group's integer ticks (host numpy), checked."""

    N: int
    T: np.ndarray
    h: np.ndarray
    stop_k: np.ndarray  # the last tick, per point
    Dr_true: np.ndarray  # the true measurement delay, in ticks
    Dpad: np.ndarray  # zero-order hold: the padding of tau (Remark 3.3(b)), in ticks
    Dt: np.ndarray  # the controller's held value -> the plant's input, in ticks
    W: np.ndarray  # the predictor's window r + tau (padded), in ticks
    Ru: int  # slots of the ring of controller outputs


def _model_plan(model, pts: ModelBatch, N: int, stop: float, pad: bool) -> _ModelPlan:
    """The plan of the group ``pts`` (every point with ``N`` base steps a period), or a
    ``BatchError`` naming what is off the grid."""
    T, tau = pts.T, pts.tau
    P = len(T)
    h = T / N
    stop_k = grid_ticks("stop", np.full(P, stop), h)
    Dr_true = grid_ticks("r_true", pts.r_true, h)
    Dt_true = grid_ticks("tau_true", pts.tau_true, h)
    Dr = grid_ticks("r", pts.r, h)
    if model.control == "zoh":
        tau_eff = np.array([padded_delay(tau[i], T[i]) for i in range(P)])
        if not pad and np.any(tau_eff != tau):
            i = int(np.flatnonzero(tau_eff != tau)[0])
            try:
                zoh_periods(float(tau[i]), float(T[i]), padding=True, hints=True)
            except ValueError as exc:
                raise BatchError(str(exc)) from None
        Dpad = grid_ticks("padding", tau_eff - tau, h)
        W = Dr + np.rint(tau_eff / h).astype(np.int64)
        Dt = Dt_true + Dpad
        nseg = W // N + (W % N > 0)
        Ru = max(int(nseg.max()), int(Dt.max()) // N + 1) + 2
    else:
        Dpad = np.zeros(P, dtype=np.int64)
        W = Dr + grid_ticks("tau", tau, h)
        Dt = Dt_true + Dpad
        Ru = max(int(W.max()), int(Dt.max())) + 2
    return _ModelPlan(N, T, h, stop_k, Dr_true, Dpad, Dt, W, Ru)


class _Failures:
    """Which points of a group failed, when and why, with their last recorded norm and
    peak (the per-point engine's record ends there)."""

    def __init__(self, P: int, N: int, T: np.ndarray, h: np.ndarray):
        self.N, self.T, self.h = N, T, h
        self.failed = np.zeros(P, dtype=bool)
        self.norm = np.zeros(P)
        self.peak = np.zeros(P)
        self.messages = [""] * P

    def mark(self, mask: np.ndarray, norms: np.ndarray, peak: np.ndarray, why: str,
             k: int) -> bool:
        """Mark the points ``mask`` failed at tick ``k`` (those not failed before keep
        ``norms`` and ``peak``); whether any is new."""
        new = mask & ~self.failed
        if not new.any():
            return False
        self.norm[new] = norms[new]
        self.peak[new] = peak[new]
        t = (k // self.N) * self.T + (k % self.N) * self.h
        for i in np.flatnonzero(new):
            self.messages[i] = f"{why} at t = {float(t[i])!r}"
        self.failed[new] = True
        return True


class _Metrics:
    """The sweep's metrics streamed tick by tick (host numpy or the backend's arrays)."""

    def __init__(self, xp, P: int, N: int, ticks: np.ndarray, periods_max: int):
        self.xp, self.P, self.N = xp, P, N
        self.ticks = ticks  # numpy, per point
        self.uniform = bool(np.all(ticks == ticks[0]))
        self.ticks_dev = xp.asarray(ticks)
        self.peak = xp.zeros(P)
        self.final = xp.zeros(P)
        self.last_above = xp.full(P, -1, dtype=xp.int64)
        self.envsq = xp.zeros((max(periods_max, 1), P))
        self.periods_max = periods_max

    def record(self, k: int, norm, put) -> None:
        xp = self.xp
        if not self.uniform:
            norm = xp.where(k <= self.ticks_dev, norm, 0.0)
            self.final = xp.where(k == self.ticks_dev, norm, self.final)
        elif k == int(self.ticks[0]):
            self.final = norm
        self.peak = xp.maximum(self.peak, norm)
        self.last_above = xp.where(norm < ZERO, self.last_above, k)
        j = k // self.N
        if j < self.periods_max:
            self.envsq = put(self.envsq, j, self.envsq[j] + norm * norm)


def _finish(metrics: _Metrics, backend: Backend, failed: np.ndarray, fail_norm: np.ndarray,
            fail_peak: np.ndarray, T: np.ndarray, h: np.ndarray, N: int,
            messages: list[str]) -> BatchResult:
    """Metrics per point from the streamed sums (on the host)."""
    to = backend.to_numpy
    peak, final = to(metrics.peak).copy(), to(metrics.final).copy()
    last = to(metrics.last_above)
    envsq = to(metrics.envsq)
    ticks = metrics.ticks
    peak[failed] = fail_peak[failed]
    final[failed] = fail_norm[failed]
    # deadbeat: the time of the tick after the last one with |x| >= ZERO
    nxt = last + 1
    db = (nxt // N) * T + (nxt % N) * h
    db = np.where(last < 0, 0.0, np.where(last < ticks, db, np.nan))
    rho = rates(envsq, ticks // N)
    bad = failed | ~np.isfinite(peak)
    rho[bad] = np.inf
    db[bad] = np.nan
    stable = (rho < 1.0).astype(np.int64)
    return BatchResult(rho, stable, final, peak, db, ~bad, messages)


def _model_group(model, params: dict, pts: ModelBatch, N: int, stop: float, pad: bool,
                 record: bool) -> BatchResult:
    """The points of ``pts`` (every one with ``N`` base steps a period) to ``stop``: the
    bookkeeping (plan, metrics, failures, the record) around the stepping of
    ``_ModelStepper``."""
    plan = _model_plan(model, pts, N, stop, pad)
    P, n, m = len(pts), model.n, model.m
    run = _ModelStepper(model, {**params, "T": plan.T}, pts, plan)
    kmax = int(plan.stop_k.max())
    metrics = _Metrics(np, P, N, plan.stop_k, int((plan.stop_k // N).max()))
    failures = _Failures(P, N, plan.T, plan.h)
    states = np.full((P, kmax + 1, n), np.nan) if record else None
    inputs = np.full((P, kmax + 1, m), np.nan) if record else None
    norm_prev = np.zeros(P)

    def fail(mask, norms, why, k):
        if failures.mark(mask, norms, metrics.peak, why, k):
            run.zero(failures.failed)

    with np.errstate(all="ignore"):
        for k in range(kmax + 1):
            bad = run.control(k)
            if bad is not None and bad.any():
                fail(bad, norm_prev, "the control is not finite (the predictor or the "
                     "feedback diverged)", k)
            run.hold(k, record)
            norm = _norm(run.x)
            metrics.record(k, np.where(failures.failed, 0.0, norm), _np_put)
            if states is not None and inputs is not None:
                states[:, k] = run.x.T
                inputs[:, k] = run.out.T
                states[failures.failed, k] = np.nan
                inputs[failures.failed, k] = np.nan
            if k == kmax:
                break
            bad = run.step()
            if bad.any():
                fail(bad, norm, "the plant state is not finite (the plant diverged)", k + 1)
            norm_prev = norm
    res = _finish(metrics, get_backend("numpy"), failures.failed, failures.norm,
                  failures.peak, plan.T, plan.h, N, failures.messages)
    res.states, res.inputs = trim(states, inputs, plan.stop_k + 1)
    return res


def _norm(x: np.ndarray) -> np.ndarray:
    """``|x|`` per point (``x`` of shape ``(n, P)``), the squares summed left to right."""
    sq = x[0] * x[0]
    for a in range(1, x.shape[0]):
        sq = sq + x[a] * x[a]
    return np.sqrt(sq)


class _ModelStepper:
    """The stepping of one model group (the maths), numpy, the points on the last axis:
    the controller at the sampling ticks (zero-order hold, Theorem 3.2, the predictor
    composing exact steps over the window) or at every tick (continuous input, Theorem
    2.1, its copy ``z`` reset to the predictor at every sample after the first), the
    plant's exact step each tick. ``U`` is the ring of controller outputs, one per period
    (zero-order hold) or per tick (continuous input)."""

    def __init__(self, model, p: dict, pts: ModelBatch, plan: _ModelPlan):
        P, n, m = len(pts), model.n, model.m
        self.model, self.p, self.plan, self.N, self.P, self.m = model, p, plan, plan.N, P, m
        self.zoh = model.control == "zoh"
        self.tau = pts.tau
        self.pidx = np.arange(P)
        self.Rx = int(plan.Dr_true.max()) + 1
        self.x0T = pts.x0.T
        self.x = pts.x0.T.copy()
        self.xring = np.zeros((self.Rx, n, P))
        self.y = self.x0T  # the controller's measurement (set at every sampling tick)
        self.u0T = pts.u0.T.copy()
        self.U = np.zeros((plan.Ru, m, P))
        self.held = self.u0T.copy()
        self.v = self.u0T.copy()
        self.out = self.u0T.copy()
        self.z = pts.x0.T.copy()  # the controller's copy of the state (continuous input)
        self.nfull, self.rem = plan.W // plan.N, plan.W % plan.N
        self.nseg = self.nfull + (self.rem > 0)

    def past(self, j: int) -> np.ndarray:
        """Controller output of slot index ``j`` (period or tick), ``u0`` before t = 0."""
        return self.U[j % self.plan.Ru] if j >= 0 else self.u0T

    def control(self, k: int) -> np.ndarray | None:
        """The controller at tick ``k`` (it measures at a sampling tick); returns where
        its output is not finite from a finite measurement (``None``: no output now)."""
        N, p, P, m = self.N, self.p, self.P, self.m
        self.xring[k % self.Rx] = self.x
        i, jj = divmod(k, N)
        if k % N == 0:
            src = k - self.plan.Dr_true
            self.y = np.where(src >= 0, self.xring[src % self.Rx, :, self.pidx].T,
                              self.x0T)
        if self.zoh:
            if k % N != 0:
                return None
            xs = self.y.copy()
            for e in range(int(self.nseg.max()), 0, -1):
                active = (e <= self.nfull) | ((e == self.nfull + 1) & (self.rem > 0))
                dur = np.where(e <= self.nfull, N * self.plan.h, self.rem * self.plan.h)
                stepped = np.asarray(self.model.step(xs, self.past(i - e), dur, p),
                                     dtype=float)
                xs = np.where(active, stepped, xs)
            self.held = np.asarray(self.model.k(xs, p), dtype=float).reshape(m, P)
        else:
            if k % N == 0 and k > 0:
                xs = self.y.copy()
                for e in range(int(self.plan.W.max()), 0, -1):
                    stepped = np.asarray(self.model.step(xs, self.past(k - e), self.plan.h,
                                                         p), dtype=float)
                    xs = np.where(e <= self.plan.W, stepped, xs)
                self.z = xs
            t = i * self.plan.T + jj * self.plan.h
            self.held = np.asarray(self.model.k(t + self.tau, self.z, p),
                                   dtype=float).reshape(m, P)
        return ~np.all(np.isfinite(self.held), axis=0) & np.all(np.isfinite(self.y), axis=0)

    def hold(self, k: int, record: bool) -> None:
        """The controller's output into its ring at tick ``k``, and the plant's input
        ``v`` through the input delay (``out``: what the controller outputs now)."""
        N, Ru, Dt, U = self.N, self.plan.Ru, self.plan.Dt, self.U
        if self.zoh:
            if k % N == 0:
                U[(k // N) % Ru] = self.held
            s = k - Dt
            due = (s >= 0) & (s % N == 0)
            if due.any():
                self.v = np.where(due, U[(s // N) % Ru, :, self.pidx].T, self.v)
            if record:
                sp = k - self.plan.Dpad
                self.out = np.where(sp >= 0, U[(sp // N) % Ru, :, self.pidx].T, self.u0T)
        else:
            U[k % Ru] = self.held
            s = k - Dt
            self.v = np.where(s >= 0, U[s % Ru, :, self.pidx].T, self.u0T)
            self.out = self.held

    def step(self) -> np.ndarray:
        """The plant (and the controller's copy) one base step on; returns where the
        plant state is not finite."""
        h, p = self.plan.h, self.p
        if not self.zoh:
            self.z = np.asarray(self.model.step(self.z, self.held, h, p), dtype=float)
        self.x = np.asarray(self.model.step(self.x, self.v, h, p), dtype=float)
        return ~np.all(np.isfinite(self.x), axis=0)

    def zero(self, failed: np.ndarray) -> None:
        """The state, outputs and rings of the ``failed`` points held at zero."""
        self.x[:, failed] = 0.0
        self.held[:, failed] = 0.0
        self.v[:, failed] = 0.0
        self.out[:, failed] = 0.0
        self.U[:, :, failed] = 0.0
        if not self.zoh:
            self.z[:, failed] = 0.0


def _np_put(a, index, value):
    a[index] = value
    return a
