"""The batch engine with a network channel in a delay's place (``run_lti_channels``, issue
29 item 4) against the in-process per-point runs (``ChannelLine`` in the delay's place)
with the same seeds.

The batch steps the same doubles in the same order as the per-point slaves: the plant's
``Ad x + Bd v``, the controller's ``K (E y + sum QB u)``, the channel's fates drawn from the
same counters. For ``n = m = 1`` (Example 3.6) that is the same trajectory bit for bit
(no BLAS kernel in a scalar product, as ``tests/test_batch.py`` measures for the constant
delay); for ``n = 2`` the per-point engine's matrix products may sum in another order, so
the states are held to ``REL`` of the run's scale (a few ulps a step, over 600 steps).
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from delaycomp import api
from delaycomp.maths.channel import Channel
from delaycomp.paper.scenarios import loop_file
from delaycomp.studies import batch
from delaycomp.studies.sweep_batch import lti_point
from delaycomp.system import lti_designs
from delaycomp.system.loopfile import build, channel_of

#: n = 2 with 600 steps: 1e-12 of the run's scale is ~4500 ulps, far above the round-off
#: of a reordered 2-term sum per step (2 ulps a step, growing at most linearly while the
#: loop is stable) and far below any effect of one wrong packet (~1e-3)
REL = 1e-12

EX36 = {"meas_delay": {"distribution": "uniform", "jitter": 0.4, "loss_model": "bernoulli",
                       "loss": 0.2},
        "input_delay": {"distribution": "exponential", "jitter": 0.2, "max_delay": 0.9,
                        "loss_model": "gilbert_elliott", "p_gb": 0.1, "p_bg": 0.5,
                        "policy": "drop_stale"}}
DBL = {"name": "dbl", "T": 0.2, "N": 20, "r": 0.36, "tau": 0.4, "stop_time": 6.0,
       "plant": {"A": [[0.0, 1.0], [0.0, 0.0]], "B": [[0.0], [1.0]], "x0": [1.0, 0.0]},
       "controller": {"K": [[-1.0, -1.6]]}}
DBL_NET = {"meas_delay": {"distribution": "gamma", "jitter": 0.1, "shape": 2.0,
                          "max_delay": 0.8, "loss_model": "bernoulli", "loss": 0.3},
           "input_delay": {"distribution": "uniform", "jitter": 0.25, "period": 0.04,
                           "policy": "playout"}}


try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib


def _ex36(**over) -> dict:
    data = tomllib.loads(Path(loop_file("example-3.6")).read_text())
    data.update(over)
    return data


def _compare(data: dict, tables: dict, seeds: list[tuple[int, int]], stop: float,
             modes=("compensated", "uncompensated"), rel: float = 0.0, stamps: bool = False):
    base = Path.cwd()
    worst = 0.0
    for mode in modes:
        d = copy.deepcopy(data)
        d["controller"] = {**d["controller"], "mode": mode}
        plain = build(d, base, name="p")
        if stamps:
            d["controller"]["stamps"] = True
        design = lti_designs([lti_point(plain)] * len(seeds))
        loop_r = plain.lti.r_true if plain.lti.r_true is not None else plain.lti.r
        loop_t = plain.lti.tau_true if plain.lti.tau_true is not None else plain.lti.tau
        meas = channel_of(tables["meas_delay"], "meas_delay", base, loop_r)
        inp = channel_of(tables["input_delay"], "input_delay", base, loop_t)
        res = batch.run_lti_channels(design, stop, meas=meas, inp=inp,
                                     meas_seeds=[a for a, _ in seeds],
                                     input_seeds=[b for _, b in seeds], record=True,
                                     stamps=stamps)
        n = design.A.shape[1]
        for p, (sm, si) in enumerate(seeds):
            t = copy.deepcopy(tables)
            t["meas_delay"]["seed"], t["input_delay"]["seed"] = sm, si
            loop = build({**d, **t}, base, name="c")
            ref = api.run(loop, engine="inprocess", stop_time=stop)
            xs, us = ref.data[:, :n], ref.data[:, n:]
            assert res.states is not None and res.inputs is not None
            got_x, got_u = res.states[p, :len(xs)], res.inputs[p, :len(xs)]
            scale = np.maximum(1.0, np.maximum.accumulate(np.abs(xs).max(axis=1)))
            err = max(float(np.max(np.abs(got_x - xs).max(axis=1) / scale)),
                      float(np.max(np.abs(got_u - us).max(axis=1) / scale)))
            worst = max(worst, err)
            assert err <= rel, (mode, sm, si, err)
    return worst


def test_example_3_6_with_jitter_and_loss_is_the_per_point_run_bit_for_bit():
    seeds = [(0, 100), (1, 101), (7, 3), (12345, 2**31 - 1)]
    assert _compare(_ex36(), EX36, seeds, 20.0) == 0.0


def test_the_double_integrator_through_two_channels_is_the_per_point_run():
    _compare(DBL, DBL_NET, [(3, 4), (11, 5)], 6.0, rel=REL)


def test_time_stamps_are_the_per_point_stamped_controller():
    """``stamps=True`` against the loop with ``[controller] stamps = true``: the same
    pieces and decisions, but the batch's flows are those of ``k h`` where the controller
    takes the exponential of a difference of times (``t_{j+1} + tau - s``, a few ulps off
    ``k h``): a relative change of ~1e-16 in each flow, carried through a stable loop over
    at most a few hundred pieces, so ``REL`` (1e-12) bounds it with room (~1e-14 measured);
    one sample used or not wrongly would change the state by ~1e-3. Uncompensated, the
    controller is ``K y`` as without stamps: bit for bit."""
    _compare(_ex36(), EX36, [(0, 100), (1, 101), (7, 3)], 20.0, modes=("compensated",),
             rel=REL, stamps=True)
    _compare(_ex36(), EX36, [(0, 100)], 20.0, modes=("uncompensated",), stamps=True)
    _compare(DBL, DBL_NET, [(3, 4), (11, 5)], 6.0, modes=("compensated",), rel=REL,
             stamps=True)
    from delaycomp.maths import stamped

    assert batch.STAMP_SNAP == stamped.SNAP  # the same decisions near age_max


def test_time_stamps_in_the_batch_are_exact_for_every_seed():
    """The property of ``tests/test_loop_stamps.py`` over many seeds at once: the README's
    loop (n = 3, m = 2) with uniform jitter 2 T and 30 % loss on the measurement and a
    play-out buffer on the commands; with stamps the plant at ``t_i + tau`` follows the
    delay-free sampled loop ``x_{i+1} = (e^{AT} + G(T) K) x_i`` (scipy alone here) to
    round-off (1e-12 of the state's size, the per-point test's bound), without them not."""
    from scipy.linalg import expm

    base = Path(__file__).resolve().parents[1] / "docs" / "examples"
    MYLOOP = tomllib.loads((base / "myloop.toml").read_text("utf-8"))
    NETWORK = {"meas_delay": {"distribution": "uniform", "jitter": 0.4,
                              "loss_model": "bernoulli", "loss": 0.3},
               "input_delay": {"distribution": "uniform", "delay": 0.2, "jitter": 0.2,
                               "policy": "playout"}}
    loop = build(copy.deepcopy(MYLOOP), base, name="myloop")
    seeds = list(range(40))
    design = lti_designs([lti_point(loop)] * len(seeds))
    meas = channel_of(NETWORK["meas_delay"], "meas_delay", base, loop.lti.r)
    inp = channel_of(NETWORK["input_delay"], "input_delay", base, loop.lti.tau)
    A, B = np.array(MYLOOP["plant"]["A"], float), np.array(MYLOOP["plant"]["B"], float)
    K = np.array(MYLOOP["controller"]["K"], float)
    T, tau, N = MYLOOP["T"], MYLOOP["tau"], MYLOOP["N"]
    n, m = B.shape
    F = expm(np.block([[A, B], [np.zeros((m, n + m))]]) * T)
    M = F[:n, :n] + F[:n, n:] @ K
    stop = float(MYLOOP["stop_time"])
    worst = {}
    for stamps in (True, False):
        res = batch.run_lti_channels(design, stop, meas=meas, inp=inp, meas_seeds=seeds,
                                     input_seeds=[s + 1000 for s in seeds], record=True,
                                     stamps=stamps)
        assert res.states is not None
        x = res.states
        at = np.arange(round(tau / T) * N, x.shape[1], N)
        step = np.abs(x[:, at[1:]] - np.einsum("ab,pkb->pka", M, x[:, at[:-1]])).max(axis=(1, 2))
        worst[stamps] = step / np.abs(x).max(axis=(1, 2))
    assert worst[True].max() <= 1e-12, worst[True].max()
    assert worst[False].min() >= 1e-3, worst[False].min()


def test_the_channels_act_and_the_seeds_fix_them():
    d = build(_ex36(), Path.cwd(), name="p")
    design = lti_designs([lti_point(d)] * 3)
    meas = Channel(delay=0.3, distribution="uniform", jitter=0.5, loss_model="bernoulli",
                   loss=0.3)
    a = batch.run_lti_channels(design, 20.0, meas=meas, meas_seeds=[1, 2, 1], record=True)
    plain = batch.run_lti(design, 20.0, record=True)
    assert a.states is not None and plain.states is not None and a.cost is not None
    assert np.array_equal(a.states[0], a.states[2])
    assert not np.array_equal(a.states[0], a.states[1])
    assert not np.array_equal(a.states[0], plain.states[0])
    # without channels it is run_lti's loop, bit for bit, and its metrics
    none = batch.run_lti_channels(design, 20.0, record=True)
    assert np.array_equal(none.states, plain.states)
    for name in ("rho", "stable", "final_norm", "peak_norm", "deadbeat_time"):
        assert np.array_equal(getattr(none, name), getattr(plain, name), equal_nan=True)
    # the cost: the rectangle rule of x'x + v'v over the ticks before stop (tau = 0: the
    # plant's input is the controller's output); summed in another order here, so equal
    # to 2000 additions' round-off (2000 eps ~ 4.4e-13)
    x, u = plain.states[0, :-1, 0], plain.inputs[0, :-1, 0]
    assert none.cost is not None
    assert none.cost[0] == pytest.approx(np.sum(0.01 * (x * x + u * u)), rel=1e-12, abs=0)


def test_refusals_are_one_line():
    d = build(_ex36(), Path.cwd(), name="p")
    design = lti_designs([lti_point(d)])
    with pytest.raises(batch.BatchError, match="meas channel: jitter"):
        batch.run_lti_channels(design, 5.0, meas=Channel(distribution="uniform", jitter=-1))
    with pytest.raises(batch.BatchError, match="meas_seeds"):
        batch.run_lti_channels(design, 5.0, meas=Channel(), meas_seeds=[-1])
    with pytest.raises(batch.BatchError, match="age_max is not allowed without stamps"):
        batch.run_lti_channels(design, 5.0, age_max=1.0)
    with pytest.raises(batch.BatchError, match=r"age_max = -1.0 is not allowed: must be a "
                                               r"finite number >= 0"):
        batch.run_lti_channels(design, 5.0, stamps=True, age_max=-1.0)
