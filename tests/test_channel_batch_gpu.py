"""The channel batch on another array library (issue 29 item 4: "on a GPU whenever a GPU
is available; on the CPU always"): ``run_lti_channels(backend="cupy")`` and
``channel_batch.shown(xp=cupy)`` against numpy.

Every step of the channel batch is an elementwise IEEE operation (``+ - * /``, ``sqrt``,
``floor``, comparisons), integer arithmetic modulo 2^64 or an index, each correctly rounded
or exact on a GPU as on the CPU (CuPy runs each ufunc as its own kernel: no fused
multiply-add across calls), and the draws that need libm (exponential, gamma) are made on
the host: so the GPU gives numpy's numbers **bit for bit**, which is what the GPU tests
assert (``assert_array_equal``), for every distribution, loss model and policy, with and
without time stamps, ``n = 1`` and ``n = 3, m = 2``.

The GPU tests need CuPy and an NVIDIA GPU; where either is missing they are skipped with
the reason (the CPU machines of CI). The code paths a non-numpy library takes (the
device arrays, the host draws and the copies back) are run on the CPU always through
``_Shim``: numpy under another module's name, so every ``xp is np`` test takes the
other branch; its numbers must be numpy's to the bit as well.
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from delaycomp.cli import main
from delaycomp.maths import channel_batch as cb
from delaycomp.maths.channel import Channel
from delaycomp.studies import batch
from delaycomp.studies.batch import channels as batch_channels  # reads its get_backend
from delaycomp.system import LtiBatch

from .external import need

FIELDS = ("rho", "stable", "final_norm", "peak_norm", "deadbeat_time", "success", "cost")

#: the channels of the cases: every distribution, loss model and policy
CHANNELS = {
    "uniform+bernoulli": Channel(distribution="uniform", delay=0.3, jitter=0.5,
                                 loss_model="bernoulli", loss=0.3),
    "gamma+ge+stale": Channel(distribution="gamma", delay=0.1, jitter=0.2, shape=0.7,
                              max_delay=0.9, loss_model="gilbert_elliott", p_gb=0.1,
                              p_bg=0.4, loss_good=0.05, loss_bad=0.6, policy="drop_stale"),
    "exponential+playout": Channel(distribution="exponential", delay=0.05, jitter=0.1,
                                   max_delay=0.5, loss_model="bernoulli", loss=0.1,
                                   policy="playout", period=0.04),
    "trace": Channel(distribution="trace", trace=(0.1, 0.35, float("nan"), 0.2, 0.6, 0.05),
                     loss_model="none"),
}


def _shim() -> batch.Backend:
    """numpy under another name (its ``asnumpy`` an identity): a non-numpy backend's code
    paths, on the CPU."""
    xp = types.ModuleType("numpy_as_another_library")
    xp.__dict__.update({k: getattr(np, k) for k in dir(np) if not k.startswith("__")})
    xp.asnumpy = np.asarray  # type: ignore[attr-defined]
    return batch.Backend("cupy", xp, "cpu (numpy under another name)")


def _gpu() -> batch.Backend:
    return need("gpu", lambda: batch.get_backend("cupy"), (batch.BatchError,),
                "the cupy backend")


def _design(P: int, n: int, m: int, T: float = 0.2, N: int = 20, r: float = 0.3,
            tau: float = 0.2, seed: int = 0) -> LtiBatch:
    """``P`` loops, each with its own plant and gain near a stable design (rng-drawn),
    half compensated, half not."""
    rng = np.random.default_rng(seed)
    A = rng.normal(0.0, 0.4, (P, n, n))
    B = rng.normal(0.0, 1.0, (P, n, m))
    K = -0.3 * np.swapaxes(B, 1, 2) + rng.normal(0.0, 0.05, (P, m, n))
    mode = np.array(["compensated", "uncompensated"] * (P // 2) + ["compensated"] * (P % 2))
    return LtiBatch(A=A, B=B, K=K, T=np.full(P, T), N=np.full(P, N, dtype=np.int64),
                    r=np.full(P, r), tau=np.full(P, tau), x0=rng.normal(0.0, 1.0, (P, n)),
                    u0=rng.normal(0.0, 0.1, (P, m)), mode=mode, r_true=np.full(P, r),
                    tau_true=np.full(P, tau))


CASES = [  # (n, m, meas, input, stamps)
    (1, 1, "uniform+bernoulli", None, False),
    (1, 1, "uniform+bernoulli", None, True),
    (3, 2, "gamma+ge+stale", "exponential+playout", False),
    (3, 2, "trace", "uniform+bernoulli", True),
    (2, 1, None, "gamma+ge+stale", False),
]


def _run(case, backend, record=False, chunk=None):
    n, m, meas, inp, stamps = case
    d = _design(7, n, m, seed=n * 10 + m)
    return batch.run_lti_channels(
        d, 4.0, meas=None if meas is None else CHANNELS[meas],
        inp=None if inp is None else CHANNELS[inp], meas_seeds=np.arange(7) * 3 + 1,
        input_seeds=np.arange(7) + 100, stamps=stamps, record=record, chunk=chunk,
        backend=backend)


def _same(a: batch.BatchResult, b: batch.BatchResult) -> None:
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    assert a.message == b.message


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"n{c[0]}m{c[1]}-{c[2]}-{c[3]}-{c[4]}")
def test_the_non_numpy_path_gives_numpys_numbers_on_the_cpu(case):
    want = _run(case, "numpy", record=True)
    got = _run(case, _shim(), record=True, chunk=3)
    _same(want, got)
    np.testing.assert_array_equal(want.states, got.states)
    np.testing.assert_array_equal(want.inputs, got.inputs)
    assert np.all(np.isfinite(want.cost)) and want.cost.min() > 0  # the runs ran


@pytest.mark.parametrize("name", sorted(CHANNELS))
@pytest.mark.parametrize("every", [1, 20])
def test_shown_through_the_shim_is_numpys(name, every):
    ch = CHANNELS[name]
    want = cb.shown(ch, np.arange(50), 0.01, 301, every=every)
    got = cb.shown(ch, np.arange(50), 0.01, 301, every=every, xp=_shim().xp)
    np.testing.assert_array_equal(want, got)
    assert (want >= 0).any() and (want < 0).any()  # histories and deliveries both shown


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"n{c[0]}m{c[1]}-{c[2]}-{c[3]}-{c[4]}")
def test_the_gpu_gives_numpys_numbers_bit_for_bit(case):
    gpu = _gpu()
    want = _run(case, "numpy", record=True)
    got = _run(case, gpu, record=True)
    _same(want, got)
    np.testing.assert_array_equal(want.states, got.states)
    np.testing.assert_array_equal(want.inputs, got.inputs)


@pytest.mark.parametrize("name", sorted(CHANNELS))
def test_the_gpu_draws_what_numpy_draws(name):
    gpu = _gpu()
    ch = CHANNELS[name]
    seeds = np.arange(2000) * 7919
    want = cb.shown(ch, seeds, 0.01, 1001)
    got = gpu.to_numpy(cb.shown(ch, seeds, 0.01, 1001, xp=gpu.xp))
    np.testing.assert_array_equal(want, got)


def test_a_large_batch_on_the_gpu_chunks_in_device_memory():
    """Example 3.6 through a jittery, lossy channel, 300 000 runs (two GPU chunks at the
    default budget when an input channel doubles the memory a run takes): the same
    numbers as numpy on a sample of them."""
    gpu = _gpu()
    P = 300_000
    d = _design(P, 1, 1, T=1.0, N=100, r=0.3, tau=0.0)
    ch = Channel(distribution="uniform", delay=0.3, jitter=2.0, loss_model="bernoulli",
                 loss=0.3)
    got = batch.run_lti_channels(d, 20.0, meas=ch, inp=CHANNELS["uniform+bernoulli"],
                                 meas_seeds=np.arange(P), input_seeds=np.arange(P) + P,
                                 backend=gpu)
    pick = np.arange(0, P, 997)
    want = batch.run_lti_channels(batch.take(d, pick), 20.0, meas=ch,
                                  inp=CHANNELS["uniform+bernoulli"], meas_seeds=pick,
                                  input_seeds=pick + P)
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(got, f)[pick], getattr(want, f), err_msg=f)


def test_jax_is_refused_in_one_line_and_auto_falls_back_to_numpy(monkeypatch):
    with pytest.raises(batch.BatchError, match=r"^array backend jax is not allowed with a "
                       r"network channel: must be numpy, cupy or auto"):
        batch.channel_backend("jax")
    monkeypatch.setattr(batch_channels, "get_backend", _no_cupy(batch.get_backend))
    assert batch.channel_backend("auto").name == "numpy"


def _no_cupy(get_backend):
    def get(name="numpy"):
        if name == "cupy":
            raise batch.BatchError("array backend cupy is not installed: pip install "
                                   "'delaycomp[cupy]' (CUDA 12; needs an NVIDIA GPU)")
        return get_backend(name)
    return get


def test_the_command_without_cupy_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(batch_channels, "get_backend", _no_cupy(batch.get_backend))
    from delaycomp.paper.scenarios import loop_file

    rc = main(["robustness", str(loop_file("example-3.6")), "--jitter", "0:0.2:2",
               "--loss", "0:0:1", "--runs", "2", "--array-backend", "cupy",
               "--out", str(tmp_path / "m.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert err == ["delaycomp: error: array backend cupy is not installed: pip install "
                   "'delaycomp[cupy]' (CUDA 12; needs an NVIDIA GPU)"]
    assert not (tmp_path / "m.csv").exists()
