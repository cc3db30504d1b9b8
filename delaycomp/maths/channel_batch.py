"""The network channel's draws and deliveries for many seeds at once (numpy).

``delaycomp.maths.channel`` draws a packet's fate from a counter-based generator (SplitMix64
of a key and a counter: no state to carry), so the fates of every packet of every seed can
be drawn at once: this module gives, for arrays of seeds and packet numbers, the same
doubles as the scalar code (``packet_draw``, the delay of each distribution, Bernoulli and
Gilbert-Elliott loss, a trace's offset), bit for bit, and the step at which a run's channel
shows each packet under every policy, as ``ChannelLine`` delivers them.

**The same doubles.** The integer part is numpy ``uint64`` arithmetic, whose ``*`` and
``+`` wrap modulo 2^64 as the scalar code's ``& (2^64 - 1)`` does (numpy does not warn on
wrapping integer arithmetic of arrays). A draw is its top 53 bits times 2^-53, exact in a
double. ``sqrt`` is correctly rounded everywhere; numpy's own ``log``, ``cos`` and ``pow``
are not libm's (its SIMD kernels differ from glibc in the last bit for some arguments:
measured, 0.3 % of ``log`` and 5 % of ``pow`` calls), so those go through ``math`` element
by element (``_libm``): exact, and paid only by the exponential and gamma distributions.

**What a run's channel shows.** The channel's output at step ``k`` is the value of the
newest packet delivered by then (``ChannelLine``): with ``drop_stale`` packet ``j`` is
delivered at its arrival ``a_j = s_j + q_j`` unless lost, and the output is the largest
``j`` with ``a_j <= k``; with ``in_order`` packet ``j`` is delivered (or, lost, passed) at
``D_j = max(ready_j, D_{j-1})``, ``ready_j`` its arrival or, lost, its timeout
``s_j + Q``, and the output is the largest delivered ``j`` with ``D_j <= k``; with
``playout`` every packet is ``ready`` at ``s_j + Q`` (lost if it arrives later). Either way
the packet shown is a function of the draws alone, not of the values carried: ``shown``
gives, per step and run, the send step of the packet shown (``-1``: none yet, the initial
history), which a batch of loops uses as an index into its stored past (a delivered packet
is at most ``Q = steps_up(bound, h)`` steps old when it is delivered).

**Other array libraries.** ``shown`` and the functions under it take ``xp``, the array
module (``numpy``, or ``cupy`` for a GPU: the batch engine's ``get_backend``): every step
is an elementwise integer or IEEE double operation, the same on either, so CuPy gives the
same doubles and the same steps (``tests/test_channel_batch_gpu.py`` on a GPU). The
draws of the exponential and gamma distributions, which need libm, are made on the host
and moved to the device.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from delaycomp.maths import grid
from delaycomp.maths.channel import DRAW_DELAY, DRAW_LOSS, DRAW_STATE, Channel

_U = np.uint64
#: SplitMix64's increment and the key's constant, the scalar module's (its module
#: docstring; tests/test_channel_batch.py holds the keys and draws equal)
_GOLDEN = 0x9E3779B97F4A7C15
_KEY = 0x6A09E667F3BCC909
_C1 = _U(0xBF58476D1CE4E5B9)
_C2 = _U(0x94D049BB133111EB)


def _host(xp, a) -> np.ndarray:
    """``a`` (an array of ``xp``) on the host."""
    return a if xp is np else xp.asnumpy(a)


def _libm(fn: Callable[[float], float], a: np.ndarray) -> np.ndarray:
    """``fn`` (a function of ``math``) of every element of ``a``: libm's doubles, as the
    scalar code and the C twin compute them."""
    a = np.asarray(a, dtype=float)
    return np.fromiter(map(fn, a.ravel().tolist()), dtype=float, count=a.size).reshape(a.shape)


def mix(z) -> np.ndarray:
    """SplitMix64's finalizer of each element (``delaycomp.maths.channel.mix``)."""
    z = np.array(z, dtype=np.uint64)  # a copy: the steps below work in place
    return _mix_inplace(z)


def _mix_inplace(z, xp=np):
    """``mix`` of the ``uint64`` array ``z`` (of ``xp``), in its own memory (no
    temporaries but one)."""
    t = xp.empty_like(z)
    for shift, mult in ((30, _C1), (27, _C2)):
        xp.right_shift(z, _U(shift), out=t)
        xp.bitwise_xor(z, t, out=z)
        xp.multiply(z, mult, out=z)
    xp.right_shift(z, _U(31), out=t)
    xp.bitwise_xor(z, t, out=z)
    return z


def stream_keys(seeds) -> np.ndarray:
    """The key of each seed's draws (``stream_key``), as ``uint64``."""
    seeds = np.asarray(seeds, dtype=np.int64)
    if np.any(seeds < 0):
        raise ValueError("seeds must be >= 0")
    return mix(seeds.astype(np.uint64) ^ _U(_KEY))


def _mantissas(keys, counters, xp=np):
    """The top 53 bits of draw ``counter`` of each key, as ``uint64`` (the draw is this
    times 2^-53, exact)."""
    k = xp.asarray(keys, dtype=xp.uint64)
    c = xp.asarray(counters, dtype=xp.uint64)
    z = xp.multiply(c, _U(_GOLDEN))
    z = xp.add(k, z, out=z if z.shape == np.broadcast_shapes(k.shape, c.shape) else None)
    _mix_inplace(z, xp)
    return xp.right_shift(z, _U(11), out=z)


def draws(keys, counters, xp=np):
    """Draw ``counter`` of each key (``draw``): doubles in ``[0, 1)``; ``keys`` and
    ``counters`` broadcast; ``xp`` the array module (numpy or cupy)."""
    out = _mantissas(keys, counters, xp).astype(xp.float64)
    return xp.multiply(out, 2.0 ** -53, out=out)


def _packet_counters(j, i, xp=np):
    j = xp.asarray(j, dtype=xp.uint64)
    i = xp.asarray(i, dtype=xp.uint64)
    return (j << _U(32)) + i + _U(1)


def packet_draws(keys, j, i, xp=np):
    """The ``i``-th draw of packet ``j`` (``packet_draw``); ``keys``, ``j`` and ``i``
    broadcast (``j < 2^32``); ``xp`` the array module (numpy or cupy)."""
    return draws(keys, _packet_counters(j, i, xp), xp)


def _below(keys, j, i, p: float, xp=np):
    """``packet_draws(keys, j, i) < p`` in integers: the draw is ``m 2^-53`` with ``m``
    the top 53 bits of ``z = mix(...)``, and ``m 2^-53 < p`` exactly when ``m < L =
    ceil(p 2^53)`` (``p 2^53`` is exact, a power of two's scaling of ``p`` in ``[0, 1]``),
    that is when ``z < L 2^11`` (``L 2^11 = 2^64``: always)."""
    L = math.ceil(p * 2.0 ** 53)
    k = xp.asarray(keys, dtype=xp.uint64)
    c = _packet_counters(j, i, xp)
    if L >= 2**53:
        return xp.ones(np.broadcast_shapes(k.shape, c.shape), dtype=bool)
    z = xp.multiply(c, _U(_GOLDEN))
    z = xp.add(k, z, out=z if z.shape == np.broadcast_shapes(k.shape, c.shape) else None)
    return _mix_inplace(z, xp) < _U(L << 11)


def gamma_draws(keys, j, shape: float) -> np.ndarray:
    """Gamma variates of shape ``shape``, scale 1 (``gamma_draw``): Marsaglia and Tsang's
    rejection loop run for every element until all are accepted, each element drawing its
    own counters as the scalar loop does."""
    keys, j = np.broadcast_arrays(np.asarray(keys, dtype=np.uint64),
                                  np.asarray(j, dtype=np.uint64))
    out_shape = keys.shape
    keys, j = keys.ravel(), j.ravel()
    i = np.full(keys.size, DRAW_DELAY, dtype=np.uint64)
    boost = np.ones(keys.size)
    a = float(shape)
    if a < 1.0:
        boost = _libm(lambda u: math.pow(1.0 - u, 1.0 / a), packet_draws(keys, j, i))
        i = i + _U(1)
        a = a + 1.0
    d = a - 1.0 / 3.0
    c = 1.0 / math.sqrt(9.0 * d)
    out = np.empty(keys.size)
    todo = np.arange(keys.size)
    while todo.size:
        kk, jj, ii = keys[todo], j[todo], i[todo]
        u1 = packet_draws(kk, jj, ii)
        u2 = packet_draws(kk, jj, ii + _U(1))
        u3 = packet_draws(kk, jj, ii + _U(2))
        i[todo] = ii + _U(3)
        x = np.sqrt(-2.0 * _libm(math.log, 1.0 - u1)) * _libm(math.cos, 2.0 * math.pi * u2)
        v = 1.0 + c * x
        pos = v > 0.0
        v3 = v * v * v
        with np.errstate(invalid="ignore", divide="ignore"):
            logv = np.where(pos, _libm(lambda t: math.log(t) if t > 0 else math.nan, v3),
                            np.nan)
        ok = pos & (_libm(math.log, 1.0 - u3) < 0.5 * x * x + d - d * v3 + d * logv)
        out[todo[ok]] = d * v3[ok] * boost[todo[ok]]
        todo = todo[~ok]
    return out.reshape(out_shape)


def offsets(channel: Channel, keys, xp=np):
    """Where each run's trace starts (``Channel.offset``); zeros without a trace."""
    keys = xp.asarray(keys, dtype=xp.uint64)
    if channel.distribution != "trace":
        return xp.zeros(keys.shape, dtype=xp.int64)
    return (draws(keys, 0, xp) * len(channel.trace)).astype(xp.int64)


def delays(channel: Channel, keys, j, offset=0, xp=np):
    """Packet ``j``'s delay [s] for each key (``Channel.delay_of``; NaN: lost in the
    trace); ``keys``, ``j`` and ``offset`` broadcast; ``xp`` the array module (numpy or
    cupy: the exponential and gamma draws, libm's, are made on the host)."""
    keys, j, offset = xp.broadcast_arrays(xp.asarray(keys, dtype=xp.uint64),
                                          xp.asarray(j, dtype=xp.int64),
                                          xp.asarray(offset, dtype=xp.int64))
    dist = channel.distribution
    if dist == "constant" or (dist != "trace" and channel.jitter == 0):
        return xp.full(keys.shape, float(channel.delay))
    if dist == "uniform":
        # jitter (m 2^-53) = (jitter 2^-53) m exactly (a power of two's scaling): one
        # product fewer, the same doubles
        d = _mantissas(keys, _packet_counters(j, DRAW_DELAY, xp), xp).astype(xp.float64)
        d *= channel.jitter * 2.0 ** -53
        d += channel.delay
        return d
    if xp is not np and dist in ("exponential", "gamma"):
        return xp.asarray(delays(channel, _host(xp, keys), _host(xp, j), _host(xp, offset)))
    if dist == "exponential":
        return channel.delay - channel.jitter * _libm(
            math.log, 1.0 - packet_draws(keys, j, DRAW_DELAY))
    if dist == "gamma":
        return channel.delay + (channel.jitter / channel.shape) * gamma_draws(
            keys, j, channel.shape)
    trace = xp.asarray(np.asarray(channel.trace, dtype=float))
    return trace[(offset + j) % len(trace)]


def losses(channel: Channel, keys, packets: int) -> np.ndarray:
    """Whether the loss model loses packet ``j`` of each key: shape ``(packets, R)``
    (before the timeout, which needs the grid); the Gilbert-Elliott chain starts good and
    moves once a packet, as in ``Channel.draw_fate``."""
    keys = np.asarray(keys, dtype=np.uint64).reshape(-1)
    return _loss_rows(channel, keys, 0, packets, np.zeros(keys.size, dtype=bool))[0]


def _loss_rows(channel: Channel, keys, j0: int, j1: int, bad, xp=np) -> tuple:
    """``losses`` of packets ``j0 .. j1 - 1`` and the Gilbert-Elliott chain's state
    after them, from ``bad`` (its state before ``j0``)."""
    j = xp.arange(j0, j1, dtype=xp.uint64)[:, None]
    if channel.loss_model == "none":
        return xp.zeros((j1 - j0, keys.size), dtype=bool), bad
    if channel.loss_model == "bernoulli":
        return _below(keys[None, :], j, DRAW_LOSS, channel.loss, xp), bad
    u_loss = packet_draws(keys[None, :], j, DRAW_LOSS, xp)
    u_state = packet_draws(keys[None, :], j, DRAW_STATE, xp)
    lost = xp.empty((j1 - j0, keys.size), dtype=bool)
    for jj in range(j1 - j0):
        bad = xp.where(bad, u_state[jj] >= channel.p_bg, u_state[jj] < channel.p_gb)
        lost[jj] = u_loss[jj] < xp.where(bad, channel.loss_bad, channel.loss_good)
    return lost, bad


def steps_up(values, step: float, xp=np):
    """``delaycomp.maths.grid.steps_up`` elementwise (finite ``values >= 0``).

    ``grid.steps_up`` takes the nearest integer ``k`` of ``r = value / step`` where ``|r -
    k| <= GRID_RTOL max(1, |r|)``, else ``ceil(r)``: for ``r >= 0`` that is ``floor(r)``
    where ``r - floor(r)`` (exact) is within the tolerance, else ``ceil(r)`` (the nearest
    integer above, within the tolerance, is ``ceil(r)`` anyway): three passes.
    """
    ratio = xp.divide(xp.asarray(values, dtype=float), step)
    f = xp.floor(ratio)
    frac = xp.subtract(ratio, f)
    xp.maximum(ratio, 1.0, out=ratio)  # |r| >= 0 here
    xp.multiply(ratio, grid.GRID_RTOL, out=ratio)
    up = xp.greater(frac, ratio)
    out = f.astype(xp.int64)
    out += up
    return out


def timeout_steps(channel: Channel, h: float) -> int:
    """``Q``: the steps after which a packet is lost (``ChannelLine.Q``), checked."""
    bound = channel.bound()
    grid.check_steps("max_delay" if channel.max_delay is not None else "delay", bound,
                     bound / h, f"steps of the communication step {h!r}")
    return grid.steps_up(bound, h)


def period_steps(channel: Channel, h: float) -> int:
    """Steps between packets (``ChannelLine.P``)."""
    return max(1, grid.steps_of(channel.period, h, "period", f"the communication step {h!r}"))


def fates(channel: Channel, seeds, h: float, packets: int) -> tuple[np.ndarray, np.ndarray]:
    """``(lost, q)`` of packets ``0 .. packets - 1`` of each seed, shape ``(packets, R)``:
    lost or not (by the loss model, a NaN in the trace, or later than the timeout ``Q``),
    the steps until it is seen (``Q`` where lost: its timeout), as ``ChannelLine.fate``."""
    channel.check()
    keys = stream_keys(np.asarray(seeds).reshape(-1))
    lost, q, _ = _fate_rows(channel, keys, offsets(channel, keys), h,
                            timeout_steps(channel, h), 0, packets,
                            np.zeros(keys.size, dtype=bool))
    return lost, q


def _fate_rows(channel: Channel, keys, offs, h: float, Q: int, j0: int, j1: int, bad,
               xp=np) -> tuple:
    """``fates`` of packets ``j0 .. j1 - 1`` and the loss chain's state after them."""
    j = xp.arange(j0, j1, dtype=xp.int64)[:, None]
    lost, bad = _loss_rows(channel, keys, j0, j1, bad, xp)
    d = delays(channel, keys[None, :], j, offs[None, :], xp)
    if channel.distribution == "uniform" or (channel.distribution != "trace"
                                             and (channel.jitter == 0
                                                  or channel.distribution == "constant")):
        # d <= bound in doubles (delay + jitter u rounds below delay + jitter, u < 1), so
        # q <= Q: no packet is late (the general test below finds none)
        if d.shape != lost.shape:
            d = xp.broadcast_to(d, lost.shape)
        q = steps_up(d, h, xp)
    else:
        with np.errstate(invalid="ignore"):
            late = ~(d / h <= Q + 1)  # NaN (lost in the trace), or surely late
        lost = lost | late
        q = steps_up(xp.where(lost, 0.0, d), h, xp)
        lost = lost | (q > Q)
    xp.putmask(q, lost, Q)
    return lost, q, bad


#: packets drawn at a time by ``shown``: their arrays (a few per packet and run) stay in
#: the processor's cache for a few thousand runs
_ROWS = 64


def sizes(channel: Channel, h: float, steps: int, every: int = 1) -> tuple[int, int, int, int]:
    """``(P, Q, J, rows)`` of ``shown``'s arguments (the channel checked): the steps between
    packets, the timeout in steps, the packets sent in ``steps`` steps and the rows shown
    (every ``every``-th step).

    Examples
    --------
    >>> sizes(Channel(delay=0.02, period=0.03), 0.01, 10, every=4)
    (3, 2, 4, 3)
    """
    channel.check()
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"every = {every!r} is not allowed: must be an integer >= 1")
    P = period_steps(channel, h)
    Q = timeout_steps(channel, h)
    J = (steps - 1) // P + 1 if steps > 0 else 0
    rows = (steps - 1) // every + 1 if steps > 0 else 0
    return P, Q, J, rows


def shown(channel: Channel, seeds, h: float, steps: int, every: int = 1, xp=np):
    """The send step of the packet each run's channel shows at steps ``0 .. steps - 1``,
    shape ``(steps, R)``; ``-1`` where none has been delivered yet (the initial history).
    With ``every > 1``: at steps ``0, every, 2 every, ...`` alone (the rows a sampler
    reads), shape ``((steps - 1) // every + 1, R)``.

    Packet ``j`` is put at the step it is delivered, ``D_j`` (in order: ``max(ready_j,
    D_{j-1})``, ``ready_j`` its arrival or, lost, its timeout; drop_stale: its arrival;
    playout: ``s_j + Q`` in order), the newest at each step kept, and the newest up to
    each step taken down the steps (a running maximum): the largest ``j`` delivered by
    then (a packet delivered at ``D`` counts from row ``ceil(D / every)`` on). The packets
    are drawn ``_ROWS`` at a time. ``xp`` is the array module of the result (numpy, or
    cupy: the same integers, on the GPU).

    Examples
    --------
    A constant delay of two steps shows packet ``k - 2`` (sent at step ``k - 2``):

    >>> shown(Channel(delay=0.02), [0], 0.01, 5)[:, 0].tolist()
    [-1, -1, 0, 1, 2]
    """
    P, Q, J, rows = sizes(channel, h, steps, every)
    keys = xp.asarray(stream_keys(np.asarray(seeds).reshape(-1)))
    offs = offsets(channel, keys, xp)
    R = keys.size
    best = xp.full((rows + 1, R), -1, dtype=xp.int64)  # row ``rows``: never shown
    flat = best.reshape(-1)
    runs = xp.arange(R, dtype=xp.int64)
    bad = xp.zeros(R, dtype=bool)
    before = xp.full(R, np.iinfo(np.int64).min, dtype=xp.int64)  # D_{j0 - 1}
    # the row of each delivery step D <= (J - 1) P + Q: ceil(D / every), at most ``rows``
    row_of = xp.minimum((xp.arange((J - 1) * P + Q + 1 if J else 1, dtype=xp.int64)
                         + (every - 1)) // every, rows)
    for j0 in range(0, J, _ROWS):
        j1 = min(J, j0 + _ROWS)
        lost, q, bad = _fate_rows(channel, keys, offs, h, Q, j0, j1, bad, xp)
        if channel.policy == "playout":  # the play-out buffer: every packet at s_j + Q
            q.fill(Q)
        ready = q
        ready += xp.arange(j0, j1, dtype=xp.int64)[:, None] * P
        if channel.policy != "drop_stale":  # in order (play-out: the order sent)
            xp.maximum(ready[0], before, out=ready[0])  # D_j = max(ready_j, D_{j-1})
            for r in range(1, j1 - j0):
                xp.maximum(ready[r - 1], ready[r], out=ready[r])
            before = ready[-1].copy()
        ready = row_of[ready]  # the first row at or after D_j
        xp.putmask(ready, lost, rows)
        ready *= R
        ready += runs
        # packet j into its row: one packet's targets are distinct (one per run), and the
        # packets come in increasing j, so each write is the maximum so far (no scatter
        # maximum: the same on every array library, no atomics on a GPU)
        for r in range(j1 - j0):
            flat[ready[r]] = j0 + r
    for k in range(1, rows):
        xp.maximum(best[k - 1], best[k], out=best[k])
    best = best[:rows]
    return best if P == 1 else xp.where(best >= 0, best * P, -1)


def stamps(channel: Channel, sent, h: float, t0: float = 0.0, xp=np):
    """The time stamps the channel outputs with the packets ``shown`` gives (``sent``,
    shape ``(steps, R)``): ``t0 + s h``, or before any delivery ``min(t_k - delay, t0)``
    (``ChannelLine``'s)."""
    k = xp.arange(sent.shape[0], dtype=float)[:, None]
    history = xp.minimum((t0 + k * h) - channel.delay, t0)
    return xp.where(sent >= 0, t0 + sent * h, history)
