"""The channel batch's compiled draws (``delaycomp.studies.channel_kernel``,
``fmus/native/fates.c``) against numpy's (``delaycomp.maths.channel_batch.shown``).

Both compute the same integers from the same doubles: the draws of ``draws.c`` (which the
channel FMU uses, held to the scalar Python code by tests/test_channel_fmu.py), the delays
in numpy's order of operations, compiled without fused multiply-add. So the packets shown
must be equal **exactly**, for every distribution, loss model, policy, period and
sampling stride; and a batch run must not depend on which draws it used.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from delaycomp.maths import channel_batch as cb
from delaycomp.maths.channel import Channel
from delaycomp.studies import batch, channel_kernel

DELAYS = {
    "constant": {"distribution": "constant", "delay": 0.07},
    "uniform": {"distribution": "uniform", "delay": 0.03, "jitter": 0.2},
    "uniform-on-grid": {"distribution": "uniform", "delay": 0.05, "jitter": 0.0},
    "exponential": {"distribution": "exponential", "delay": 0.02, "jitter": 0.05,
                    "max_delay": 0.3},
    "gamma<1": {"distribution": "gamma", "delay": 0.01, "jitter": 0.08, "shape": 0.6,
                "max_delay": 0.4},
    "gamma>1": {"distribution": "gamma", "delay": 0.01, "jitter": 0.08, "shape": 3.5,
                "max_delay": 0.25},
    "trace": {"distribution": "trace",
              "trace": (0.04, 0.21, float("nan"), 0.12, 0.5, 0.0, 0.33)},
}
LOSSES = {
    "none": {"loss_model": "none"},
    "bernoulli": {"loss_model": "bernoulli", "loss": 0.3},
    "gilbert_elliott": {"loss_model": "gilbert_elliott", "p_gb": 0.2, "p_bg": 0.3,
                        "loss_good": 0.05, "loss_bad": 0.7},
}
POLICIES = ("in_order", "drop_stale", "playout")


def test_the_kernel_is_compiled_here():
    # the tests' machines have the C compiler the native FMUs need
    assert channel_kernel.status().startswith("compiled C"), channel_kernel.status()


@pytest.mark.parametrize("delay,loss,policy",
                         list(itertools.product(DELAYS, LOSSES, POLICIES)))
def test_the_compiled_draws_are_numpys(delay, loss, policy):
    for period, every in ((0.0, 1), (0.0, 10), (0.03, 1), (0.03, 7)):
        ch = Channel(**DELAYS[delay], **LOSSES[loss], policy=policy, period=period)
        seeds = np.arange(150) * 101 + 3
        want = cb.shown(ch, seeds, 0.01, 301, every=every)
        got = channel_kernel.shown(ch, seeds, 0.01, 301, every)
        assert got is not None
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want, err_msg=f"period {period}, every {every}")
        assert (want >= 0).any()  # packets got through


def test_edge_sizes():
    ch = Channel(distribution="uniform", delay=0.03, jitter=0.2, loss_model="bernoulli",
                 loss=0.3)
    for steps, every in ((0, 1), (1, 1), (2, 5), (25, 30)):
        want = cb.shown(ch, [4, 5], 0.01, steps, every=every)
        got = channel_kernel.shown(ch, [4, 5], 0.01, steps, every)
        np.testing.assert_array_equal(got, want)
    assert channel_kernel.shown(ch, np.arange(0), 0.01, 10).shape == (10, 0)
    with pytest.raises(ValueError, match=r"^every = 0 is not allowed"):
        channel_kernel.shown(ch, [1], 0.01, 10, 0)


def test_without_a_compiler_the_batch_draws_with_numpy_the_same_numbers(monkeypatch):
    ch = Channel(distribution="gamma", delay=0.01, jitter=0.08, shape=2.0, max_delay=0.3,
                 loss_model="gilbert_elliott", p_gb=0.2, p_bg=0.3, loss_bad=0.6)
    P = 6
    d = batch.take(_example(), np.zeros(P, dtype=np.int64))

    def run():
        return batch.run_lti_channels(d, 6.0, meas=ch, inp=ch, meas_seeds=np.arange(P),
                                      input_seeds=np.arange(P) + 50, record=True)

    fast = run()  # the compiled draws

    def fail():
        raise OSError("the compiler failed: cc: not found")

    monkeypatch.setattr(channel_kernel, "_build", fail)
    monkeypatch.setattr(channel_kernel, "_STATUS", None)
    monkeypatch.setattr(channel_kernel, "_LIB", None)
    assert channel_kernel.shown(ch, [1], 0.01, 10) is None
    assert channel_kernel.status() == ("numpy (the compiled draws are not available: the "
                                       "compiler failed: cc: not found)")
    slow = run()
    for f in ("rho", "final_norm", "peak_norm", "cost", "states", "inputs"):
        np.testing.assert_array_equal(getattr(fast, f), getattr(slow, f), err_msg=f)
    assert np.isfinite(fast.cost).all()


def _example():
    from delaycomp.system import LtiBatch

    return LtiBatch(A=np.array([[[0.0, 1.0], [0.0, 0.0]]]), B=np.array([[[0.0], [1.0]]]),
                    K=np.array([[[-1.0, -1.6]]]), T=np.array([0.2]), N=np.array([20]),
                    r=np.array([0.1]), tau=np.array([0.2]), x0=np.array([[1.0, 0.0]]),
                    u0=np.array([[0.0]]), mode=np.array(["compensated"]),
                    r_true=np.array([0.1]), tau_true=np.array([0.2]))
