"""FMU slave: a network channel on n signals, in a delay's place.

The maths is ``delaycomp.maths.channel.ChannelLine``: packets every ``period`` stamped with
their send time, each delayed by ``delay`` plus a draw of ``distribution`` (``jitter``,
``shape``, or the delays ``trace[1..L]`` of a measured trace, ``L`` the build's, a negative
entry a lost packet), lost by ``loss_model`` or after ``max_delay``, delivered by
``policy``; ``seed`` fixes the draws. Outputs: the last delivered packet's values ``y`` and
its send time ``stamp``. With ``distribution = constant`` and no loss it is the delay FMU
(``delaycomp_delay.py``), the same numbers. See README.md beside this file.
"""

from __future__ import annotations

import math

from pythonfmu import Fmi2Causality, Fmi2Variability, Integer

from delaycomp.fmu.slave import (
    TableSlave,
    check_finite,
    check_inputs,
    is_roundoff_step,
    state_count,
    state_flag,
    state_number,
    state_refused,
    state_vector,
)
from delaycomp.maths.channel import (
    DISTRIBUTIONS,
    LOSS_MODELS,
    POLICIES,
    SEED_MAX,
    Channel,
    ChannelLine,
    Packet,
)
from delaycomp.maths.grid import grid_step, same_step
from delaycomp.names import indexed

#: the Real parameters after ``delay``: name, start, description
_REALS = (
    ("jitter", 0.0, "the random part of the delay [s], >= 0: the width of uniform, the mean "
                    "of exponential and gamma"),
    ("shape", 1.0, "gamma's shape, > 0"),
    ("max_delay", 0.0, "timeout [s]: a packet later than this is lost; 0: the "
                       "distribution's largest delay (required for exponential and gamma)"),
    ("loss", 0.0, "bernoulli: the probability that a packet is lost, 0 .. 1"),
    ("p_gb", 0.0, "gilbert_elliott: probability of going from good to bad, 0 .. 1"),
    ("p_bg", 1.0, "gilbert_elliott: probability of going from bad to good, 0 .. 1"),
    ("loss_good", 0.0, "gilbert_elliott: loss probability in the good state, 0 .. 1"),
    ("loss_bad", 1.0, "gilbert_elliott: loss probability in the bad state, 0 .. 1"),
    ("period", 0.0, "time between packets [s], a multiple of the communication step; 0: "
                    "every step"),
)


class DelaycompChannel(TableSlave):
    """A network channel: per-packet delays, loss and a delivery policy, time stamps."""

    description = ("network channel: packets stamped with their send time, delayed by "
                   "delay + a draw, lost or delivered in order")
    fp_guarded = True  # values are copied; the draws' arithmetic is bounded

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        n = int(self.config["n"])
        self.n = n
        self.delay = 0.0
        self.u0 = [0.0] * n
        self.u = [0.0] * n
        self.distribution = "constant"
        self.loss_model = "none"
        self.policy = "in_order"
        self.L = int(self.config.get("L", 0))
        self.trace = [0.0] * self.L
        self.seed = 0
        self.values = {name: start for name, start, _ in _REALS}
        self.line: ChannelLine | None = None  # made at the first step, when h is known
        self.channel: Channel | None = None
        self._h: float | None = None
        self.parameter("delay", lambda: self.delay, lambda v: setattr(self, "delay", v),
                       "the least delay [s], >= 0 (constant: the delay)")
        self.string_parameter("distribution", lambda: self.distribution,
                              lambda v: setattr(self, "distribution", v),
                              "the delay's random part: constant (none), uniform, "
                              "exponential, gamma, or trace", DISTRIBUTIONS)
        for name, _, text in _REALS:
            get, put = ((lambda a=name: self.values[a]),
                        (lambda v, a=name: self.values.__setitem__(a, v)))
            self.parameter(name, get, put, text)
        self.string_parameter("loss_model", lambda: self.loss_model,
                              lambda v: setattr(self, "loss_model", v),
                              "none, bernoulli (loss) or gilbert_elliott (p_gb, p_bg, "
                              "loss_good, loss_bad)", LOSS_MODELS)
        self.string_parameter("policy", lambda: self.policy,
                              lambda v: setattr(self, "policy", v),
                              "in_order (a packet waits for those sent before it), "
                              "drop_stale (a packet older than the one shown is dropped) or "
                              "playout (each packet shown at its send time + max_delay, a "
                              "later one lost)",
                              POLICIES)
        self.register_variable(Integer(
            "seed", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
            getter=lambda: self.seed, setter=lambda v: setattr(self, "seed", int(v)),
            description=f"the draws' seed, 0 .. {SEED_MAX}"))
        for i in range(self.L):
            get, put = (lambda i=i: self.trace[i]), (lambda v, i=i: self.trace.__setitem__(i, v))
            self.parameter(f"trace[{i + 1}]", get, put,
                           "distribution = trace: a measured delay [s], >= delay, replayed in "
                           "order from an offset drawn from the seed; negative: a lost packet")
        for i in range(n):
            get, put = (lambda i=i: self.u0[i]), (lambda v, i=i: self.u0.__setitem__(i, v))
            self.parameter(f"u0[{i + 1}]", get, put,
                           "input history, shown until the first packet is delivered")
        self.input_names = indexed("u", n)
        self.output_names = indexed("y", n)
        for i, name in enumerate(self.input_names):
            self.real_input(name, (lambda i=i: self.u[i]),
                            (lambda v, i=i: self.u.__setitem__(i, v)), "signal sent, input")
        for i, (name, src) in enumerate(zip(self.output_names, self.input_names)):
            # a packet seen in the step it is sent (delay 0) carries this step's input
            self.real_output(name, (lambda i=i: self._output()[0][i]),
                             "the last delivered packet's value", depends_on=(src,))
        self.real_output("stamp", lambda: self._output()[1],
                         "send time [s] of the value shown (the history: t - delay, at "
                         "most t0)")

    def _make_channel(self) -> Channel:
        v = self.values
        if self.distribution == "trace" and not self.trace:
            self.fail("distribution = 'trace' is not allowed: this channel FMU is built "
                      "without a trace (L = 0): build it with the trace's length L >= 1")
        for i, d in enumerate(self.trace):
            check_finite(f"trace[{i + 1}]", d)
            if self.distribution == "trace" and 0 <= d < self.delay:
                self.fail(f"trace[{i + 1}] = {d!r} is not allowed: must be a delay >= delay "
                          f"= {self.delay!r} [s], or negative (a lost packet)")
        trace = tuple(math.nan if d < 0 else d for d in self.trace)
        channel = Channel(delay=self.delay, distribution=self.distribution,
                          jitter=v["jitter"], shape=v["shape"], trace=trace,
                          max_delay=v["max_delay"] or None, loss_model=self.loss_model,
                          loss=v["loss"], p_gb=v["p_gb"], p_bg=v["p_bg"],
                          loss_good=v["loss_good"], loss_bad=v["loss_bad"],
                          policy=self.policy, seed=self.seed, period=v["period"])
        try:
            channel.check()
        except ValueError as exc:
            self.fail(str(exc))
        return channel

    def _setup(self):
        check_finite("delay", self.delay)
        for name, value in self.values.items():
            check_finite(name, value)
        self.channel = self._make_channel()
        for i, v in enumerate(self.u0):
            check_finite(f"u0[{i + 1}]", v)
        self.line = None
        self._h = None

    def _output(self) -> tuple[tuple[float, ...], float]:
        if self.line is not None:
            return self.line.output(self.u)
        # before the first step (h not known yet): packet 0 is seen at once where it is not
        # lost and has no delay (the grid would take a delay up to 1e-9 h for none too)
        ch = self.channel
        if ch is None:
            return tuple(self.u0), self.t0 - self.delay
        lost, d, _ = ch.draw_fate(ch.key(), 0, False, ch.offset())
        # a play-out buffer shows every packet after the largest delay
        if not lost and (ch.bound() == 0 if ch.policy == "playout" else d == 0):
            return tuple(self.u), self.t0
        return tuple(self.u0), self.t0 - ch.delay

    def _hidden_state(self) -> dict:
        if self.line is None:
            return {"h": None}
        return {"h": self._h, "line": self.line.get_state()}

    def _restore_hidden(self, hidden: dict) -> None:
        if hidden == {"h": None}:
            return
        h = state_number("hidden.h", hidden.get("h"), positive=True)
        line = self._new_line(h, refuse=lambda m: state_refused("hidden.h", h, m))
        st = hidden.get("line")
        if not isinstance(st, dict):
            raise state_refused("hidden.line", st, "the channel's state")
        k = state_count("hidden.line.k", st.get("k"))
        bad = state_flag("hidden.line.bad", st.get("bad"))
        current = st.get("current")
        cur = None if current is None else self._packet("hidden.line.current", current, k, line)
        rows = st.get("inflight")
        if not (isinstance(rows, list) and len(rows) <= line.Q // line.P + 2):
            raise state_refused("hidden.line.inflight", rows, f"a list of at most "
                                f"{line.Q // line.P + 2} packets")
        flight = [self._packet(f"hidden.line.inflight[{i}]", r, k, line)
                  for i, r in enumerate(rows)]
        seqs = [p.seq for p in flight]
        if seqs != sorted(set(seqs)) or (cur is not None and any(s <= cur.seq for s in seqs)):
            raise state_refused("hidden.line.inflight", rows, "packets in the order sent, "
                                "each newer than the one shown")
        line.set_state({"k": k, "bad": bad, "current": current, "inflight": rows})
        self.line, self._h = line, h

    def _packet(self, field: str, row, k: int, line: ChannelLine) -> Packet:
        """A packet of a restored state: sent at a send step before step k, seen within
        the timeout, its values finite."""
        if not (isinstance(row, list) and len(row) == 5):
            raise state_refused(field, row, "[seq, sent, ready, lost, values]")
        seq = state_count(f"{field}.seq", row[0])
        sent = state_count(f"{field}.sent", row[1], seq * line.P)
        if sent >= k:
            raise state_refused(f"{field}.sent", sent, f"a step before {k}")
        ready = state_count(f"{field}.ready", row[2])
        if not sent <= ready <= sent + line.Q:
            raise state_refused(f"{field}.ready", ready, f"in {sent} .. {sent + line.Q}")
        lost = state_flag(f"{field}.lost", row[3])
        values = state_vector(f"{field}.values", row[4], self.n)
        return Packet(seq, sent, ready, lost, tuple(float(v) for v in values))

    def _new_line(self, h: float, refuse) -> ChannelLine:
        assert self.channel is not None
        try:
            return ChannelLine(self.channel, self.n, h, self.u0, self.t0)
        except ValueError as exc:
            raise refuse(str(exc)) from None

    def _step(self, t: float, step_size: float) -> None:
        if not (math.isfinite(step_size) and step_size > 0):
            self.fail(f"step size {step_size!r} at t = {t!r} is not allowed: must be a finite "
                      "number > 0")
        if self.line is None:
            self.line = self._new_line(step_size, refuse=lambda m: self.fail(m))
            self._h = step_size
        else:
            h = self._h
            assert h is not None  # set with the line
            if is_roundoff_step(step_size, h):
                return  # the master's round-off (fmuslave.ROUNDOFF_STEP_FRACTION): nothing moves
            if not (same_step(step_size, h, t) or grid_step(t, step_size, h, self.t0)):
                self.fail(f"step size {step_size!r} is not allowed: this channel runs on a "
                          f"fixed communication step, {h!r}")
        check_inputs(self.input_names, self.u, t)
        self.line.push(self.u)
