"""A network channel on the base grid: per-packet delays, loss, and a delivery policy.

The channel takes the place of a transport delay (``delaycomp.maths.delayline``). On the
grid ``t_k = t0 + k h`` it sends a **packet** every ``P`` steps (``period = P h``; ``period
= 0``: every step): packet ``j`` leaves at step ``s_j = j P`` carrying the input ``u_{s_j}``
and its send time ``t_{s_j}`` (the **time stamp**). Its fate is drawn from the seed:

- **delay** ``d_j = delay + X_j``: ``X_j = 0`` (``constant``), uniform on ``[0, jitter)``
  (``uniform``), exponential of mean ``jitter`` (``exponential``), gamma of shape
  ``shape`` and mean ``jitter`` (``gamma``), or ``trace[(o + j) mod L]`` of a measured trace
  replayed in order from an offset ``o`` drawn from the seed (``trace``; ``delay`` is then
  its minimum and a ``NaN`` entry a lost packet). It is seen at the first grid point at or
  after its arrival, ``q_j = steps_up(d_j, h)`` steps after it left
  (``delaycomp.maths.grid.steps_up``);
- **loss**: none, ``bernoulli`` (each packet lost with probability ``loss``), or
  ``gilbert_elliott`` (a two-state Markov chain, good to bad with probability ``p_gb``, bad
  to good with ``p_bg``, starting good; a packet is lost with probability ``loss_good`` or
  ``loss_bad`` in the state it finds); and a packet later than ``max_delay`` (the timeout,
  default the largest delay the distribution gives) is lost too;
- **policy** for late and reordered packets: ``in_order`` delivers packets in the order
  they were sent, a packet that arrives early waiting for the ones before it (a lost one
  is waited for until its timeout, ``s_j + steps_up(max_delay, h)``); ``drop_stale``
  delivers a packet when it arrives unless a newer one was delivered before, and drops it
  then; ``playout`` is a receiver's **play-out buffer**: every packet is shown at its send
  time plus the timeout, ``s_j + Q`` with ``Q = steps_up(max_delay, h)`` (the largest
  delay), one that arrives later is lost; a varying delay becomes the constant ``Q h``
  (no loss: ``DelayLine`` of ``Q`` steps exactly).

The output at ``t_k`` is the value of the last packet delivered at or before ``t_k`` and
its time stamp; before the first delivery, the initial history ``u_init`` stamped
``t_k - delay``, at most ``t0`` (the history holds up to ``t0``: in a loop, the plant's
initial state). With a constant delay ``D h``, no loss and a packet every step this is
``DelayLine`` exactly: ``y_k = u_{k-D}``, ``u_init`` before ``t0 + D h``.

**Random numbers** are counter-based (no generator state to carry): the ``i``-th draw of
packet ``j`` is ``mix(key + (j 2^32 + i + 1) G)`` (``G`` the golden-ratio increment and
``mix`` the finalizer of SplitMix64, ``key = mix(seed ^ K)``), its top 53 bits a double in
``[0, 1)``; draw 0 decides the loss, draw 1 the Gilbert-Elliott transition, draws 2 on the
delay (gamma by Marsaglia and Tsang with Box-Muller normals). Integer arithmetic and one
``log``, ``sqrt``, ``cos``, ``pow`` of libm per step: the same numbers in C, and in numpy
over many runs at once.

Examples
--------
>>> line = ChannelLine(Channel(delay=0.02), n=1, h=0.01, u_init=[0.0])
>>> [line.step([float(k)])[0][0] for k in range(5)]
[0.0, 0.0, 0.0, 1.0, 2.0]
>>> ChannelLine(Channel(delay=0.02), 1, 0.01, [0.0]).step([7.0])[1]  # the stamp: t - delay
-0.02
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

from delaycomp.maths import grid

#: the delay distributions
DISTRIBUTIONS = ("constant", "uniform", "exponential", "gamma", "trace")
#: the loss models
LOSS_MODELS = ("none", "bernoulli", "gilbert_elliott")
#: what becomes of late and reordered packets
POLICIES = ("in_order", "drop_stale", "playout")
#: the largest seed (an FMI Integer)
SEED_MAX = 2**31 - 1

_M64 = (1 << 64) - 1
_GOLDEN = 0x9E3779B97F4A7C15  # 2^64 / golden ratio: SplitMix64's increment
_KEY = 0x6A09E667F3BCC909  # the fractional bits of sqrt(2): seed 0 is no zero key
_UNIT = 2.0 ** -53
#: the draws of one packet: loss, the Gilbert-Elliott transition, then the delay's
DRAW_LOSS, DRAW_STATE, DRAW_DELAY = 0, 1, 2


def mix(z: int) -> int:
    """SplitMix64's finalizer (Stafford's variant 13) of a 64-bit integer."""
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _M64
    return z ^ (z >> 31)


def stream_key(seed: int) -> int:
    """The key of a seed's draws."""
    return mix((seed & _M64) ^ _KEY)


def draw(key: int, counter: int) -> float:
    """The draw ``counter`` of a key: a double in ``[0, 1)``, a multiple of 2^-53."""
    return (mix((key + (counter * _GOLDEN)) & _M64) >> 11) * _UNIT


def packet_draw(key: int, j: int, i: int) -> float:
    """The ``i``-th draw of packet ``j`` (counter ``j 2^32 + i + 1``; counter 0 is the
    trace's offset)."""
    return draw(key, (j << 32) + i + 1)


def _open(u: float) -> float:
    """``1 - u``: a draw in ``(0, 1]``, whose logarithm is finite."""
    return 1.0 - u


def gamma_draw(key: int, j: int, shape: float) -> float:
    """A gamma variate of shape ``shape`` and scale 1 from packet ``j``'s delay draws:
    Marsaglia and Tsang (2000) for ``shape >= 1``, with a normal by Box-Muller; for
    ``shape < 1``, ``G(shape + 1) U^(1 / shape)``."""
    i = DRAW_DELAY
    boost = 1.0
    a = shape
    if a < 1.0:
        boost = math.pow(_open(packet_draw(key, j, i)), 1.0 / a)
        i += 1
        a = a + 1.0
    d = a - 1.0 / 3.0
    c = 1.0 / math.sqrt(9.0 * d)
    while True:
        u1, u2, u3 = (packet_draw(key, j, i + m) for m in range(3))
        i += 3
        x = math.sqrt(-2.0 * math.log(_open(u1))) * math.cos(2.0 * math.pi * u2)
        v = 1.0 + c * x
        if v <= 0.0:
            continue
        v = v * v * v
        if math.log(_open(u3)) < 0.5 * x * x + d - d * v + d * math.log(v):
            return d * v * boost


@dataclasses.dataclass(frozen=True)
class Channel:
    """A channel's parameters (see the module docstring); ``check`` says what is allowed."""

    delay: float = 0.0
    distribution: str = "constant"
    jitter: float = 0.0
    shape: float = 1.0
    trace: tuple[float, ...] = ()
    max_delay: float | None = None
    loss_model: str = "none"
    loss: float = 0.0
    p_gb: float = 0.0
    p_bg: float = 1.0
    loss_good: float = 0.0
    loss_bad: float = 1.0
    policy: str = "in_order"
    seed: int = 0
    period: float = 0.0

    def check(self) -> None:
        """``ValueError`` naming the first parameter out of its range."""
        def number(name: str, low: float, high: float = math.inf) -> None:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (
                    math.isfinite(v) and low <= v <= high):
                upper = f" and <= {high!r}" if math.isfinite(high) else ""
                raise ValueError(f"{name} = {v!r} is not allowed: must be a finite number "
                                 f">= {low!r}{upper}")

        for name, allowed in (("distribution", DISTRIBUTIONS), ("loss_model", LOSS_MODELS),
                              ("policy", POLICIES)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} = {getattr(self, name)!r} is not allowed: must be "
                                 f"one of {', '.join(allowed)}")
        number("delay", 0.0)
        number("jitter", 0.0)
        number("period", 0.0)
        for name in ("loss", "p_gb", "p_bg", "loss_good", "loss_bad"):
            number(name, 0.0, 1.0)
        if not (isinstance(self.shape, (int, float)) and not isinstance(self.shape, bool)
                and math.isfinite(self.shape) and self.shape > 0):
            raise ValueError(f"shape = {self.shape!r} is not allowed: must be a finite "
                             "number > 0")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not (
                0 <= self.seed <= SEED_MAX):
            raise ValueError(f"seed = {self.seed!r} is not allowed: must be an integer in 0 "
                             f".. {SEED_MAX}")
        if self.distribution == "trace":
            if not 1 <= len(self.trace) <= grid.MAX_STEPS:
                raise ValueError(f"trace ({len(self.trace)} delays) is not allowed: must "
                                 f"hold 1 to {grid.MAX_STEPS} delays")
            for i, d in enumerate(self.trace):
                if not (math.isnan(d) or (math.isfinite(d) and d >= self.delay)):
                    raise ValueError(f"trace[{i + 1}] = {d!r} is not allowed: must be a "
                                     f"delay >= delay = {self.delay!r} [s], or NaN (lost)")
        if self.max_delay is not None:
            number("max_delay", self.delay)
        elif self.distribution in ("exponential", "gamma") and self.jitter > 0:
            raise ValueError(f"max_delay is required for distribution = "
                             f"{self.distribution!r}: the timeout after which a packet is "
                             f"lost (a finite number >= delay = {self.delay!r})")

    def bound(self) -> float:
        """The largest delay a delivered packet has: ``max_delay``, else the
        distribution's largest (``delay`` and ``delay + jitter`` for ``constant`` and
        ``uniform``, the trace's largest)."""
        if self.max_delay is not None:
            return float(self.max_delay)
        if self.distribution == "uniform":
            return self.delay + self.jitter
        if self.distribution == "trace":
            finite = [d for d in self.trace if not math.isnan(d)]
            return max(finite) if finite else self.delay
        return self.delay  # constant, or no jitter

    def bound_name(self) -> str:
        """What ``bound`` is, in a message: ``max_delay``, ``delay + jitter`` (uniform),
        ``the trace's largest delay`` or ``delay``."""
        if self.max_delay is not None:
            return "max_delay"
        if self.distribution == "uniform" and self.jitter > 0:
            return "delay + jitter"
        if self.distribution == "trace":
            return "the trace's largest delay"
        return "delay"

    def key(self) -> int:
        """The key of the seed's draws."""
        return stream_key(self.seed)

    def offset(self) -> int:
        """Where a trace starts (draw 0 of the seed's stream); 0 without a trace."""
        if self.distribution != "trace":
            return 0
        return int(draw(self.key(), 0) * len(self.trace))

    def draw_fate(self, key: int, j: int, bad: bool, offset: int = 0
                  ) -> tuple[bool, float, bool]:
        """Packet ``j``'s draws ``(lost, delay, bad)`` given the Gilbert-Elliott chain's
        state before it (``bad``): lost by the loss model or not, its delay [s] (NaN: lost
        in the trace), the chain's state after it (before the timeout, which needs the
        grid)."""
        lost = False
        if self.loss_model == "bernoulli":
            lost = packet_draw(key, j, DRAW_LOSS) < self.loss
        elif self.loss_model == "gilbert_elliott":
            u = packet_draw(key, j, DRAW_STATE)
            bad = (u >= self.p_bg) if bad else (u < self.p_gb)
            lost = packet_draw(key, j, DRAW_LOSS) < (self.loss_bad if bad else self.loss_good)
        return lost, self.delay_of(key, j, offset), bad

    def delay_of(self, key: int, j: int, offset: int = 0) -> float:
        """Packet ``j``'s delay [s] (NaN: lost in the trace)."""
        dist = self.distribution
        if dist == "constant" or (dist != "trace" and self.jitter == 0):
            return self.delay
        if dist == "uniform":
            return self.delay + self.jitter * packet_draw(key, j, DRAW_DELAY)
        if dist == "exponential":
            return self.delay - self.jitter * math.log(_open(packet_draw(key, j, DRAW_DELAY)))
        if dist == "gamma":
            return self.delay + (self.jitter / self.shape) * gamma_draw(key, j, self.shape)
        return self.trace[(offset + j) % len(self.trace)]


@dataclasses.dataclass
class Packet:
    """A packet in flight: its number, the step it left, the step it is seen (or, lost,
    the step of its timeout), whether it is lost, its values."""

    seq: int
    sent: int
    ready: int
    lost: bool
    values: tuple[float, ...]


class ChannelLine:
    """``n`` signals through a ``Channel`` on the grid ``t0 + k h``.

    Contract as ``DelayLine``'s: ``output(u)`` gives ``(y_k, stamp_k)`` for the current
    input ``u_k`` without changing state; ``push(u)`` takes ``u_k`` as the grid advances
    from ``t_k`` to ``t_{k+1}``; ``step(u)`` is both.
    """

    def __init__(self, channel: Channel, n: int, h: float, u_init: Sequence[float],
                 t0: float = 0.0):
        channel.check()
        self.channel = channel
        self.n, self.h, self.t0 = n, h, t0
        init = tuple(float(v) for v in u_init)
        if len(init) != n:
            raise ValueError(f"u_init must have {n} values, got {len(init)}")
        self.u_init = init
        self.P = max(1, grid.steps_of(channel.period, h, "period",
                                      f"the communication step {h!r}"))
        bound = channel.bound()
        grid.check_steps(channel.bound_name(), bound, bound / h,
                         f"steps of the communication step {h!r}")
        self.Q = grid.steps_up(bound, h)
        self.key = channel.key()
        self.offset = channel.offset()
        self.k = 0
        self.inflight: list[Packet] = []
        self.current: Packet | None = None
        self.bad = False  # the Gilbert-Elliott chain's state
        #: this step's deliveries for its input (step, input, result): an FMU reads every
        #: output and then pushes, one step's draws and deliveries are made once
        self._memo: tuple | None = None

    def fate(self, j: int, bad: bool) -> tuple[bool, int, bool]:
        """Packet ``j``'s fate ``(lost, q, bad)`` given the chain's state before it: lost
        or not, the steps until it is seen (until its timeout, lost), the chain's state."""
        lost, d, bad = self.channel.draw_fate(self.key, j, bad, self.offset)
        if lost or not d / self.h <= self.Q + 1:  # NaN (lost in the trace), or surely late
            return True, self.Q, bad
        q = grid.steps_up(d, self.h)
        return (True, self.Q, bad) if q > self.Q else (False, q, bad)

    def _deliver(self, u) -> tuple[Packet | None, list[Packet], bool]:
        """``(current, in flight, bad)`` after the deliveries of this step."""
        k = self.k
        values = tuple(float(v) for v in u)
        memo = self._memo
        if memo is not None and memo[0] == k and memo[1] == values:
            return memo[2]
        pending = list(self.inflight)
        bad = self.bad
        if k % self.P == 0:
            lost, q, bad = self.fate(k // self.P, bad)
            if self.channel.policy == "playout":
                q = self.Q  # the play-out buffer: every packet at send time + the timeout
            pending.append(Packet(k // self.P, k, k + q, lost, values))
        current = self.current
        keep: list[Packet] = []
        if self.channel.policy != "drop_stale":  # in order (play-out: the order sent)
            blocked = False
            for p in pending:  # in the order sent
                if not blocked and p.ready <= k:
                    if not p.lost:
                        current = p
                else:
                    blocked = True
                    keep.append(p)
        else:  # drop_stale: the newest arrival wins, older and lost ones go
            for p in pending:
                if not p.lost and p.ready <= k and (current is None or p.seq > current.seq):
                    current = p
            keep = [p for p in pending if not p.lost and p.ready > k
                    and (current is None or p.seq > current.seq)]
        self._memo = (k, values, (current, keep, bad))
        return current, keep, bad

    def _seen(self, current: Packet | None) -> tuple[tuple[float, ...], float]:
        if current is None:  # the history, which holds up to t0
            return self.u_init, min((self.t0 + self.k * self.h) - self.channel.delay, self.t0)
        return current.values, self.t0 + current.sent * self.h

    def output(self, u) -> tuple[tuple[float, ...], float]:
        """``(y_k, stamp_k)``: the values of the last packet delivered by now (``u_k``
        itself where this step's packet is seen at once) and its send time."""
        return self._seen(self._deliver(u)[0])

    def push(self, u) -> None:
        """Take this step's input ``u_k``; the grid advances to ``t_{k+1}``."""
        self.current, self.inflight, self.bad = self._deliver(u)
        self.k += 1
        self._memo = None

    def step(self, u) -> tuple[tuple[float, ...], float]:
        """``output(u)`` then ``push(u)``."""
        out = self.output(u)
        self.push(u)
        return out

    def get_state(self) -> dict:
        """The line's state (plain values, for an FMU state)."""
        def packet(p: Packet | None):
            return None if p is None else [p.seq, p.sent, p.ready, p.lost, list(p.values)]
        return {"k": self.k, "bad": self.bad, "current": packet(self.current),
                "inflight": [packet(p) for p in self.inflight]}

    def set_state(self, state: dict) -> None:
        """Restore what ``get_state`` returned (checked by the FMU that holds it)."""
        def packet(row):
            return None if row is None else Packet(int(row[0]), int(row[1]), int(row[2]),
                                                    bool(row[3]), tuple(map(float, row[4])))
        self._memo = None
        self.k = int(state["k"])
        self.bad = bool(state["bad"])
        self.current = packet(state["current"])
        self.inflight = [packet(r) for r in state["inflight"]]
