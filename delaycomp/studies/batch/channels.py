"""The batch engine's LTI loops through network channels: ``run_lti_channels`` advances
``run_lti``'s loops (``delaycomp.studies.batch.lti``) with a channel
(``delaycomp.maths.channel.Channel``) in the place of the measurement delay and/or the
input delay, each point with its own seed, optionally under the time-stamp controller
(``_Stamped``), a chunk of points at a time, on numpy or CuPy (``channel_backend``).
"""

from __future__ import annotations

import numpy as np

from delaycomp.maths.lti import MODES
from delaycomp.maths.stamped import SNAP
from delaycomp.studies.batch.backends import Backend, get_backend
from delaycomp.studies.batch.base import (
    BatchError,
    BatchResult,
    grid_ticks,
    merge,
    take,
    trim,
    unique_rows,
)
from delaycomp.studies.batch.lti import LtiPlan, coefficients, dot, lti_plan
from delaycomp.studies.batch.metrics import BlockMetrics, sumsq
from delaycomp.system import LtiBatch

#: how close to ``age_max`` (in ``T``) a sample's age counts as within it: the time-stamp
#: controller's own (``delaycomp.maths.stamped.SNAP``)
STAMP_SNAP = SNAP

#: ``run_lti_channels``' default chunk: points advanced together (measured in
#: ``bench/channels.py``: a few thousand keep a tick's rows and the channel's arrays of a
#: chunk in cache while the per-tick overhead of numpy's calls stays small)
CHANNEL_CHUNK = 2048
#: on a GPU (CuPy): the device memory a chunk's largest arrays may take [bytes] (the send
#: steps of an input channel, one per tick and point, and the draws of 64 packets): the
#: chunk is as many points as fit, at most ``GPU_CHANNEL_CHUNK_MAX``
GPU_CHANNEL_BYTES = 2**31
GPU_CHANNEL_CHUNK_MAX = 2**18


def _constant_shown(D: np.ndarray, steps: int, xp=np):
    """The send step a constant delay of ``D`` ticks (per point) shows at each step: ``k -
    D``, ``-1`` before ``D`` (``DelayLine``)."""
    s = xp.arange(steps, dtype=xp.int64)[:, None] - xp.asarray(D)[None, :]
    return xp.where(s >= 0, s, -1)


def channel_backend(backend: Backend | str) -> Backend:
    """The array library of ``run_lti_channels``: numpy, or CuPy on a GPU (``auto``: CuPy
    where it reaches a GPU, else numpy). JAX is refused: its arrays are immutable, and the
    channel's stepping writes into its rings in place."""
    name = backend.name if isinstance(backend, Backend) else backend
    if name == "jax":
        raise BatchError("array backend jax is not allowed with a network channel: must be "
                         "numpy, cupy or auto (the channel's stepping writes in place)")
    if isinstance(backend, Backend):
        return backend
    if name == "auto":
        try:
            return get_backend("cupy")
        except BatchError:
            return get_backend("numpy")
    return get_backend(name)


def run_lti_channels(design: LtiBatch, stop: float, *, meas=None, inp=None,
                     meas_seeds=None, input_seeds=None, record: bool = False,
                     stamps: bool = False, age_max=None, chunk: int | None = None,
                     backend: Backend | str = "numpy") -> BatchResult:
    """Advance the ``P`` LTI loops of ``design`` to ``stop`` with a network channel
    (``delaycomp.maths.channel.Channel``) in the place of the measurement delay (``meas``)
    and/or the input delay (``inp``), each point with its own seed: the loop of
    ``run_lti`` (zero-order hold, ``compensated`` or ``uncompensated``), numpy.

    The channel's fates are drawn for every point at once
    (``delaycomp.maths.channel_batch.shown``): at tick ``k`` the controller's
    measurement is the state at the send step of the packet the measurement channel shows
    (``x0`` before any), the plant's input the controller output at the send step of the
    packet the input channel shows (``u0`` before any); a role without a channel keeps the
    constant delay ``r_true`` or ``tau_true``. A packet is at most ``Q`` ticks old when
    it is delivered (``Q = steps_up(bound, h)``), so a ring of ``Q + 1`` past states and a
    latch per point hold what is needed. The arithmetic is ``run_lti``'s, in its order.

    On a GPU (``backend="cupy"``) the same steps run on CuPy's arrays, the points of a
    chunk on the device: every operation is elementwise IEEE arithmetic or integer
    indexing, so the results are numpy's bit for bit (the exponential and gamma delays,
    which need libm, are drawn on the host).

    With ``stamps=True`` the controller is the time-stamp controller
    (``delaycomp.maths.stamped.StampedController``, a loop file's ``[controller] stamps =
    true``) vectorized over the points: at ``t_i`` each point's estimate of ``x(t_i)`` is
    its sample carried from its stamp (the send tick of the packet shown; the history
    ``x0`` is the state at ``t0``) when the sample is newer than the last one used and at
    most ``age_max`` old, else its last estimate carried over ``T``; the output is ``K``
    times the estimate carried over the controller's ``tau`` (``compensated``) or ``K y``.
    The pieces of the plant's input are multiples of ``h`` long (the stamps, ``t_i`` and
    ``tau`` lie on the base grid), so their exact flows are computed once, for ``k h``,
    ``k = 0 .. N``, per distinct ``(A, B)``: no matrix exponential per run.

    Parameters
    ----------
    design : delaycomp.system.LtiBatch
        The loops; every point with the same ``T`` and ``N`` (one base step ``h``). The
        controller's ``r`` and ``tau`` are what it assumes (its predictor).
    stop : float
        Stop time, a multiple of ``h``.
    meas, inp : Channel, optional
        The channels; their ``seed`` is replaced by the points' seeds.
    meas_seeds, input_seeds : array_like of int, optional
        One seed per point (default ``0 .. P - 1``).
    record : bool
        Keep every tick's state and controller output.
    stamps : bool
        The time-stamp controller in the place of the paper's.
    age_max : float or array_like, optional
        With ``stamps``: the oldest sample used [s] (per point or one for all); default
        the measurement channel's largest delay (``Channel.bound``, else ``r_true``) plus
        ``T``, as in loop files.
    chunk : int, optional
        Points advanced together (default ``CHANNEL_CHUNK`` on the CPU; on a GPU as many
        as ``GPU_CHANNEL_BYTES`` hold): the batch runs chunk by chunk, so its per-tick
        arrays stay in the processor's cache; the results do not depend on it.
    backend : Backend or str
        The array library: ``numpy`` (default), ``cupy`` (a GPU) or ``auto`` (CuPy where
        it reaches a GPU, else numpy); ``channel_backend``.

    Returns
    -------
    BatchResult
        The sweep's metrics and ``cost``: ``sum_k h (|x_k|^2 + |v_k|^2)`` over the ticks
        before ``stop`` (``v`` the plant's input), the rectangle rule of
        ``int_0^stop x'x + v'v dt`` (``inf`` where the run failed).
    """
    from delaycomp.maths.channel_batch import period_steps, timeout_steps

    be = channel_backend(backend)
    bad = [md for md in set(design.mode.tolist()) if md not in MODES]
    if bad:
        raise BatchError(f"mode = {bad[0]!r} is not allowed: must be one of {', '.join(MODES)}")
    P = len(design)
    if P == 0:
        raise BatchError("the batch has no points")
    if not (np.all(design.N == design.N[0]) and np.all(design.T == design.T[0])):
        raise BatchError("T and N are not allowed to differ between the points of a batch "
                         "with a channel: must be the same at every point")
    N = int(design.N[0])
    plan = lti_plan(design, N, float(stop))  # the checks, on every point
    h = float(plan.h[0])

    def seeds_of(given, name):
        s = np.arange(P) if given is None else np.broadcast_to(np.asarray(given), (P,))
        if not np.issubdtype(s.dtype, np.integer) or np.any(s < 0) or np.any(s > 2**31 - 1):
            raise BatchError(f"{name} are not allowed: must be integers in 0 .. {2**31 - 1}")
        return s

    def checked(channel, name):
        if channel is None:
            return None
        try:
            channel.check()
            timeout_steps(channel, h)
            period_steps(channel, h)
        except ValueError as exc:
            raise BatchError(f"{name.split('_')[0]} channel: {exc}") from None
        return seeds_of(meas_seeds if name == "meas_seeds" else input_seeds, name)

    seeds_m, seeds_i = checked(meas, "meas_seeds"), checked(inp, "input_seeds")
    ages = None
    if stamps:
        if age_max is None:
            bound = (np.full(P, float(meas.bound())) if meas is not None
                     else np.asarray(design.r_true, dtype=float))
            ages = bound + design.T
        else:
            ages = np.broadcast_to(np.asarray(age_max, dtype=float), (P,)).copy()
            if not np.all(np.isfinite(ages) & (ages >= 0)):
                raise BatchError(f"age_max = {age_max!r} is not allowed: must be a finite "
                                 "number >= 0 [s] (or one per point)")
    elif age_max is not None:
        raise BatchError("age_max is not allowed without stamps = True")
    if chunk is None:
        kmax = int(plan.stop_k.max())
        per_point = 8 * (kmax + 1) * (2 if inp is not None else 0) + 8 * 64 * 8 + 4096
        chunk = (CHANNEL_CHUNK if be.name == "numpy"
                 else max(CHANNEL_CHUNK, min(GPU_CHANNEL_CHUNK_MAX,
                                             GPU_CHANNEL_BYTES // per_point)))
    elif isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise BatchError(f"chunk = {chunk!r} is not allowed: must be an integer >= 1")
    flows: dict = {}
    parts = []
    for c0 in range(0, P, chunk):
        idx = np.arange(c0, min(P, c0 + chunk))
        whole = idx.size == P
        sub = design if whole else take(design, idx)
        part = _channel_chunk(sub, float(stop), meas, inp,
                              None if seeds_m is None else seeds_m[idx],
                              None if seeds_i is None else seeds_i[idx], record,
                              None if ages is None else ages[idx], flows,
                              plan if whole else _plan_take(plan, idx), be)
        parts.append((idx, part))
    return merge(parts, P)


def _plan_take(plan: LtiPlan, idx: np.ndarray) -> LtiPlan:
    """The plan of the points ``idx`` of ``plan``'s."""
    return LtiPlan(plan.N, plan.T[idx], plan.h[idx], plan.stop_k[idx], plan.Dr[idx],
                    plan.Dt[idx], plan.Ad[idx], plan.Bd[idx], plan.E[idx], plan.QB[:, idx])


def _channel_chunk(design: LtiBatch, stop: float, meas, inp, seeds_m, seeds_i,
                   record: bool, ages, flows: dict, plan: LtiPlan, be: Backend
                   ) -> BatchResult:
    """``run_lti_channels`` of the (checked) points of one chunk, ``plan`` theirs, on the
    array library ``be``."""
    from delaycomp.maths.channel_batch import shown, timeout_steps
    from delaycomp.studies import channel_kernel

    xp = be.xp
    P, N = len(design), int(design.N[0])
    h = float(plan.h[0])
    kmax = int(plan.stop_k.max())

    def fates(channel, seeds, every=1):
        """The packets shown: the compiled draws on the CPU where they are available (the
        same integers), else the array library's."""
        if be.name == "numpy":
            got = channel_kernel.shown(channel, seeds, h, kmax + 1, every)
            if got is not None:
                return got
        return shown(channel, seeds, h, kmax + 1, every=every, xp=xp)

    # the measurement at the sampling ticks alone
    Sm = (_constant_shown(plan.Dr, kmax + 1, xp)[::N] if meas is None
          else fates(meas, seeds_m, N))
    if inp is not None:
        Si, Qi = fates(inp, seeds_i), timeout_steps(inp, h)
    else:
        Si, Qi = None, int(plan.Dt.max())
        if not np.all(plan.Dt == plan.Dt[0]):
            Si = _constant_shown(plan.Dt, kmax + 1, xp)
    stamped = None
    if ages is not None:
        delay = (np.full(P, float(meas.delay)) if meas is not None
                 else np.asarray(design.r_true, dtype=float))
        stamped = _Stamped(be, plan, design, grid_ticks("tau", design.tau, plan.h), ages, delay,
                           flows)
    const = inp is None and bool(np.all(plan.Dt == plan.Dt[0]))
    run = _ChannelStepper(be, plan, design, Sm, None if const else Si, Qi, record, stamped,
                          int(plan.Dt[0]) if const else None)
    acc = BlockMetrics(be, P, N, plan.stop_k, int((plan.stop_k // N).max()))
    with np.errstate(all="ignore"):
        for i in range(kmax // N + 1):
            rows = min(N, kmax - i * N + 1)
            badc = run.sample(i)
            if badc.any():
                acc.cut(badc, i * N, "the control is not finite (the feedback diverged: "
                        "overflow)", plan.T, plan.h)
            blk, sqx = run.period(i, rows, i * N + rows - 1 == kmax)
            acc.block(blk, i * N, plan.T, plan.h, sqx)
    res = acc.finish(plan.T, plan.h)
    end = np.minimum(acc.cut_at, plan.stop_k + 1)
    cost = be.to_numpy(run.cost).copy()
    cost[~res.success] = np.inf
    res.cost = cost
    res.states, res.inputs = trim(run.states, run.inputs, end)
    return res


class _ChannelStepper:
    """The stepping of ``run_lti_channels`` (numpy or CuPy, the points on the last axis).

    The states are kept in a ring of ``nb`` blocks of ``N`` ticks, ``xb[b, row]``, long
    enough for the oldest packet the measurement channel shows at a sampling tick (its
    age is known from the channel's fates, drawn before the run): the controller reads its
    sample there at the sampling ticks alone, and a block is the metrics' rows as it
    stands. The controller outputs are a ring of one per period; the plant's input a
    latch, updated where the input channel shows another packet (a constant delay: at
    the ticks its period's output arrives). Every value is computed as before, in the same
    order: the cost's sums a block at a time, row after row.
    """

    def __init__(self, be: Backend, plan: LtiPlan, d: LtiBatch, Sm, Si, Qi: int,
                 record: bool, stamped: _Stamped | None = None, Dt_const: int | None = None):
        xp = be.xp
        P, n, m = d.B.shape
        N = plan.N
        self.be, self.xp = be, xp
        self.plan, self.N, self.n, self.m, self.P = plan, N, n, m, P
        self.Sm, self.Si, self.Dt_const = Sm, Si, Dt_const
        kmax = int(plan.stop_k.max())
        ticks = xp.arange(0, kmax + 1, N)[:, None]
        age = int(xp.max(xp.where(Sm >= 0, ticks - Sm, 0)))  # Sm: one row and column or more
        self.nb = age // N + 2  # blocks kept: the oldest sample read and this period's
        self.Lmax = plan.QB.shape[0]
        self.Ru = max(self.Lmax, 0 if stamped is None else stamped.back) + Qi // N + 3
        self.stamped = stamped
        self.comp = be.asarray(np.asarray(d.mode == "compensated"))  # on the device, once

        self.Ad, self.Bd, self.K, self.E, self.QB, self.x0, self.u0 = coefficients(
            plan, d, lambda a: be.asarray(np.ascontiguousarray(a)), self.Lmax)
        self.xb = xp.zeros((self.nb, N, n, P))
        self.flat = self.xb.reshape(self.nb * N, n, P)
        self.flat[0] = self.x0
        self.y = self.x0.copy()
        self.v = self.u0.copy()  # the plant-input latch: u0 before any packet
        self.held = self.u0.copy()
        self.U = xp.zeros((self.Ru, m, P))
        self.bv = xp.stack([dot(self.Bd[a], self.v) for a in range(n)])
        self.vb = xp.zeros((N, m, P))  # the plant's input at each tick of the block
        self.cost = xp.zeros(P)
        self.h = float(plan.h[0])  # one h in a channel batch
        self.prev_i = xp.full(P, -1, dtype=xp.int64)
        self.pidx = xp.arange(P)
        self.tmp = xp.empty(P)
        self.states = np.full((P, kmax + 1, n), np.nan) if record else None
        self.inputs = np.full((P, kmax + 1, m), np.nan) if record else None

    def sample(self, i: int) -> np.ndarray:
        """The controller at the sampling tick ``i N`` from the state at the send tick of
        the packet shown then (``x0`` before any); returns where its output is not finite
        from a finite measurement (on the host)."""
        xp = self.xp
        s = self.Sm[i]
        slot = s % (self.nb * self.N)
        y = self.y
        for a in range(self.n):
            xp.copyto(y[a], xp.where(s >= 0, self.flat[slot, a, self.pidx], self.x0[a]))
        n, U = self.n, self.U
        if self.stamped is not None:
            xhat = self.stamped.predict(i, y, s, U, self.Ru)
            phi = list(xp.where(self.comp, xhat, y))
        else:
            phi = [dot(self.E[a], y) for a in range(n)]
            for q in range(self.Lmax):
                past = U[(i - q - 1) % self.Ru] if i - q - 1 >= 0 else self.u0
                for a in range(n):
                    phi[a] = phi[a] + dot(self.QB[q][a], past)
        self.held = xp.stack([dot(self.K[c], phi) for c in range(self.m)])
        self.U[i % self.Ru] = self.held
        return self.be.to_numpy(~xp.all(xp.isfinite(self.held), axis=0)
                                & xp.all(xp.isfinite(y), axis=0))

    def _input(self, k: int) -> None:
        """The plant-input latch at tick ``k``."""
        N = self.N
        if self.Dt_const is not None:  # a constant delay: the output of tick k - D
            s = k - self.Dt_const
            if s < 0 or s % N:
                return
            self.v = self.U[(s // N) % self.Ru].copy()
        else:
            s = self.Si[k]
            new = self.xp.flatnonzero(s != self.prev_i)
            if not new.size:
                return
            self.v[:, new] = self.U[(s[new] // N) % self.Ru, :, new].T
            self.prev_i = s
        self.bv = self.xp.stack([dot(self.Bd[a], self.v) for a in range(self.n)])

    def period(self, i: int, rows: int, last: bool) -> tuple[np.ndarray, np.ndarray]:
        """The ticks of period ``i`` (``rows`` of them; ``last``: the run's last tick is
        among them, not stepped from): the input latch, the record, the plant's exact
        step into the next row of the ring; then the cost of the block. Returns the
        block of states and their ``|x|^2``."""
        N, n, nb, xp = self.N, self.n, self.nb, self.xp
        bi = i % nb
        blk, nxt = self.xb[bi], self.xb[(i + 1) % nb]
        Ad, tmp, vb = self.Ad, self.tmp, self.vb
        for row in range(rows):
            k = i * N + row
            self._input(k)
            vb[row] = self.v
            x = blk[row]
            if self.states is not None and self.inputs is not None:
                self.states[:, k] = self.be.to_numpy(x).T
                self.inputs[:, k] = self.be.to_numpy(self.held).T
            if last and row == rows - 1:
                break
            out = blk[row + 1] if row + 1 < N else nxt[0]
            for a in range(n):  # Ad[a] x + bv[a], left to right (dot's order)
                xp.multiply(Ad[a][0], x[0], out=out[a])
                for b in range(1, n):
                    xp.multiply(Ad[a][b], x[b], out=tmp)
                    xp.add(out[a], tmp, out=out[a])
                xp.add(out[a], self.bv[a], out=out[a])
        # the cost: sum_k h (|x_k|^2 + |v_k|^2), each tick's term added in turn
        sqx = sumsq(blk[:rows])
        stepped = rows - 1 if last else rows
        if stepped > 0:
            v = vb[:stepped]
            sq = sqx[:stepped] + v[:, 0] * v[:, 0]
            for c in range(1, self.m):
                sq += v[:, c] * v[:, c]
            sq *= self.h
            for row in range(stepped):
                xp.add(self.cost, sq[row], out=self.cost)
        return blk[:rows], sqx


class _Stamped:
    """The time-stamp controller's estimate and prediction for every point at once
    (``delaycomp.maths.stamped.StampedController``'s maths, in ticks): the plant's input
    is ``u_j`` over ticks ``[j N + Dtau, (j + 1) N + Dtau)`` (``u0`` for ``j < 0``), each
    piece of it ``L`` ticks long carried by the exact flow ``(F[L], G[L])`` of its point's
    ``(A, B)``, the flows of ``L = 0 .. N`` computed once. The decisions (a new sample,
    too old) compare the same doubles as the controller: the channel's stamps ``s h``
    (before any packet ``min(k h - delay, 0)``), ``t_i = i T`` and ``age_max + 1e-9 T``."""

    def __init__(self, be: Backend, plan: LtiPlan, d: LtiBatch, Dtau: np.ndarray,
                 age_max: np.ndarray, delay: np.ndarray, cache: dict | None = None):
        from delaycomp.maths.lti import flow

        xp, dev = be.xp, be.asarray
        self.xp = xp
        P, n, m = d.B.shape
        N, h = plan.N, float(plan.h[0])
        self.N, self.n, self.m, self.h, self.T = N, n, m, h, float(plan.T[0])
        first, inv = unique_rows(d.A, d.B)
        self.inv = dev(inv)
        cache = {} if cache is None else cache  # the flows of (A, B, h, N): chunks share them

        def flows_of(p):
            key = (d.A[p].tobytes(), d.B[p].tobytes(), d.A.shape, d.B.shape, h, N)
            if key not in cache:
                cache[key] = [flow(d.A[p], d.B[p], k * h) for k in range(N + 1)]
            return cache[key]

        flows = [flows_of(p) for p in first]
        self.F = dev(np.array([[f[0] for f in row] for row in flows]))  # (U, N + 1, n, n)
        self.G = dev(np.array([[f[1] for f in row] for row in flows]))  # (U, N + 1, n, m)
        self.Dtau = dev(Dtau.astype(np.int64))
        self.limit = dev(age_max + STAMP_SNAP * self.T)
        self.delay = dev(delay)
        self.u0 = dev(np.ascontiguousarray(d.u0.T))  # (m, P)
        #: the periods of outputs the carries reach back (the ring's length needed)
        self.back = int(np.max(np.floor(age_max / h).astype(np.int64) + Dtau)) // N + 3
        self.z = None  # the estimates of x(t_{i-1}), (n, P), of the backend
        self.last = xp.full(P, -np.inf)  # the stamp of the newest sample used

    def carry(self, x: np.ndarray, idx: np.ndarray, a: np.ndarray, b: np.ndarray,
              U: np.ndarray, Ru: int) -> np.ndarray:
        """The states ``x`` (``(n, len(idx))``) of the points ``idx`` carried from tick
        ``a`` to tick ``b`` (per point, ``a <= b``), piece by piece."""
        xp = self.xp
        x, a = x.copy(), a.copy()
        N, n, m = self.N, self.n, self.m
        Dtau = self.Dtau[idx]
        while True:
            on = xp.flatnonzero(a < b)
            if not on.size:
                return x
            p, aa = idx[on], a[on]
            j = (aa - Dtau[on]) // N  # the output the plant receives just after aa
            end = xp.minimum((j + 1) * N + Dtau[on], b[on])
            L = end - aa
            F, G = self.F[self.inv[p], L], self.G[self.inv[p], L]
            u = xp.where(j >= 0, U[j % Ru, :, p].T, self.u0[:, p])
            xo = x[:, on]
            for r in range(n):
                acc = F[:, r, 0] * xo[0]
                for c in range(1, n):
                    acc = acc + F[:, r, c] * xo[c]
                g = G[:, r, 0] * u[0]
                for c in range(1, m):
                    g = g + G[:, r, c] * u[c]
                x[r, on] = acc + g
            a[on] = end

    def predict(self, i: int, y: np.ndarray, sent: np.ndarray, U: np.ndarray,
                Ru: int) -> np.ndarray:
        """``x_hat`` of every point at ``t_i`` from the samples ``y`` (``(n, P)``) sent at
        ticks ``sent`` (``-1``: the history); stores the estimates of ``x(t_i)``."""
        xp = self.xp
        N, P = self.N, y.shape[1]
        k = i * N
        t = 0.0 + i * self.T
        stamp = xp.where(sent >= 0, 0.0 + sent * self.h,
                         xp.minimum((0.0 + k * self.h) - self.delay, 0.0))
        if self.z is None:  # the first instant always uses its sample
            new = xp.ones(P, dtype=bool)
        else:
            new = (stamp > self.last) & (t - xp.maximum(stamp, 0.0) <= self.limit)
        self.last = xp.where(new, xp.maximum(stamp, self.last), self.last)
        z = xp.empty_like(y)
        fresh = xp.flatnonzero(new)
        if fresh.size:
            z[:, fresh] = self.carry(y[:, fresh], fresh, xp.maximum(sent[fresh], 0),
                                     xp.full(fresh.size, k, dtype=xp.int64), U, Ru)
        old = xp.flatnonzero(~new)
        if old.size:
            assert self.z is not None
            z[:, old] = self.carry(self.z[:, old], old,
                                   xp.full(old.size, k - N, dtype=xp.int64),
                                   xp.full(old.size, k, dtype=xp.int64), U, Ru)
        self.z = z
        every = xp.arange(P)
        return self.carry(z, every, xp.full(P, k, dtype=xp.int64), k + self.Dtau, U, Ru)
