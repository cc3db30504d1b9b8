"""The channel's draws and deliveries for many seeds at once (``channel_batch``) against the
scalar code (``delaycomp.maths.channel``), bit for bit: every draw, every distribution's
delay (gamma's rejection loop included), both loss models, a trace's offset, and the packet
``ChannelLine`` shows at every step under each policy, with and without a period."""

from __future__ import annotations

import math

import numpy as np
import pytest

from delaycomp.maths import channel as ch
from delaycomp.maths import channel_batch as cb
from delaycomp.maths.channel import Channel, ChannelLine

SEEDS = [0, 1, 2, 3, 7, 11, 12345, ch.SEED_MAX, 2**31 - 2, 99991]


def test_keys_and_draws_are_the_scalar_ones_bit_for_bit():
    keys = cb.stream_keys(SEEDS)
    assert [int(k) for k in keys] == [ch.stream_key(s) for s in SEEDS]
    j = np.arange(300)
    for i in range(6):
        got = cb.packet_draws(keys[None, :], j[:, None], i)
        want = np.array([[ch.packet_draw(ch.stream_key(s), jj, i) for s in SEEDS]
                         for jj in j.tolist()])
        assert np.array_equal(got, want), i
    assert np.array_equal(cb.draws(keys, 0), [ch.draw(ch.stream_key(s), 0) for s in SEEDS])
    # the whole 64-bit range wraps as the scalar code's mask does
    big = np.array([2**64 - 1, 2**63, 0x9E3779B97F4A7C15], dtype=np.uint64)
    assert [int(v) for v in cb.mix(big)] == [ch.mix(int(v)) for v in big]


@pytest.mark.parametrize("shape", [0.3, 1.0, 2.5, 9.0])
def test_gamma_draws_are_the_scalar_rejection_loops(shape):
    keys = cb.stream_keys(range(40))
    j = np.arange(60)
    got = cb.gamma_draws(keys[None, :], j[:, None], shape)
    want = np.array([[ch.gamma_draw(ch.stream_key(s), jj, shape) for s in range(40)]
                     for jj in j.tolist()])
    assert np.array_equal(got, want)


CHANNELS = {
    "constant": Channel(delay=0.05),
    "uniform": Channel(delay=0.02, distribution="uniform", jitter=0.13),
    "exponential": Channel(delay=0.01, distribution="exponential", jitter=0.05,
                           max_delay=0.2),
    "gamma": Channel(delay=0.0, distribution="gamma", jitter=0.06, shape=0.7, max_delay=0.25),
    "gamma2": Channel(delay=0.03, distribution="gamma", jitter=0.04, shape=3.0,
                      max_delay=0.12),
    "trace": Channel(delay=0.01, distribution="trace",
                     trace=(0.01, 0.05, math.nan, 0.031, 0.2, 0.02, 0.07)),
}
LOSS = {"none": {}, "bernoulli": {"loss_model": "bernoulli", "loss": 0.3},
        "gilbert_elliott": {"loss_model": "gilbert_elliott", "p_gb": 0.2, "p_bg": 0.4,
                            "loss_good": 0.05, "loss_bad": 0.8}}


@pytest.mark.parametrize("dist", list(CHANNELS))
def test_delays_and_offsets_are_the_scalar_ones(dist):
    c = CHANNELS[dist]
    keys = cb.stream_keys(range(30))
    off = cb.offsets(c, keys)
    assert off.tolist() == [Channel(**{**c.__dict__, "seed": s}).offset() for s in range(30)]
    j = np.arange(100)
    got = cb.delays(c, keys[None, :], j[:, None], off[None, :])
    want = np.array([[c.delay_of(ch.stream_key(s), jj, int(off[s])) for s in range(30)]
                     for jj in j.tolist()])
    assert np.array_equal(got, want, equal_nan=True)


@pytest.mark.parametrize("loss", list(LOSS))
def test_losses_are_the_scalar_chains(loss):
    c = Channel(**LOSS[loss])
    got = cb.losses(c, cb.stream_keys(range(25)), 200)
    for s in range(25):
        key, bad = ch.stream_key(s), False
        for j in range(200):
            lost, _, bad = c.draw_fate(key, j, bad)
            assert got[j, s] == lost, (s, j)


def _line_shows(c: Channel, seed: int, h: float, steps: int) -> list[int]:
    """The send step of the value ``ChannelLine`` shows at each step (the values carried
    are the step numbers; the history is -1)."""
    line = ChannelLine(Channel(**{**c.__dict__, "seed": seed}), 1, h, [-1.0])
    return [int(line.step([float(k)])[0][0]) for k in range(steps)]


@pytest.mark.parametrize("policy", ch.POLICIES)
@pytest.mark.parametrize("loss", list(LOSS))
@pytest.mark.parametrize("dist", list(CHANNELS))
def test_the_packet_shown_is_channel_lines(dist, loss, policy):
    h, steps, seeds = 0.01, 150, list(range(8))
    c = Channel(**{**CHANNELS[dist].__dict__, **LOSS[loss], "policy": policy})
    got = cb.shown(c, seeds, h, steps)
    for r, s in enumerate(seeds):
        assert got[:, r].tolist() == _line_shows(c, s, h, steps), s
    stamps = cb.stamps(c, got, h)
    line = ChannelLine(c, 1, h, [0.0])
    assert stamps[:, 0].tolist() == [line.step([0.0])[1] for _ in range(steps)]


@pytest.mark.parametrize("policy", ch.POLICIES)
def test_a_period_sends_every_p_steps(policy):
    c = Channel(delay=0.0, distribution="uniform", jitter=0.05, period=0.03, policy=policy,
                loss_model="bernoulli", loss=0.2)
    got = cb.shown(c, [3, 4, 5], 0.01, 120)
    assert set(np.unique(got[got >= 0]) % 3) == {0}
    for r, s in enumerate([3, 4, 5]):
        assert got[:, r].tolist() == _line_shows(c, s, 0.01, 120)


@pytest.mark.parametrize("policy", ch.POLICIES)
def test_every_gives_the_rows_a_sampler_reads(policy):
    c = Channel(delay=0.01, distribution="uniform", jitter=0.3, policy=policy,
                loss_model="bernoulli", loss=0.4)
    full = cb.shown(c, range(50), 0.01, 301)
    for every in (1, 7, 100, 400):
        assert np.array_equal(cb.shown(c, range(50), 0.01, 301, every=every), full[::every])
    with pytest.raises(ValueError, match="every = 0 is not allowed: must be an integer >= 1"):
        cb.shown(c, [0], 0.01, 10, every=0)


@pytest.mark.parametrize("p", [0.0, 0.3, 0.5, 2.0 ** -53, 1.0 - 2.0 ** -53, 1.0])
def test_bernoulli_loss_in_integers_is_the_draw_below_p(p):
    keys = cb.stream_keys(range(20))[None, :]
    j = np.arange(500)[:, None]
    assert np.array_equal(cb._below(keys, j, ch.DRAW_LOSS, p),
                          cb.packet_draws(keys, j, ch.DRAW_LOSS) < p)
