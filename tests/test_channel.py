"""The network channel's maths (issue 29, item 1): ``delaycomp.maths.channel``.

Checked against what does not share its code: SplitMix64's published first output; scipy's
distributions (Kolmogorov-Smirnov); the loss models' stationary rates and burst lengths
from their formulas; the delivery policies written here a second way, over the whole run
at once (a running maximum of release steps for ``in_order``, the newest arrival for
``drop_stale``); ``DelayLine`` for the constant channel, bit for bit.

The statistical tests draw from fixed seeds, so they are deterministic; their thresholds
(a KS p-value of 1e-3, 4.5 standard errors) are what a correct sampler passes with
probability 0.999 or more, and what a wrong scale, shape or rate (off by a few percent at
these sample sizes) fails.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from scipy import stats

from delaycomp.maths.channel import (
    Channel,
    ChannelLine,
    draw,
    mix,
    packet_draw,
    stream_key,
)
from delaycomp.maths.delayline import DelayLine

H = 0.01


def _inputs(steps: int, n: int) -> np.ndarray:
    return np.random.default_rng(7).normal(size=(steps, n))


def test_splitmix64_known_answer_and_draws_in_the_unit_interval():
    """SplitMix64 from state 0: first output 0xE220A8397B1DCDAF (Vigna's reference
    splitmix64.c); a draw is the top 53 bits, a multiple of 2^-53 in [0, 1)."""
    assert mix(0x9E3779B97F4A7C15) == 0xE220A8397B1DCDAF
    assert draw(0, 1) == (0xE220A8397B1DCDAF >> 11) * 2.0 ** -53
    key = stream_key(5)
    values = [packet_draw(key, j, i) for j in range(200) for i in range(5)]
    assert all(0.0 <= v < 1.0 and (v * 2**53).is_integer() for v in values)
    assert len(set(values)) == len(values)
    assert stream_key(0) != 0 and stream_key(0) != stream_key(1)


@pytest.mark.parametrize("D", [0, 1, 7, 36])
@pytest.mark.parametrize("policy", ["in_order", "drop_stale", "playout"])
def test_a_constant_channel_is_the_delay_line_bit_for_bit(D, policy):
    """No jitter, no loss, a packet every step: ``y_k = u_{k-D}`` (``u_init`` before), as
    ``DelayLine`` gives it, the same doubles; the stamp is the send time ``t_{k-D}``, and
    ``t_k - delay`` while the history is out."""
    n, steps = 3, 150
    u = _inputs(steps, n)
    u_init = [0.5, -1.0, 2.0]
    line = ChannelLine(Channel(delay=D * H, policy=policy, seed=11), n, H, u_init)
    ref = DelayLine(n, D, u_init)
    for k in range(steps):
        want = ref.output(u[k])
        ref.push(u[k])
        got, stamp = line.step(u[k])
        assert got == want
        assert stamp == (k - D) * H if k >= D else math.isclose(stamp, k * H - D * H)


def _delays(channel: Channel, count: int) -> np.ndarray:
    key = stream_key(channel.seed)
    return np.array([channel.delay_of(key, j) for j in range(count)])


@pytest.mark.parametrize("distribution, shape, law", [
    ("uniform", 1.0, lambda m, k: stats.uniform(scale=m)),
    ("exponential", 1.0, lambda m, k: stats.expon(scale=m)),
    ("gamma", 0.4, lambda m, k: stats.gamma(k, scale=m / k)),
    ("gamma", 1.0, lambda m, k: stats.gamma(k, scale=m / k)),
    ("gamma", 2.5, lambda m, k: stats.gamma(k, scale=m / k)),
    ("gamma", 12.0, lambda m, k: stats.gamma(k, scale=m / k)),
])
def test_the_delay_distributions_are_scipys(distribution, shape, law):
    """20000 packets' delays minus ``delay`` against scipy's law of the same parameters
    (``jitter`` the uniform's width, the exponential's and the gamma's mean)."""
    channel = Channel(delay=0.05, distribution=distribution, jitter=0.08, shape=shape,
                      max_delay=10.0, seed=3)
    extra = _delays(channel, 20000) - 0.05
    dist = law(0.08, shape)
    assert stats.kstest(extra, dist.cdf).pvalue > 1e-3
    assert abs(extra.mean() - dist.mean()) <= 4.5 * dist.std() / math.sqrt(len(extra))
    assert extra.min() >= 0.0


def test_another_scale_fails_the_same_test():
    """What the threshold rejects: the exponential draws tested against a mean 3 % off."""
    extra = _delays(Channel(distribution="exponential", jitter=0.08, max_delay=10.0, seed=3),
                    20000)
    assert stats.kstest(extra, stats.expon(scale=0.08 * 1.03).cdf).pvalue < 1e-3


def _fates(channel: Channel, count: int, h: float = H):
    line = ChannelLine(channel, 1, h, [0.0])
    bad, out = False, []
    for j in range(count):
        lost, q, bad = line.fate(j, bad)
        out.append((lost, q, bad))
    return out


def test_bernoulli_loss_rate():
    lost = np.array([f[0] for f in _fates(Channel(loss_model="bernoulli", loss=0.3,
                                                  seed=9), 20000)])
    assert abs(lost.mean() - 0.3) <= 4.5 * math.sqrt(0.3 * 0.7 / len(lost))


def test_gilbert_elliott_stationary_loss_and_burst_length():
    """Gilbert's model (lost in bad, kept in good): the loss rate is the bad state's
    stationary probability ``p_gb / (p_gb + p_bg)`` and a burst lasts ``1 / p_bg`` packets
    on average; with losses in both states the rate weighs them by that probability."""
    p_gb, p_bg = 0.05, 0.25
    fates = _fates(Channel(loss_model="gilbert_elliott", p_gb=p_gb, p_bg=p_bg, seed=4),
                   40000)
    lost = np.array([f[0] for f in fates])
    assert np.array_equal(lost, np.array([f[2] for f in fates]))  # lost exactly when bad
    pi_bad = p_gb / (p_gb + p_bg)
    # a Markov chain's samples are correlated: the standard error grows by
    # sqrt((1 + rho) / (1 - rho)), rho = 1 - p_gb - p_bg its lag-one correlation
    rho = 1 - p_gb - p_bg
    se = math.sqrt(pi_bad * (1 - pi_bad) / len(lost) * (1 + rho) / (1 - rho))
    assert abs(lost.mean() - pi_bad) <= 4.5 * se
    edges = np.flatnonzero(np.diff(np.r_[0, lost.astype(int), 0]))
    bursts = edges[1::2] - edges[::2]
    mean_burst = 1 / p_bg
    assert abs(bursts.mean() - mean_burst) <= 4.5 * math.sqrt(1 - p_bg) / p_bg / math.sqrt(
        len(bursts))
    mixed = _fates(Channel(loss_model="gilbert_elliott", p_gb=p_gb, p_bg=p_bg,
                           loss_good=0.1, loss_bad=0.6, seed=4), 40000)
    rate = np.mean([f[0] for f in mixed])
    assert abs(rate - (pi_bad * 0.6 + (1 - pi_bad) * 0.1)) <= 0.02


def _policy_reference(fates, P: int, steps: int, policy: str, Q: int
                      ) -> list[int | None]:
    """The packet each step shows, computed over the whole run: packet ``j`` leaves at
    ``j P`` and is ready at ``j P + q`` (lost: its timeout; ``playout``: ``j P + Q`` always);
    ``in_order`` releases it at the running maximum of the ready steps of it and all before
    it, ``drop_stale`` and ``playout`` at its own;
    a step shows the newest packet not lost released by then (None: the history)."""
    sent = np.arange(len(fates)) * P
    ready = sent + np.array([q for _, q, _ in fates])
    lost = np.array([f[0] for f in fates])
    if policy == "playout":  # each at its send step + the timeout Q (late ones: lost)
        ready = sent + Q
    release = np.maximum.accumulate(ready) if policy == "in_order" else ready
    shown: list[int | None] = []
    for k in range(steps):
        seen = np.flatnonzero(~lost & (release <= k) & (sent <= k))
        shown.append(int(seen.max()) if len(seen) else None)
    return shown


@pytest.mark.parametrize("policy", ["in_order", "drop_stale", "playout"])
@pytest.mark.parametrize("channel", [
    Channel(delay=0.02, distribution="uniform", jitter=0.3, loss_model="bernoulli", loss=0.3,
            seed=1),
    Channel(delay=0.0, distribution="exponential", jitter=0.1, max_delay=0.25, seed=2,
            period=0.05),
    Channel(delay=0.01, distribution="gamma", jitter=0.2, shape=2.0, max_delay=0.6,
            loss_model="gilbert_elliott", p_gb=0.1, p_bg=0.4, seed=5, period=0.03),
    Channel(delay=0.03, distribution="trace", trace=(0.03, 0.2, float("nan"), 0.07, 0.11),
            seed=6),
], ids=["uniform-bernoulli", "exponential-period", "gamma-gilbert", "trace"])
def test_the_policies_against_a_whole_run_computation(channel, policy):
    """Jitter of several periods (packets overtake each other), loss, timeouts: the line's
    value and stamp at each step are those of the packet the whole-run computation shows."""
    channel = Channel(**{**channel.__dict__, "policy": policy})
    steps, n = 400, 2
    u = _inputs(steps, n)
    line = ChannelLine(channel, n, H, [9.0, -9.0])
    P = line.P
    fates = _fates(channel, steps // P + 1)
    shown = _policy_reference(fates, P, steps, policy, line.Q)
    overtaken = 0
    for k in range(steps):
        values, stamp = line.step(u[k])
        j = shown[k]
        if j is None:
            assert values == (9.0, -9.0) and stamp == min(k * H - channel.delay, 0.0)
        else:
            assert values == tuple(u[j * P]) and stamp == j * P * H
        overtaken += j is not None and k > 0 and shown[k - 1] is not None and j < shown[k - 1]
    assert overtaken == 0  # the stamps never go back, by any policy
    assert len({s for s in shown if s is not None}) > 10  # the run delivers


@pytest.mark.parametrize("loss", [0.0, 0.3])
def test_a_playout_buffer_makes_the_varying_delay_constant(loss):
    """Uniform jitter of 30 steps (packets overtake each other): behind a play-out buffer
    every packet is shown exactly Q = steps_up(delay + jitter, h) steps after it left, so
    without loss the line is ``DelayLine`` of Q steps, the same doubles; with loss a lost
    packet's step keeps the value before it (its age grows by one step per lost packet)."""
    channel = Channel(delay=0.02, distribution="uniform", jitter=0.3, policy="playout",
                      loss_model="bernoulli", loss=loss, seed=3)
    n, steps = 2, 400
    u = _inputs(steps, n)
    line = ChannelLine(channel, n, H, [1.0, -1.0])
    Q = line.Q
    assert Q == 32
    ref = DelayLine(n, Q, [1.0, -1.0])
    lost = [f[0] for f in _fates(channel, steps)]
    ages = []
    for k in range(steps):
        want = ref.output(u[k])
        ref.push(u[k])
        got, stamp = line.step(u[k])
        if k < Q:
            assert got == (1.0, -1.0)
            continue
        j = max(i for i in range(k - Q + 1) if not lost[i]) if any(
            not x for x in lost[:k - Q + 1]) else None
        if not loss:
            assert got == want and stamp == (k - Q) * H
        elif j is not None:
            assert got == tuple(u[j]) and stamp == j * H
        ages.append(round(k - stamp / H))
    assert min(ages) == Q and (max(ages) > Q) == (loss > 0)


def test_in_order_waits_where_drop_stale_moves_on():
    """A packet overtaken: ``drop_stale`` shows the newer one when it arrives and drops the
    older; ``in_order`` shows nothing new until the older arrives (or times out)."""
    # the trace: packet 0 takes 0.2 s, packet 1 0.05 s (it overtakes), then 0.05 s each
    channel = Channel(delay=0.05, distribution="trace", trace=(0.2,) + (0.05,) * 99, seed=0)
    offset = ChannelLine(channel, 1, H, [0.0]).offset
    channel = Channel(**{**channel.__dict__, "trace": tuple(np.roll(channel.trace, offset))})
    for policy, first in (("drop_stale", 6), ("in_order", 20)):
        line = ChannelLine(Channel(**{**channel.__dict__, "policy": policy}), 1, H, [-1.0])
        outs = [line.step([float(k)]) for k in range(30)]
        shown = next(k for k, (values, _) in enumerate(outs) if values[0] >= 0)
        assert shown == first, (policy, outs)
        # drop_stale: packet 1, sent at 0.01; in_order: packet 0 releases packets 1 to 15,
        # which arrived meanwhile (each 5 steps after it left), and the newest shows
        assert outs[shown][1] == (1 if policy == "drop_stale" else 15) * H


def test_a_trace_is_replayed_in_order_from_an_offset_drawn_from_the_seed():
    trace = (0.01, 0.02, float("nan"), 0.05)
    offsets = set()
    for seed in range(12):
        channel = Channel(delay=0.01, distribution="trace", trace=trace, seed=seed)
        line = ChannelLine(channel, 1, H, [0.0])
        offsets.add(line.offset)
        for j in range(10):
            d = channel.delay_of(line.key, j, line.offset)
            want = trace[(line.offset + j) % 4]
            assert d == want or (math.isnan(d) and math.isnan(want))
            assert line.fate(j, False)[0] == math.isnan(want)
    assert offsets == {0, 1, 2, 3}


def test_the_state_restores_the_run():
    channel = Channel(delay=0.02, distribution="gamma", jitter=0.15, shape=1.5,
                      max_delay=0.5, loss_model="gilbert_elliott", p_gb=0.1, p_bg=0.3,
                      seed=8)
    u = _inputs(200, 2)
    line = ChannelLine(channel, 2, H, [0.0, 0.0])
    first = [line.step(u[k]) for k in range(90)]
    saved = line.get_state()
    rest = [line.step(u[k]) for k in range(90, 200)]
    again = ChannelLine(channel, 2, H, [0.0, 0.0])
    again.set_state(saved)
    assert [again.step(u[k]) for k in range(90, 200)] == rest
    assert first != rest[:90]


def test_the_seed_decides_the_run():
    channel = Channel(distribution="uniform", jitter=0.2, loss_model="bernoulli", loss=0.2)
    runs = {}
    for seed in (0, 0, 1):
        line = ChannelLine(Channel(**{**channel.__dict__, "seed": seed}), 1, H, [0.0])
        runs.setdefault(seed, []).append([line.step([float(k)]) for k in range(200)])
    assert runs[0][0] == runs[0][1] and runs[0][0] != runs[1][0]


@pytest.mark.parametrize("fields, message", [
    ({"delay": -0.1}, "delay = -0.1 is not allowed: must be a finite number >= 0.0"),
    ({"delay": math.inf}, "delay = inf is not allowed"),
    ({"distribution": "pareto"}, "distribution = 'pareto' is not allowed: must be one of "
                                 "constant, uniform, exponential, gamma, trace"),
    ({"jitter": -1.0}, "jitter = -1.0 is not allowed"),
    ({"shape": 0.0}, "shape = 0.0 is not allowed: must be a finite number > 0"),
    ({"loss_model": "burst"}, "loss_model = 'burst' is not allowed"),
    ({"loss": 1.5}, "loss = 1.5 is not allowed: must be a finite number >= 0.0 and <= 1.0"),
    ({"p_gb": -0.1}, "p_gb = -0.1 is not allowed"),
    ({"policy": "fifo"}, "policy = 'fifo' is not allowed: must be one of in_order, "
                         "drop_stale"),
    ({"seed": -1}, "seed = -1 is not allowed: must be an integer in 0 .. 2147483647"),
    ({"seed": 1.5}, "seed = 1.5 is not allowed"),
    ({"period": -0.2}, "period = -0.2 is not allowed"),
    ({"distribution": "exponential", "jitter": 0.1}, "max_delay is required for "
                                                     "distribution = 'exponential'"),
    ({"max_delay": 0.01, "delay": 0.02}, "max_delay = 0.01 is not allowed: must be a finite "
                                         "number >= 0.02"),
    ({"distribution": "trace"}, "trace (0 delays) is not allowed: must hold 1 to"),
    ({"distribution": "trace", "trace": (0.1, -0.1)}, "trace[2] = -0.1 is not allowed: must "
                                                      "be a delay >= delay = 0.0"),
])
def test_a_bad_parameter_is_named_with_its_range(fields, message):
    with pytest.raises(ValueError) as info:
        Channel(**fields).check()
    assert str(info.value).startswith(message), str(info.value)


def test_the_line_refuses_a_period_off_the_grid_and_a_timeout_beyond_the_buffers():
    with pytest.raises(ValueError, match=re.escape(
            "period = 0.015 is not allowed: must be a multiple of the communication step "
            "0.01")):
        ChannelLine(Channel(period=0.015), 1, H, [0.0])
    with pytest.raises(ValueError, match=re.escape(
            "max_delay = 100000.0 is not allowed: must be at most 1000000 steps")):
        ChannelLine(Channel(max_delay=1e5), 1, H, [0.0])
    # the bound named as what it is: delay + jitter of a uniform channel, a trace's largest
    with pytest.raises(ValueError, match=re.escape(
            "delay + jitter = 100000.5 is not allowed: must be at most 1000000 steps")):
        ChannelLine(Channel(delay=0.5, distribution="uniform", jitter=1e5), 1, H, [0.0])
    with pytest.raises(ValueError, match=re.escape(
            "the trace's largest delay = 20000.0 is not allowed: must be at most 1000000")):
        ChannelLine(Channel(distribution="trace", trace=(0.1, 2e4)), 1, H, [0.0])
