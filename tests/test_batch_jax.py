"""The batch engine on another array library: JAX on the CPU (the ``jax`` extra, part of
``test``). Proves that the non-numpy path of ``delaycomp.studies.batch`` computes what numpy
computes; on a GPU the same code runs on CuPy or JAX (``bench/batch.py`` measures it).

JAX runs here eagerly in float64: every ufunc is the same IEEE operation as numpy's, so the
trajectories agree to the LTI bound of tests/test_batch.py (1e-12 relative to the run's
scale; measured bit-equal)."""

from __future__ import annotations

import numpy as np

from delaycomp.studies import batch, sweep
from delaycomp.studies.axes import parse_grid
from delaycomp.studies.sweep import SweepOptions

from .test_batch import LTI_REL, assert_close, assert_same


def test_jax_backend_is_usable_and_double_precision():
    be = batch.get_backend("jax")
    assert be.name == "jax"
    assert be.to_numpy(be.xp.asarray([1.0]) / 3.0).dtype == np.float64


def test_jax_trajectories_and_metrics_equal_numpy():
    """Per-point gains, delays (one not a whole period, one with a true input delay) and
    both modes, on a short grid (eager JAX dispatches every operation)."""
    k = np.array([0.5, 2.0, 3.0, 2.0, 2.0, 2.0])
    args = dict(A=[[1.0]], B=[[1.0]], K=-k.reshape(-1, 1, 1), T=1.0, N=20,
                r=np.array([0.0, 0.35, 0.95, 0.3, 1.4, 0.3]), tau=0.0, x0=[1.0], u0=[0.2],
                mode=["uncompensated"] * 3 + ["compensated"] * 3, stop=6.0,
                tau_true=np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.25]), record=True)
    ref = batch.simulate_lti(**args, backend="numpy")
    got = batch.simulate_lti(**args, backend="jax")
    for p in range(len(k)):
        assert_close(got.states[p], ref.states[p], LTI_REL)
        assert_close(got.inputs[p], ref.inputs[p], LTI_REL)
    for b, s in zip(got.rows(), ref.rows()):
        assert_same(b, s, LTI_REL)


def test_sweep_on_jax_says_so_and_equals_numpy():
    axes = [parse_grid("k=1:3:2"), parse_grid("r=0:0.5:2")]
    notes: list[str] = []
    rows = sweep.run_sweep("example-3.6", axes, ["N=10"],
                           SweepOptions(stop=4.0, engine="batch", array_backend="jax"), notes=notes)
    assert any(n.startswith("batch engine (jax, ") for n in notes), notes
    ref = sweep.run_sweep("example-3.6", axes, ["N=10"], SweepOptions(stop=4.0, engine="batch"))
    for b, s in zip(rows, ref):
        assert_same(b, s, LTI_REL)


def test_jax_equals_numpy_for_a_chain_of_integrators():
    """n = 3 (the general path, where the block ring is written once a block), per-point
    measurement and input delays (whole and not whole periods), both modes."""
    from delaycomp.maths.predictors import deadbeat_gain

    T, N = 0.5, 10
    args = dict(A=np.eye(3, k=1), B=np.eye(3)[:, -1:], K=deadbeat_gain(3, T), T=T, N=N,
                r=np.array([0.0, 0.2, 0.65, 0.3]), tau=np.array([0.0, 0.5, 0.0, 1.0]),
                x0=[1.0, -1.0, 0.5], u0=[0.1],
                mode=["compensated", "compensated", "uncompensated", "compensated"],
                r_true=np.array([0.0, 0.25, 0.65, 0.3]), stop=6.0, record=True)
    ref = batch.simulate_lti(**args, backend="numpy")
    got = batch.simulate_lti(**args, backend="jax")
    for p in range(4):
        assert_close(got.states[p], ref.states[p], LTI_REL)
        assert_close(got.inputs[p], ref.inputs[p], LTI_REL)
    for b, s in zip(got.rows(), ref.rows()):
        assert_same(b, s, LTI_REL)
