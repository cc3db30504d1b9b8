"""Many closed loops at once: the sampled-data loop advanced for a batch of points.

A maths module (numpy/scipy; no FMI, no scenario): it takes the loops as validated
batches of points (``delaycomp.system.LtiBatch`` for LTI loops, ``ModelBatch``
for a model's), arrays with one entry per point, and advances every point together on
the base grid, tick by tick, vectorized over the points. It computes what the per-point
engine (the master stepping the slaves) computes, in the same order, so the sweep's
metrics come out the same:

1. at tick ``k`` (time ``(k // N) T + (k % N) h``, ``h = T / N``) the controller reads
   ``y_k = x_{k - Dr}`` (``x0`` before ``t = 0``; ``Dr = r_true / h``) and, at a sampling
   tick, computes its output; the input delay hands the plant ``v_k = u_{k - Dtau}``
   (``u0`` before ``t = 0``);
2. the tick is recorded (the metrics below are streamed, nothing per tick is kept unless
   ``record=True``);
3. the plant steps from ``t_k`` to ``t_{k+1}`` under ``v_k``.

Per-point delays and periods enter as integer ticks and per-point ring buffers: a ring of
past states for the measurement delay and a ring of controller outputs (one per period
under zero-order hold, one per tick under continuous input) for the predictor's window and
the input delay. Points with different ``N`` run in separate groups; within a group the
ticks are common and ``T`` (hence ``h``), ``r``, ``tau`` differ freely.

- ``run_lti`` (an ``LtiBatch``; ``simulate_lti`` takes loose arrays):
  ``x' = A x + B u``, exactly discretized (per-point matrices, one matrix exponential per
  distinct ``(A, B, h)``), the zero-order-hold controller of
  Theorem 3.2 with the closed-form predictor of Corollary 3.4 (``compensated``) or
  ``u = K y`` (``uncompensated``). Any array library with numpy's API (numpy, CuPy, JAX)
  through ``get_backend``.
- ``run_model`` (a model, its parameters and a ``ModelBatch``; ``simulate_model``
  takes loose arrays): a model (``delaycomp.maths.model``) that declares ``BATCH = True``
  and has an exact ``step``: its ``f``, ``k`` and ``step`` accept a batch (states of shape
  ``(n, P)``). Zero-order hold (Theorem 3.2, with Remark 3.3(b) padding) and continuous
  input (Theorem 2.1, the controller's copy ``z`` integrated on the base grid and reset to
  ``Phi`` at every sample after the first). ``Phi`` is the composition of exact steps over
  the stored window (the per-point engine's closed forms compose the same exact flows).
  numpy only.

Each engine splits its bookkeeping (a group's plan: integer ticks, maps and checks; the
metrics; the failures; the record) from its stepping (``_LtiStepper``,
``_ModelStepper``: the maths of one tick or one period).

Failures follow the per-point engine: a control that is not finite (from a finite
measurement) refuses the tick (not recorded), a plant state that is not finite after a
step ends the run after the last recorded tick; the point then has ``rho = inf`` (the loop
diverged: every failure of this engine says so, as the per-point engine's components do).

Metrics (the sweep's, ``delaycomp.studies.sweep``): ``rho`` from a least-squares line through
the logarithm of the per-period root-sum-square of ``|x|`` after the first fifth of the
periods, ``stable``, ``final_norm``, ``peak_norm``, ``deadbeat_time`` (the time from which
``|x| < 1e-9`` holds to the end; ``nan`` if never).

The modules: ``.lti``, ``.model`` and ``.channels``, one engine each; ``.base``, what they
share (``BatchError``, ``BatchResult``, the grid arithmetic, the points of a batch);
``.backends``, the array libraries; ``.metrics``, the metrics streamed from the ticks.
Every name below is importable from here (``from delaycomp.studies import batch;
batch.run_lti(...)``).
"""

from delaycomp.studies.batch.backends import BACKENDS, Backend, get_backend
from delaycomp.studies.batch.base import BatchError, BatchResult, ModelBatch, take
from delaycomp.studies.batch.channels import (
    CHANNEL_CHUNK,
    GPU_CHANNEL_BYTES,
    GPU_CHANNEL_CHUNK_MAX,
    STAMP_SNAP,
    channel_backend,
    run_lti_channels,
)
from delaycomp.studies.batch.lti import run_lti, simulate_lti
from delaycomp.studies.batch.model import batchable, run_model, simulate_model
from delaycomp.studies.metrics import ZERO

__all__ = [
    "BACKENDS",
    "CHANNEL_CHUNK",
    "GPU_CHANNEL_BYTES",
    "GPU_CHANNEL_CHUNK_MAX",
    "STAMP_SNAP",
    "ZERO",
    "Backend",
    "BatchError",
    "BatchResult",
    "ModelBatch",
    "batchable",
    "channel_backend",
    "get_backend",
    "run_lti",
    "run_lti_channels",
    "run_model",
    "simulate_lti",
    "simulate_model",
    "take",
]
