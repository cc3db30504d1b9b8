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
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, TypeVar, cast

import numpy as np

from delaycomp.errors import DelaycompError, is_divergence
from delaycomp.maths.grid import on_grid_array
from delaycomp.maths.grid import periods as zoh_periods
from delaycomp.maths.lti import MODES, LTIPredictor, discretize
from delaycomp.maths.nlcontrol import padded_delay
from delaycomp.maths.stamped import SNAP
from delaycomp.studies.metrics import ZERO, tail_start
from delaycomp.system import LtiBatch

#: Array libraries ``get_backend`` knows; ``auto`` takes the first GPU library found.
BACKENDS = ("numpy", "cupy", "jax", "auto")


class BatchError(DelaycompError, ValueError):
    """A batch ingredient is out of range or inconsistent (one-line message)."""


# -- array libraries --------------------------------------------------------------------

@dataclass(frozen=True)
class Backend:
    """An array library with numpy's API: its namespace, conversions, in-place update."""

    name: str
    #: the array module (``numpy``, ``cupy`` or ``jax.numpy``): ``Any``, as the three share
    #: numpy's API but no common static type
    xp: Any
    device: str

    def asarray(self, a):
        """``a`` as an array of this library (on its device)."""
        return self.xp.asarray(a)

    def to_numpy(self, a) -> np.ndarray:
        """``a`` (an array of this library) as a numpy array on the host."""
        if self.name == "cupy":
            return self.xp.asnumpy(a)
        return np.asarray(a)

    def put(self, a, index, value):
        """``a[index] = value``, returning the array (JAX arrays are immutable)."""
        if self.name == "jax":
            return a.at[index].set(value)
        a[index] = value
        return a


def get_backend(name: str = "numpy") -> Backend:
    """The array library ``name`` (one of ``BACKENDS``), checked to be usable.

    ``jax`` runs in double precision (``jax_enable_x64`` is switched on: the maths needs
    float64). ``auto`` is CuPy if it sees a GPU, else JAX if it sees one, else numpy.
    Raises ``BatchError`` naming what is missing.
    """
    if name not in BACKENDS:
        raise BatchError(f"array backend {name!r} is not allowed: must be one of "
                         f"{', '.join(BACKENDS)}")
    if name == "numpy":
        return Backend("numpy", np, "cpu")
    if name == "auto":
        for candidate in ("cupy", "jax"):
            try:
                backend = get_backend(candidate)
            except BatchError:
                continue
            if backend.device != "cpu":
                return backend
        return Backend("numpy", np, "cpu")
    if name == "cupy":
        try:
            import cupy
        except ImportError:
            raise BatchError("array backend cupy is not installed: pip install "
                             "'delaycomp[cupy]' (CUDA 12; needs an NVIDIA GPU)") from None
        try:
            count = cupy.cuda.runtime.getDeviceCount()
        except Exception as exc:  # noqa: BLE001 - no driver, no device: say so in one line
            raise BatchError(f"array backend cupy cannot reach a GPU: {exc}") from None
        if count < 1:
            raise BatchError("array backend cupy cannot reach a GPU: no device")
        props = cupy.cuda.runtime.getDeviceProperties(0)
        label = props["name"].decode() if isinstance(props["name"], bytes) else props["name"]
        return Backend("cupy", cupy, f"gpu ({label})")
    try:
        import jax
    except ImportError:
        raise BatchError("array backend jax is not installed: pip install "
                         "'delaycomp[jax]'") from None
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    dev = jax.devices()[0]
    return Backend("jax", jnp, "cpu" if dev.platform == "cpu" else f"{dev.platform} ({dev})")


# -- results ----------------------------------------------------------------------------

@dataclass
class BatchResult:
    """Per-point metrics (arrays of length P, in input order) and optional trajectories.

    ``deadbeat_time`` is ``nan`` where ``|x|`` never stays below ``ZERO`` (and where the
    run failed); ``success`` is False where a component would have refused (``message``
    then says why). With ``record=True``: ``states[p, k]`` is ``x`` of point ``p`` at tick
    ``k`` and ``inputs[p, k]`` the controller's output (``nan`` after a point's end).
    """

    rho: np.ndarray
    stable: np.ndarray
    final_norm: np.ndarray
    peak_norm: np.ndarray
    deadbeat_time: np.ndarray
    success: np.ndarray
    message: list[str] = field(default_factory=list)
    states: np.ndarray | None = None
    inputs: np.ndarray | None = None
    #: ``run_lti_channels``: the quadratic cost ``sum_k h (|x_k|^2 + |v_k|^2)`` per point
    cost: np.ndarray | None = None

    def rows(self) -> list[dict]:
        """One dict per point with the sweep's metric columns (``None`` for never;
        ``failed`` the message of a point that did not reach its stop time: every failure
        of this engine is the loop's own divergence, ``delaycomp.errors.is_divergence``)."""
        deadbeat = [None if math.isnan(d) else d for d in np.asarray(
            self.deadbeat_time, dtype=float).tolist()]
        # tolist() gives Python floats and ints at once (a float() per value is 10x slower)
        rows = [{"rho": a, "stable": b, "final_norm": c, "peak_norm": d, "deadbeat_time": e,
                 "failed": ""}
                for a, b, c, d, e in zip(np.asarray(self.rho, dtype=float).tolist(),
                                         np.asarray(self.stable).astype(int).tolist(),
                                         np.asarray(self.final_norm, dtype=float).tolist(),
                                         np.asarray(self.peak_norm, dtype=float).tolist(),
                                         deadbeat)]
        for p in np.flatnonzero(~np.asarray(self.success, dtype=bool)).tolist():
            why = self.message[p] if p < len(self.message) else ""
            rows[p]["failed"] = why or "the run failed"
            if not is_divergence(why):  # not ours to call unstable
                rows[p]["rho"] = rows[p]["stable"] = None
        return rows

    def without_trajectories(self) -> BatchResult:
        """The metrics alone (what a worker sends back: arrays pickle fast, dicts do not)."""
        return BatchResult(self.rho, self.stable, self.final_norm, self.peak_norm,
                           self.deadbeat_time, self.success, self.message)


def _merge(parts: list[tuple[np.ndarray, BatchResult]], P: int) -> BatchResult:
    """Results of groups (each with the input indices it covers) back in input order."""
    if len(parts) == 1 and np.array_equal(parts[0][0], np.arange(P)):
        return parts[0][1]
    first = parts[0][1]
    out = {}
    for name in ("rho", "stable", "final_norm", "peak_norm", "deadbeat_time", "success"):
        arr = np.empty(P, dtype=getattr(first, name).dtype)
        for idx, res in parts:
            arr[idx] = getattr(res, name)
        out[name] = arr
    message = [""] * P
    for idx, res in parts:
        for j, i in enumerate(idx):
            message[i] = res.message[j]
    states = inputs = None
    if first.states is not None:
        # every group ran with the same ``record``: all of them hold both trajectories
        assert first.inputs is not None
        K = max(cast(np.ndarray, r.states).shape[1] for _, r in parts)
        states = np.full((P, K, first.states.shape[2]), np.nan)
        inputs = np.full((P, K, first.inputs.shape[2]), np.nan)
        for idx, res in parts:
            assert res.states is not None and res.inputs is not None
            states[idx, :res.states.shape[1]] = res.states
            inputs[idx, :res.inputs.shape[1]] = res.inputs
    cost = None
    if first.cost is not None:
        cost = np.empty(P)
        for idx, res in parts:
            cost[idx] = res.cost
    return BatchResult(**out, message=message, states=states, inputs=inputs, cost=cost)


# -- grid arithmetic --------------------------------------------------------------------

def _ticks(name: str, value: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``value / h`` as integers; ``BatchError`` if some point is off the base grid."""
    ratio = np.asarray(value, dtype=float) / h
    steps = np.rint(ratio)
    bad = ~on_grid_array(value, h)
    if np.any(bad) or np.any(ratio < 0):
        p = int(np.flatnonzero(bad | (ratio < 0))[0])
        raise BatchError(f"{name} = {float(np.ravel(value)[p])!r} (point {p}) is not allowed: "
                         f"must be a multiple >= 0 of the base step h = {float(h[p])!r}")
    return steps.astype(np.int64)


def _per_point(value, P: int, shape: tuple, name: str) -> np.ndarray:
    """``value`` broadcast to ``(P, *shape)`` as floats."""
    a = np.asarray(value, dtype=float)
    if a.shape == () and shape == (1,):
        a = a.reshape(1)
    if a.shape == shape:
        return np.broadcast_to(a, (P, *shape)).copy()
    if a.shape == (P, *shape):
        return a.copy()
    if shape == () and a.size == P:
        return a.reshape(P).copy()
    raise BatchError(f"{name} has shape {a.shape}: must be {shape} or {(P, *shape)}")


class _Metrics:
    """The sweep's metrics streamed tick by tick (host numpy or the backend's arrays)."""

    def __init__(self, xp, P: int, N: int, ticks: np.ndarray, periods_max: int):
        self.xp, self.P, self.N = xp, P, N
        self.ticks = ticks  # numpy, per point
        self.uniform = bool(np.all(ticks == ticks[0]))
        self.ticks_dev = xp.asarray(ticks)
        self.peak = xp.zeros(P)
        self.final = xp.zeros(P)
        self.last_above = xp.full(P, -1, dtype=xp.int64)
        self.envsq = xp.zeros((max(periods_max, 1), P))
        self.periods_max = periods_max

    def record(self, k: int, norm, put) -> None:
        xp = self.xp
        if not self.uniform:
            norm = xp.where(k <= self.ticks_dev, norm, 0.0)
            self.final = xp.where(k == self.ticks_dev, norm, self.final)
        elif k == int(self.ticks[0]):
            self.final = norm
        self.peak = xp.maximum(self.peak, norm)
        self.last_above = xp.where(norm < ZERO, self.last_above, k)
        j = k // self.N
        if j < self.periods_max:
            self.envsq = put(self.envsq, j, self.envsq[j] + norm * norm)


def _finish(metrics: _Metrics, backend: Backend, failed: np.ndarray, fail_norm: np.ndarray,
            fail_peak: np.ndarray, T: np.ndarray, h: np.ndarray, N: int,
            messages: list[str]) -> BatchResult:
    """Metrics per point from the streamed sums (on the host)."""
    to = backend.to_numpy
    peak, final = to(metrics.peak).copy(), to(metrics.final).copy()
    last = to(metrics.last_above)
    envsq = to(metrics.envsq)
    ticks = metrics.ticks
    peak[failed] = fail_peak[failed]
    final[failed] = fail_norm[failed]
    # deadbeat: the time of the tick after the last one with |x| >= ZERO
    nxt = last + 1
    db = (nxt // N) * T + (nxt % N) * h
    db = np.where(last < 0, 0.0, np.where(last < ticks, db, np.nan))
    rho = _rates(envsq, ticks // N)
    bad = failed | ~np.isfinite(peak)
    rho[bad] = np.inf
    db[bad] = np.nan
    stable = (rho < 1.0).astype(np.int64)
    return BatchResult(rho, stable, final, peak, db, ~bad, messages)


# -- the points of a batch --------------------------------------------------------------

@dataclass(frozen=True)
class ModelBatch:
    """Many loops of one model at once: each point's timing and constant histories, arrays
    with a leading axis of points. What ``run_model`` takes; ``simulate_model``
    gathers its loose per-point arguments into one (broadcast and checked: ``T > 0``,
    delays finite and ``>= 0``, ``N >= 1``; ``r_true`` and ``tau_true`` filled in with
    ``r`` and ``tau`` where not given). The timing fields of
    ``delaycomp.system.LtiBatch``, in its order."""

    T: np.ndarray  # (P,)
    N: np.ndarray  # (P,) int64
    r: np.ndarray
    tau: np.ndarray
    r_true: np.ndarray
    tau_true: np.ndarray
    x0: np.ndarray  # (P, n): also the controller's initial copy z (continuous input)
    u0: np.ndarray  # (P, m)

    def __len__(self) -> int:
        return len(self.T)


_Points = TypeVar("_Points", bound="LtiBatch | ModelBatch")


def take(points: _Points, index) -> _Points:
    """The points ``index`` (an index array, a slice or a mask) of an
    ``LtiBatch`` or a ``ModelBatch``: every field indexed on
    its leading axis (a group of points, a chunk)."""
    return type(points)(*(getattr(points, f.name)[index]
                          for f in dataclasses.fields(points)))


def _points(P: int, n: int, m: int, T, r, tau, N, r_true, tau_true, x0, u0) -> ModelBatch:
    """Timing and histories per point, broadcast and checked: ``T > 0``, delays ``>= 0``
    and finite, ``N >= 1``; the true delays default to the assumed ones."""
    T = _per_point(T, P, (), "T")
    r = _per_point(r, P, (), "r")
    tau = _per_point(tau, P, (), "tau")
    r_true = r if r_true is None else _per_point(r_true, P, (), "r_true")
    tau_true = tau if tau_true is None else _per_point(tau_true, P, (), "tau_true")
    x0 = _per_point(x0, P, (n,), "x0")
    u0 = _per_point(u0, P, (m,), "u0")
    Ns = np.broadcast_to(np.asarray(N), (P,)).astype(np.int64)
    for name, v in (("T", T), ("r", r), ("tau", tau), ("r_true", r_true),
                    ("tau_true", tau_true)):
        if not np.all(np.isfinite(v)) or np.any(v < 0) or (name == "T" and np.any(v <= 0)):
            raise BatchError(f"{name} is not allowed: must be finite and "
                             f"{'> 0' if name == 'T' else '>= 0'} at every point")
    if np.any(Ns < 1):
        raise BatchError("N is not allowed: must be a positive integer at every point")
    return ModelBatch(T, Ns, r, tau, r_true, tau_true, x0, u0)


def _count(matrices, scalars, vectors, mode=None) -> int:
    """Number of points: the leading axis of any per-point ingredient (1 if none)."""
    found = [np.shape(a)[0] for a in matrices if np.ndim(a) == 3]
    found += [np.size(v) for v in scalars if v is not None and np.ndim(v) >= 1]
    found += [np.shape(v)[0] for v in vectors if np.ndim(v) == 2]
    if mode is not None and not isinstance(mode, str):
        found.append(len(mode))
    if len(set(found)) > 1:
        raise BatchError(f"the per-point ingredients disagree on the number of points: "
                         f"{sorted(set(found))}")
    return int(found[0]) if found else 1


def _unique_rows(*arrays) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the first occurrence of each distinct row, and the inverse map."""
    key = np.concatenate([np.ascontiguousarray(a).reshape(len(a), -1) for a in arrays],
                         axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


def _trim(states, inputs, end: np.ndarray):
    """Recorded trajectories with the ticks from ``end[p]`` on of each point ``p`` set to
    ``nan`` (``None`` stays ``None``)."""
    if states is not None:
        for p, e in enumerate(end.tolist()):
            states[p, e:] = np.nan
            inputs[p, e:] = np.nan
    return states, inputs


# -- LTI loops --------------------------------------------------------------------------

def simulate_lti(A, B, K, T, N, r, tau, x0, u0, mode, stop: float, r_true=None,
                 tau_true=None, *, record: bool = False,
                 backend: Backend | str = "numpy") -> BatchResult:
    """Advance ``P`` LTI loops of Theorem 3.2 / Corollary 3.4 together to ``stop``.

    A convenience over ``run_lti`` for loose arrays: the ingredients are broadcast
    over the points (shared matrices and scalars to every point), checked (shapes, finite
    timing; ``BatchError``) and stacked into a ``delaycomp.system.LtiBatch``.

    Parameters
    ----------
    A, B, K : array_like
        ``(n, n)``, ``(n, m)``, ``(m, n)`` shared by every point, or with a leading axis of
        length ``P``. ``u = K x`` (the paper's sign).
    T, r, tau : float or array_like
        Sampling period, and the delays the controller assumes; ``tau`` a multiple of
        ``T``; ``r``, ``tau`` multiples of ``h = T / N``.
    N : int or array_like of int
        Base steps per period; points with different ``N`` run as separate groups.
    x0, u0 : array_like
        Constant histories of ``x`` on ``[-r, 0]`` and of ``u`` on ``[-r - tau, 0)``.
    mode : str or sequence of str
        ``compensated`` (``u = K Phi``) or ``uncompensated`` (``u = K y``), per point.
    stop : float
        Stop time, a multiple of every point's ``h``.
    r_true, tau_true : float or array_like, optional
        The loop's delays (default: the assumed ones), multiples of ``h``.
    record : bool
        Keep every tick's state and control (memory ``P x ticks``; for tests and plots).
    backend : Backend or str
        Array library (``get_backend``).

    Returns
    -------
    BatchResult

    Examples
    --------
    Shared ``A``, ``B``, ``T``, ``N``; a gain and a delay per point:

    >>> res = simulate_lti([[1.0]], [[1.0]], [[[-2.0]], [[-1.5]]], 1.0, 100, [0.0, 0.3],
    ...                    0.0, [1.0], [0.0], "compensated", 10.0)
    >>> res.stable.tolist()
    [1, 1]
    """
    be = backend if isinstance(backend, Backend) else get_backend(backend)
    A = np.asarray(A, dtype=float)
    P = _count([A, B, K], [T, r, tau, N, r_true, tau_true], [x0, u0], mode)
    n = A.shape[-1]
    m = np.asarray(B, dtype=float).shape[-1]
    A = _per_point(A, P, (n, n), "A")
    B = _per_point(B, P, (n, m), "B")
    K = _per_point(K, P, (m, n), "K")
    t = _points(P, n, m, T, r, tau, N, r_true, tau_true, x0, u0)
    modes = np.broadcast_to(np.asarray(mode, dtype=object), (P,)).copy()
    design = LtiBatch(A, B, K, t.T, t.N, t.r, t.tau, t.r_true, t.tau_true, t.x0, t.u0, modes)
    return run_lti(design, stop, record=record, backend=be)


def run_lti(design: LtiBatch, stop: float, *, record: bool = False,
            backend: Backend | str = "numpy") -> BatchResult:
    """Advance the ``P`` LTI loops of ``design`` together to ``stop`` (Theorem 3.2 with the
    closed-form predictor of Corollary 3.4, or ``u = K y``): the batch engine's core.

    ``design`` is a validated ``delaycomp.system.LtiBatch`` (from
    ``delaycomp.system.lti_designs``, a scenario's or a loop file's ``designs``, or
    ``simulate_lti``), one entry per point; points with different ``N`` run as
    separate groups (``take``), within a group ``T``, the delays and the matrices
    differ freely. ``stop`` is a multiple of every point's ``h = T / N``; ``record`` keeps
    every tick's state and control; ``backend`` is the array library
    (``get_backend``). Raises ``BatchError`` where a mode, a delay or ``stop``
    is not allowed at some point, or a predictor overflows.

    Examples
    --------
    >>> from delaycomp.system import lti_designs
    >>> pts = [dict(A=[[1.0]], B=[[1.0]], K=[[-k]], T=1.0, r=0.3, tau=0.0, N=100,
    ...             mode="compensated", x0=[1.0], u0=[0.0]) for k in (0.5, 2.0, 3.5)]
    >>> run_lti(lti_designs(pts), 20.0).stable.tolist()
    [0, 1, 0]
    """
    be = backend if isinstance(backend, Backend) else get_backend(backend)
    bad = [md for md in set(design.mode.tolist()) if md not in MODES]
    if bad:
        raise BatchError(f"mode = {bad[0]!r} is not allowed: must be one of {', '.join(MODES)}")
    parts = []
    for Nv in np.unique(design.N):
        idx = np.flatnonzero(design.N == Nv)
        parts.append((idx, _lti_group(be, take(design, idx), int(Nv), float(stop), record)))
    return _merge(parts, len(design))


@dataclass(frozen=True)
class _LtiPlan:
    """One LTI group on the host, checked: its integer ticks, the exact discretization
    and the predictor ``Phi = E y + sum_q QB[q] u_{i-q-1}`` (Corollary 3.4) per point."""

    N: int
    T: np.ndarray
    h: np.ndarray
    stop_k: np.ndarray  # the last tick, per point
    Dr: np.ndarray  # the true measurement delay, in ticks
    Dt: np.ndarray  # the true input delay, in ticks
    Ad: np.ndarray  # (P, n, n): e^(A h)
    Bd: np.ndarray  # (P, n, m)
    E: np.ndarray  # (P, n, n)
    QB: np.ndarray  # (Lmax, P, n, m)


def _lti_plan(d: LtiBatch, N: int, stop: float) -> _LtiPlan:
    """The plan of the group ``d`` (every point with ``N`` base steps a period), or a
    ``BatchError`` naming the first point off the grid."""
    P = len(d)
    T = d.T
    h = T / N
    stop_k = _ticks("stop", np.full(P, stop), h)
    _ticks("r", d.r, h)
    Dr = _ticks("r_true", d.r_true, h)
    Dt = _ticks("tau_true", d.tau_true, h)
    for p in _unique_rows(d.tau, T)[0]:
        try:
            zoh_periods(float(d.tau[p]), float(T[p]), hints=True)
        except ValueError as exc:
            raise BatchError(f"{exc} (point {p})") from None
    # exact discretization, once per distinct (A, B, h)
    first, inv = _unique_rows(d.A, d.B, h)
    Ad_u, Bd_u = zip(*(discretize(d.A[i], d.B[i], float(h[i])) for i in first))
    E, QB = _predictors(d, d.mode == "compensated")
    return _LtiPlan(N, T, h, stop_k, Dr, Dt, np.stack(Ad_u)[inv], np.stack(Bd_u)[inv], E, QB)


def _predictors(d: LtiBatch, comp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``E`` (P, n, n) and ``QB`` (Lmax, P, n, m) of the points' predictors, once per
    distinct ``(A, B, T, r, tau)``; an uncompensated point has ``E = I``, ``QB = 0``,
    hence ``u = K y``. ``BatchError`` where a predictor is not finite."""
    A, B, T, r, tau = d.A, d.B, d.T, d.r, d.tau
    P, n, m = B.shape
    L = np.ones(P, dtype=np.int64)
    E = np.broadcast_to(np.eye(n), (P, n, n)).copy()
    cidx = np.flatnonzero(comp)
    preds = {}
    if cidx.size:
        f2, inv2 = _unique_rows(A[cidx], B[cidx], T[cidx], r[cidx], tau[cidx])
        for j, i in enumerate(f2):
            p = cidx[i]
            preds[j] = LTIPredictor(A[p], B[p], float(T[p]), float(r[p]), float(tau[p]))
        for j, p in enumerate(cidx):
            pr = preds[inv2[j]]
            L[p] = pr.L
            E[p] = pr.E
    QB = np.zeros((int(L.max()), P, n, m))
    for j, p in enumerate(cidx):
        pr = preds[inv2[j]]
        for q in range(pr.L):
            QB[q, p] = pr.QB[q]
    if not (np.all(np.isfinite(E)) and np.all(np.isfinite(QB))):
        p = int(np.flatnonzero(~(np.isfinite(E).all(axis=(1, 2))
                                 & np.isfinite(QB).all(axis=(0, 2, 3))))[0])
        raise BatchError(f"A = {A[p].tolist()} (point {p}) is not allowed: must keep the "
                         f"predictor e^(A (r + tau)) finite for r + tau = "
                         f"{float(r[p] + tau[p])!r} (it overflows)")
    return E, QB


def _lti_group(be: Backend, d: LtiBatch, N: int, stop: float, record: bool) -> BatchResult:
    """The points of ``d`` (every one with ``N`` base steps a period) to ``stop``: the
    bookkeeping (plan, metrics a block at a time, the record's end) around the stepping
    of ``_LtiStepper``."""
    plan = _lti_plan(d, N, stop)
    run = _LtiStepper(be, plan, d, record)
    acc = _BlockMetrics(be, len(d), N, plan.stop_k, int((plan.stop_k // N).max()))
    with np.errstate(all="ignore"):  # overflow is detected per block, as the FMUs refuse
        run.start()
        for i in range(run.kmax // N + 1):
            bad = run.sample(i)
            if bool(run.xp.any(bad)):
                acc.cut(be.to_numpy(bad), i * N, "the control is not finite (the feedback "
                        "diverged: overflow)", plan.T, plan.h)
            run.hold(i)
            rows = run.advance(i)
            acc.block(run.xb[i % run.nb, :rows], i * N, plan.T, plan.h)
    res = acc.finish(plan.T, plan.h)
    res.states, res.inputs = _trim(run.states, run.inputs,
                                   np.minimum(acc.cut_at, plan.stop_k + 1))
    return res


def _coefficients(plan: _LtiPlan, d: LtiBatch, col, Lmax: int) -> tuple:
    """A stepper's per-point coefficients, entry by entry, each ``col`` of its ``(P,)``
    column (contiguous, on the stepper's device): ``(Ad, Bd, K, E, QB, x0, u0)``, ``QB``
    the predictor's first ``Lmax`` blocks."""
    n, m = plan.Bd.shape[1:]
    return ([[col(plan.Ad[:, a, b]) for b in range(n)] for a in range(n)],
            [[col(plan.Bd[:, a, c]) for c in range(m)] for a in range(n)],
            [[col(d.K[:, c, a]) for a in range(n)] for c in range(m)],
            [[col(plan.E[:, a, b]) for b in range(n)] for a in range(n)],
            [[[col(plan.QB[q, :, a, c]) for c in range(m)] for a in range(n)]
             for q in range(Lmax)],
            col(d.x0.T), col(d.u0.T))


class _LtiStepper:
    """The stepping of one LTI group (the maths), on the backend's arrays, the points on
    the last axis: the controller at each sampling tick, the plant's exact step each tick.

    The states of the last ``nb`` periods are kept in blocks of ``N`` ticks,
    ``xb[b, row]`` (the measurement delay's ring); the controller outputs one per period,
    ``U`` (the predictor's window and the input delay's ring).
    """

    def __init__(self, be: Backend, plan: _LtiPlan, d: LtiBatch, record: bool):
        xp, dev = be.xp, be.asarray
        P, n, m = d.B.shape
        N = plan.N
        self.be, self.xp, self.plan, self.N, self.n, self.m = be, xp, plan, N, n, m
        self.kmax = int(plan.stop_k.max())
        self.Lmax = plan.QB.shape[0]
        self.nb = int(plan.Dr.max()) // N + 2  # blocks of N ticks kept for the measurement
        self.Ru = max(self.Lmax, int(plan.Dt.max()) // N + 1) + 2
        self.is_np = be.name == "numpy"
        self.scalar = self.is_np and n == 1  # the hot path: two ufunc calls a tick

        def col(a):  # a per-point coefficient as a contiguous (P,) array
            return dev(np.ascontiguousarray(a))

        self.Ad, self.Bd, self.K, self.E, self.QB, self.x0, self.u0 = _coefficients(
            plan, d, col, self.Lmax)
        self.pidx = dev(np.arange(P))
        self.Dr_uniform = bool(np.all(plan.Dr == plan.Dr[0]))
        self.Dt_uniform = bool(np.all(plan.Dt == plan.Dt[0]))
        self.Dr_d = dev(plan.Dr)
        self.xb = xp.zeros((self.nb, N, n, P))  # states of the last nb blocks of N ticks
        self.U = xp.zeros((self.Ru, m, P))  # controller outputs, one per period
        self.x = [self.x0[a] for a in range(n)]
        self.v = self.held = self.u0
        self.tmp = np.empty(P) if self.is_np else None
        self.states = np.full((P, self.kmax + 1, n), np.nan) if record else None
        self.inputs = np.full((P, self.kmax + 1, m), np.nan) if record else None
        # the plant input changes at the ticks k with (k - Dt) % N == 0: rows Dt % N
        self.change_rows = {int(c) for c in np.unique(plan.Dt % N)}
        self.Dt_rows = plan.Dt % N
        self.bv = self.forced(self.v)

    def start(self) -> None:
        """Tick 0's state into the ring."""
        for a in range(self.n):
            self.xb = self.be.put(self.xb, (0, 0, a), self.x[a])

    def forced(self, v) -> list:
        """``Bd v``, per state component."""
        return [_dot(self.Bd[a], v) for a in range(self.n)]

    def sample(self, i: int):
        """The controller at the sampling tick ``i N``: ``held = K Phi(y)``, ``y`` the
        state ``Dr`` ticks before; returns where it is not finite from a finite ``y``."""
        xp, N, n, k0, bi = self.xp, self.N, self.n, i * self.N, i % self.nb
        if not self.is_np and i > 0:  # row 0 of this block: the last step's result
            self.xb = self.be.put(self.xb, (bi, 0), xp.stack(self.x))
        xb, U, u0 = self.xb, self.U, self.u0
        if self.Dr_uniform:
            src = k0 - int(self.plan.Dr[0])
            y = xb[(src // N) % self.nb, src % N] if src >= 0 else self.x0
        else:
            src = k0 - self.Dr_d
            y = xp.where(src >= 0, xb[(src // N) % self.nb, src % N, :, self.pidx].T,
                         self.x0)
        phi = [_dot(self.E[a], y) for a in range(n)]
        for q in range(self.Lmax):
            past = U[(i - q - 1) % self.Ru] if i - q - 1 >= 0 else u0
            for a in range(n):
                phi[a] = phi[a] + _dot(self.QB[q][a], past)
        self.held = xp.stack([_dot(self.K[c], phi) for c in range(self.m)])
        return ~xp.all(xp.isfinite(self.held), axis=0) & xp.all(xp.isfinite(y), axis=0)

    def hold(self, i: int) -> None:
        """The controller output of period ``i`` into its ring."""
        self.U = self.be.put(self.U, i % self.Ru, self.held)

    def plant_input(self, k: int, row: int, v):
        """``v`` at tick ``k``: the controller output of tick ``k - Dt``."""
        if row not in self.change_rows:
            return v, False
        N, Dt, U, Ru = self.N, self.plan.Dt, self.U, self.Ru
        if self.Dt_uniform:
            s = k - int(Dt[0])
            return (U[(s // N) % Ru], True) if s >= 0 else (v, False)
        due = (self.Dt_rows == row) & (k - Dt >= 0)
        if not due.any():
            return v, False
        s = np.maximum(k - Dt, 0)
        dev = self.be.asarray
        return self.xp.where(dev(due), U[dev((s // N) % Ru), :, self.pidx].T, v), True

    def advance(self, i: int) -> int:
        """The plant through the ticks of period ``i`` (each recorded first, with
        ``record``), its states into block ``i % nb`` of the ring; returns their number."""
        xp, be, N, n, kmax = self.xp, self.be, self.N, self.n, self.kmax
        Ad, xb, tmp = self.Ad, self.xb, self.tmp
        k0, bi = i * N, i % self.nb
        rows = min(N, kmax - k0 + 1)
        x, v, bv = self.x, self.v, self.bv
        later = []  # other libraries: rows 1.. of this block, written once at its end
        for row in range(rows):
            k = k0 + row
            v, changed = self.plant_input(k, row, v)
            if changed:
                bv = self.forced(v)
            if self.states is not None and self.inputs is not None:
                self.states[:, k] = be.to_numpy(xp.stack(x)).T
                self.inputs[:, k] = be.to_numpy(self.held).T
            if k == kmax:
                break
            # the plant's step to tick k + 1, into its row of the block ring
            bi1, row1 = (bi, row + 1) if row + 1 < N else ((i + 1) % self.nb, 0)
            if self.scalar:  # n = 1 on numpy: the hot path, two ufunc calls a tick
                out = xb[bi1, row1, 0]
                np.multiply(Ad[0][0], x[0], out=out)
                np.add(out, bv[0], out=out)
                x = [out]
            elif self.is_np:
                assert tmp is not None  # the scratch row of numpy
                for a in range(n):
                    out = xb[bi1, row1, a]
                    np.multiply(Ad[a][0], x[0], out=out)
                    for b in range(1, n):
                        np.multiply(Ad[a][b], x[b], out=tmp)
                        np.add(out, tmp, out=out)
                    np.add(out, bv[a], out=out)
                x = [xb[bi1, row1, a] for a in range(n)]
            else:  # JAX arrays are immutable: one write a block, not one a tick
                x = [_dot(Ad[a], x) + bv[a] for a in range(n)]
                if row1:
                    later.append(xp.stack(x))
        if later:
            self.xb = be.put(xb, (bi, slice(1, 1 + len(later))), xp.stack(later))
        self.x, self.v, self.bv = x, v, bv
        return rows


class _BlockMetrics:
    """The sweep's metrics, from blocks of ticks (norms computed a block at a time).

    Per point, ticks from ``end = min(cut, ticks + 1)`` on are not recorded: ``cut`` is the
    first tick a component refused (a control that is not finite), or the first tick whose
    state is not finite (the plant's step to it failed).
    """

    def __init__(self, be: Backend, P: int, N: int, ticks: np.ndarray, periods_max: int):
        xp = be.xp
        self.be, self.xp, self.P, self.N = be, xp, P, N
        self.ticks = ticks
        self.cut_at = np.full(P, np.iinfo(np.int64).max, dtype=np.int64)
        self.messages = [""] * P
        self.peak = xp.zeros(P)
        self.final = np.full(P, np.nan)
        self.last_above = xp.full(P, -1, dtype=xp.int64)
        self.envsq = np.zeros((max(periods_max, 1), P))
        self.periods_max = periods_max
        self.prev_last = np.full(P, np.nan)  # norm of the tick before the current block

    def cut(self, mask: np.ndarray, k: int, why: str, T, h) -> None:
        """End the record of the points ``mask`` at tick ``k`` (the first not recorded),
        saying ``why``; a point already cut keeps its first cut."""
        new = mask & (self.cut_at > k)
        if not new.any():
            return
        self.cut_at[new] = k
        t = (k // self.N) * T + (k % self.N) * h
        for p in np.flatnonzero(new):
            self.messages[p] = f"{why} at t = {float(t[p])!r}"

    def block(self, xs, start: int, T, h, sq=None) -> None:
        """Rows ``xs[j]`` (shape ``(n, P)``) are the states of ticks ``start + j``
        (``sq``: their ``|x|^2``, summed over the components in order, where the caller
        has them).

        Three passes over the block in the common case (squares, their column maxima and
        sums): ``sqrt`` is monotonic, so the largest norm is the root of the largest square,
        and norms are taken only on the rows a metric reads.
        """
        xp = self.xp
        R = xs.shape[0]
        if sq is None:
            sq = _sumsq(xs)
        colmax = xp.max(sq, axis=0)
        finite = bool(xp.isfinite(xp.max(colmax)))
        if not finite:  # rare: states not finite, or |x|^2 overflow
            self._cut_diverged(xs, start, T, h)
        end = np.minimum(self.cut_at, self.ticks + 1)
        sq_in, above, last_row, need = self._peaks(sq, colmax, start, end, finite)
        self._last_above(sq, above, last_row, need, start)
        j = start // self.N
        if j < self.periods_max and R == self.N:
            self.envsq[j] = self.be.to_numpy(_rowsum(xp, sq_in))
        self._final(sq, start, end)

    def _cut_diverged(self, xs, start: int, T, h) -> None:
        """Cut each point at its first tick of the block whose state is not finite (a
        norm may overflow where the states are finite: those are not cut)."""
        xp = self.xp
        bad = ~xp.all(xp.isfinite(xs), axis=1)
        has = self.be.to_numpy(xp.any(bad, axis=0))
        first = self.be.to_numpy(xp.argmax(bad, axis=0))
        for p in np.flatnonzero(has):
            self.cut(np.arange(self.P) == p, start + int(first[p]),
                     "the plant state is not finite (the plant diverged: overflow)", T, h)

    def _peaks(self, sq, colmax, start: int, end: np.ndarray, finite: bool):
        """The peaks updated with the block's recorded rows; returns the squares of the
        recorded rows, where ``|x| >= ZERO`` (``None``: every row recorded), that on the
        last row, and the points whose last such row is to be searched."""
        xp = self.xp
        R = sq.shape[0]
        if np.any(end < start + R) or not finite:
            norms = xp.sqrt(sq)
            rows = xp.asarray(start + np.arange(R))[:, None]
            incl = rows < xp.asarray(end)[None, :]
            sq_in = xp.where(incl, sq, 0.0)
            above = incl & ~(norms < ZERO)
            self.peak = xp.maximum(self.peak, xp.max(xp.where(incl, norms, 0.0), axis=0))
            last_row = above[R - 1]
            need = self.be.to_numpy(xp.any(above, axis=0) & ~last_row)
            return sq_in, above, last_row, need
        self.peak = xp.maximum(self.peak, xp.sqrt(colmax))
        last_row = xp.sqrt(sq[R - 1]) >= ZERO
        need = self.be.to_numpy((xp.sqrt(colmax) >= ZERO) & ~last_row)
        return sq, None, last_row, need

    def _last_above(self, sq, above, last_row, need: np.ndarray, start: int) -> None:
        """The last tick with ``|x| >= ZERO``: the block's last row for most points; a
        search only where some earlier row is above and the last is not."""
        xp = self.xp
        R = sq.shape[0]
        self.last_above = xp.where(last_row, start + R - 1, self.last_above)
        if need.any():
            sel = np.flatnonzero(need)
            cols = self.be.asarray(sel)
            sub = above[:, cols] if above is not None else xp.sqrt(sq[:, cols]) >= ZERO
            last = (R - 1) - self.be.to_numpy(xp.argmax(sub[::-1], axis=0))
            host = self.be.to_numpy(self.last_above).copy()
            host[sel] = start + last
            self.last_above = self.be.asarray(host)

    def _final(self, sq, start: int, end: np.ndarray) -> None:
        """The last recorded norm of the points whose record ends in this block (or just
        before it)."""
        R = sq.shape[0]
        hit = (end - 1 >= start) & (end - 1 < start + R)
        if hit.any():
            sel = np.flatnonzero(hit)
            rows_sel = end[sel] - 1 - start
            self.final[sel] = np.sqrt(self.be.to_numpy(sq[self.be.asarray(rows_sel),
                                                          self.be.asarray(sel)]))
        at_start = end == start
        if at_start.any():
            self.final[at_start] = self.prev_last[at_start]
        self.prev_last = np.sqrt(self.be.to_numpy(sq[R - 1]))

    def finish(self, T, h) -> BatchResult:
        """The metrics per point from what the blocks streamed (on the host)."""
        to = self.be.to_numpy
        N = self.N
        peak = to(self.peak).copy()
        last = to(self.last_above)
        failed = self.cut_at <= self.ticks
        peak[failed & (self.cut_at == 0)] = np.nan  # nothing recorded
        nxt = last + 1
        db = (nxt // N) * T + (nxt % N) * h
        db = np.where(last < 0, 0.0, np.where(last < self.ticks, db, np.nan))
        rho = _rates(self.envsq, self.ticks // N)
        bad = failed | ~np.isfinite(peak)
        rho[bad] = np.inf
        db[bad] = np.nan
        stable = (rho < 1.0).astype(np.int64)
        return BatchResult(rho, stable, self.final.copy(), peak, db, ~bad,
                           list(self.messages))


def _rowsum(xp, a):
    """``sum_j a[j]`` (rows of shape ``(P,)``), added row after row: numpy's ``sum(axis=0)``
    of a C-ordered array does exactly that (its pairwise summation is for the contiguous
    axis); other libraries (a GPU's reduction trees) are given the loop, so that they sum
    in numpy's order and give its doubles."""
    if xp is np:
        return np.sum(a, axis=0)
    acc = a[0].copy()
    for j in range(1, a.shape[0]):
        acc += a[j]
    return acc


def _sumsq(xs):
    """``|x|^2`` of each row ``xs[j]`` (shape ``(n, P)``), the components added in order."""
    sq = xs[:, 0] * xs[:, 0]
    for a in range(1, xs.shape[1]):
        sq = sq + xs[:, a] * xs[:, a]
    return sq


def _rates(envsq: np.ndarray, periods: np.ndarray) -> np.ndarray:
    """``rho`` per point from the per-period sums of ``|x|^2`` (``envsq[j, p]``)."""
    P = len(periods)
    rho = np.full(P, np.nan)
    for S in np.unique(periods):
        sel = np.flatnonzero(periods == S)
        start = tail_start(int(S))
        tail = np.sqrt(envsq[start:S, sel]).T  # (points, tail length)
        if tail.shape[1] < 2:
            continue  # too few periods to estimate a rate: nan, as the per-point metric
        zero = np.any(tail == 0.0, axis=1)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            # the least-squares slope of log e_j, its sums taken period after period
            # (elementwise over the points): a point's rho depends on its own numbers
            # alone, not on how many points share the call (a matrix product's BLAS
            # kernel sums in blocks that depend on the shape)
            y = np.log(tail)
            L = tail.shape[1]
            t = np.arange(L, dtype=float)
            tc = t - t.mean()
            ybar = y[:, 0].copy()
            for j in range(1, L):
                ybar += y[:, j]
            ybar /= L
            acc = (y[:, 0] - ybar) * tc[0]
            for j in range(1, L):
                acc += (y[:, j] - ybar) * tc[j]
            slope = acc / float(np.sum(tc * tc))
            rho[sel] = np.where(zero, 0.0, np.exp(slope))
    return rho


# -- model loops ------------------------------------------------------------------------

def batchable(model) -> str | None:
    """Why ``model`` cannot run batched (``None`` if it can)."""
    if not getattr(model, "batch", False):
        return f"model {model.name} does not declare BATCH = True"
    if model.step is None:
        return f"model {model.name} has no exact step (the batch engine has no ODE solver)"
    return None


def simulate_model(model, params: dict, T, N, r, tau, x0, u0, stop: float, r_true=None,
                   tau_true=None, *, pad: bool = False, record: bool = False) -> BatchResult:
    """Advance ``P`` loops of a batchable model (``batchable``) together to ``stop``.

    A convenience over ``run_model`` for loose arrays: the per-point timing and
    histories are broadcast over the points, checked (``BatchError``) and gathered
    into one ``ModelBatch``.

    Parameters
    ----------
    model : delaycomp.maths.model.Model
        With ``BATCH = True`` and an exact ``step``.
    params : dict
        The model's parameters, shared by every point (numbers may be arrays of length P).
    T, N, r, tau, x0, u0, stop, r_true, tau_true :
        As in ``simulate_lti``; ``x0`` is also the controller's initial ``z``
        (continuous input).
    pad : bool
        Zero-order hold: pad ``tau`` up to the next multiple of ``T`` (Remark 3.3(b)).
    record : bool
        Keep every tick's state and control.

    Returns
    -------
    BatchResult
    """
    why = batchable(model)
    if why:
        raise BatchError(why)
    P = _count([], [T, r, tau, N, r_true, tau_true], [x0, u0])
    points = _points(P, model.n, model.m, T, r, tau, N, r_true, tau_true, x0, u0)
    return run_model(model, params, points, stop, pad=pad, record=record)


def run_model(model, params: dict, points: ModelBatch, stop: float, *, pad: bool = False,
              record: bool = False) -> BatchResult:
    """Advance the ``P`` loops of a batchable ``model`` (``batchable``) at ``points``
    together to ``stop``: the batch engine's core for model loops.

    ``params`` are the model's parameters, shared by every point (a number may be an array
    of length ``P``, one per point); ``points`` the checked per-point timing and histories
    (``ModelBatch``); points with different ``N`` run as separate groups. ``pad``:
    under zero-order hold, pad ``tau`` up to the next multiple of ``T`` (Remark 3.3(b));
    ``record`` keeps every tick's state and control. Raises ``BatchError`` where the
    model is not batchable or a delay or ``stop`` is not allowed at some point.
    """
    why = batchable(model)
    if why:
        raise BatchError(why)
    P = len(points)
    parts = []
    for Nv in np.unique(points.N):
        idx = np.flatnonzero(points.N == Nv)
        p_idx = {key: (np.asarray(val)[idx] if np.ndim(val) == 1 and np.size(val) == P
                       else val) for key, val in params.items()}
        res = _model_group(model, p_idx, take(points, idx), int(Nv), float(stop), pad,
                           record)
        parts.append((idx, res))
    return _merge(parts, P)


@dataclass(frozen=True)
class _ModelPlan:
    """One model group's integer ticks (host numpy), checked."""

    N: int
    T: np.ndarray
    h: np.ndarray
    stop_k: np.ndarray  # the last tick, per point
    Dr_true: np.ndarray  # the true measurement delay, in ticks
    Dpad: np.ndarray  # zero-order hold: the padding of tau (Remark 3.3(b)), in ticks
    Dt: np.ndarray  # the controller's held value -> the plant's input, in ticks
    W: np.ndarray  # the predictor's window r + tau (padded), in ticks
    Ru: int  # slots of the ring of controller outputs


def _model_plan(model, pts: ModelBatch, N: int, stop: float, pad: bool) -> _ModelPlan:
    """The plan of the group ``pts`` (every point with ``N`` base steps a period), or a
    ``BatchError`` naming what is off the grid."""
    T, tau = pts.T, pts.tau
    P = len(T)
    h = T / N
    stop_k = _ticks("stop", np.full(P, stop), h)
    Dr_true = _ticks("r_true", pts.r_true, h)
    Dt_true = _ticks("tau_true", pts.tau_true, h)
    Dr = _ticks("r", pts.r, h)
    if model.control == "zoh":
        tau_eff = np.array([padded_delay(tau[i], T[i]) for i in range(P)])
        if not pad and np.any(tau_eff != tau):
            i = int(np.flatnonzero(tau_eff != tau)[0])
            try:
                zoh_periods(float(tau[i]), float(T[i]), padding=True, hints=True)
            except ValueError as exc:
                raise BatchError(str(exc)) from None
        Dpad = _ticks("padding", tau_eff - tau, h)
        W = Dr + np.rint(tau_eff / h).astype(np.int64)
        Dt = Dt_true + Dpad
        nseg = W // N + (W % N > 0)
        Ru = max(int(nseg.max()), int(Dt.max()) // N + 1) + 2
    else:
        Dpad = np.zeros(P, dtype=np.int64)
        W = Dr + _ticks("tau", tau, h)
        Dt = Dt_true + Dpad
        Ru = max(int(W.max()), int(Dt.max())) + 2
    return _ModelPlan(N, T, h, stop_k, Dr_true, Dpad, Dt, W, Ru)


class _Failures:
    """Which points of a group failed, when and why, with their last recorded norm and
    peak (the per-point engine's record ends there)."""

    def __init__(self, P: int, N: int, T: np.ndarray, h: np.ndarray):
        self.N, self.T, self.h = N, T, h
        self.failed = np.zeros(P, dtype=bool)
        self.norm = np.zeros(P)
        self.peak = np.zeros(P)
        self.messages = [""] * P

    def mark(self, mask: np.ndarray, norms: np.ndarray, peak: np.ndarray, why: str,
             k: int) -> bool:
        """Mark the points ``mask`` failed at tick ``k`` (those not failed before keep
        ``norms`` and ``peak``); whether any is new."""
        new = mask & ~self.failed
        if not new.any():
            return False
        self.norm[new] = norms[new]
        self.peak[new] = peak[new]
        t = (k // self.N) * self.T + (k % self.N) * self.h
        for i in np.flatnonzero(new):
            self.messages[i] = f"{why} at t = {float(t[i])!r}"
        self.failed[new] = True
        return True


def _model_group(model, params: dict, pts: ModelBatch, N: int, stop: float, pad: bool,
                 record: bool) -> BatchResult:
    """The points of ``pts`` (every one with ``N`` base steps a period) to ``stop``: the
    bookkeeping (plan, metrics, failures, the record) around the stepping of
    ``_ModelStepper``."""
    plan = _model_plan(model, pts, N, stop, pad)
    P, n, m = len(pts), model.n, model.m
    run = _ModelStepper(model, {**params, "T": plan.T}, pts, plan)
    kmax = int(plan.stop_k.max())
    metrics = _Metrics(np, P, N, plan.stop_k, int((plan.stop_k // N).max()))
    failures = _Failures(P, N, plan.T, plan.h)
    states = np.full((P, kmax + 1, n), np.nan) if record else None
    inputs = np.full((P, kmax + 1, m), np.nan) if record else None
    norm_prev = np.zeros(P)

    def fail(mask, norms, why, k):
        if failures.mark(mask, norms, metrics.peak, why, k):
            run.zero(failures.failed)

    with np.errstate(all="ignore"):
        for k in range(kmax + 1):
            bad = run.control(k)
            if bad is not None and bad.any():
                fail(bad, norm_prev, "the control is not finite (the predictor or the "
                     "feedback diverged)", k)
            run.hold(k, record)
            norm = _norm(run.x)
            metrics.record(k, np.where(failures.failed, 0.0, norm), _np_put)
            if states is not None and inputs is not None:
                states[:, k] = run.x.T
                inputs[:, k] = run.out.T
                states[failures.failed, k] = np.nan
                inputs[failures.failed, k] = np.nan
            if k == kmax:
                break
            bad = run.step()
            if bad.any():
                fail(bad, norm, "the plant state is not finite (the plant diverged)", k + 1)
            norm_prev = norm
    res = _finish(metrics, get_backend("numpy"), failures.failed, failures.norm,
                  failures.peak, plan.T, plan.h, N, failures.messages)
    res.states, res.inputs = _trim(states, inputs, plan.stop_k + 1)
    return res


def _norm(x: np.ndarray) -> np.ndarray:
    """``|x|`` per point (``x`` of shape ``(n, P)``), the squares summed left to right."""
    sq = x[0] * x[0]
    for a in range(1, x.shape[0]):
        sq = sq + x[a] * x[a]
    return np.sqrt(sq)


class _ModelStepper:
    """The stepping of one model group (the maths), numpy, the points on the last axis:
    the controller at the sampling ticks (zero-order hold, Theorem 3.2, the predictor
    composing exact steps over the window) or at every tick (continuous input, Theorem
    2.1, its copy ``z`` reset to the predictor at every sample after the first), the
    plant's exact step each tick. ``U`` is the ring of controller outputs, one per period
    (zero-order hold) or per tick (continuous input)."""

    def __init__(self, model, p: dict, pts: ModelBatch, plan: _ModelPlan):
        P, n, m = len(pts), model.n, model.m
        self.model, self.p, self.plan, self.N, self.P, self.m = model, p, plan, plan.N, P, m
        self.zoh = model.control == "zoh"
        self.tau = pts.tau
        self.pidx = np.arange(P)
        self.Rx = int(plan.Dr_true.max()) + 1
        self.x0T = pts.x0.T
        self.x = pts.x0.T.copy()
        self.xring = np.zeros((self.Rx, n, P))
        self.y = self.x0T  # the controller's measurement (set at every sampling tick)
        self.u0T = pts.u0.T.copy()
        self.U = np.zeros((plan.Ru, m, P))
        self.held = self.u0T.copy()
        self.v = self.u0T.copy()
        self.out = self.u0T.copy()
        self.z = pts.x0.T.copy()  # the controller's copy of the state (continuous input)
        self.nfull, self.rem = plan.W // plan.N, plan.W % plan.N
        self.nseg = self.nfull + (self.rem > 0)

    def past(self, j: int) -> np.ndarray:
        """Controller output of slot index ``j`` (period or tick), ``u0`` before t = 0."""
        return self.U[j % self.plan.Ru] if j >= 0 else self.u0T

    def control(self, k: int) -> np.ndarray | None:
        """The controller at tick ``k`` (it measures at a sampling tick); returns where
        its output is not finite from a finite measurement (``None``: no output now)."""
        N, p, P, m = self.N, self.p, self.P, self.m
        self.xring[k % self.Rx] = self.x
        i, jj = divmod(k, N)
        if k % N == 0:
            src = k - self.plan.Dr_true
            self.y = np.where(src >= 0, self.xring[src % self.Rx, :, self.pidx].T,
                              self.x0T)
        if self.zoh:
            if k % N != 0:
                return None
            xs = self.y.copy()
            for e in range(int(self.nseg.max()), 0, -1):
                active = (e <= self.nfull) | ((e == self.nfull + 1) & (self.rem > 0))
                dur = np.where(e <= self.nfull, N * self.plan.h, self.rem * self.plan.h)
                stepped = np.asarray(self.model.step(xs, self.past(i - e), dur, p),
                                     dtype=float)
                xs = np.where(active, stepped, xs)
            self.held = np.asarray(self.model.k(xs, p), dtype=float).reshape(m, P)
        else:
            if k % N == 0 and k > 0:
                xs = self.y.copy()
                for e in range(int(self.plan.W.max()), 0, -1):
                    stepped = np.asarray(self.model.step(xs, self.past(k - e), self.plan.h,
                                                         p), dtype=float)
                    xs = np.where(e <= self.plan.W, stepped, xs)
                self.z = xs
            t = i * self.plan.T + jj * self.plan.h
            self.held = np.asarray(self.model.k(t + self.tau, self.z, p),
                                   dtype=float).reshape(m, P)
        return ~np.all(np.isfinite(self.held), axis=0) & np.all(np.isfinite(self.y), axis=0)

    def hold(self, k: int, record: bool) -> None:
        """The controller's output into its ring at tick ``k``, and the plant's input
        ``v`` through the input delay (``out``: what the controller outputs now)."""
        N, Ru, Dt, U = self.N, self.plan.Ru, self.plan.Dt, self.U
        if self.zoh:
            if k % N == 0:
                U[(k // N) % Ru] = self.held
            s = k - Dt
            due = (s >= 0) & (s % N == 0)
            if due.any():
                self.v = np.where(due, U[(s // N) % Ru, :, self.pidx].T, self.v)
            if record:
                sp = k - self.plan.Dpad
                self.out = np.where(sp >= 0, U[(sp // N) % Ru, :, self.pidx].T, self.u0T)
        else:
            U[k % Ru] = self.held
            s = k - Dt
            self.v = np.where(s >= 0, U[s % Ru, :, self.pidx].T, self.u0T)
            self.out = self.held

    def step(self) -> np.ndarray:
        """The plant (and the controller's copy) one base step on; returns where the
        plant state is not finite."""
        h, p = self.plan.h, self.p
        if not self.zoh:
            self.z = np.asarray(self.model.step(self.z, self.held, h, p), dtype=float)
        self.x = np.asarray(self.model.step(self.x, self.v, h, p), dtype=float)
        return ~np.all(np.isfinite(self.x), axis=0)

    def zero(self, failed: np.ndarray) -> None:
        """The state, outputs and rings of the ``failed`` points held at zero."""
        self.x[:, failed] = 0.0
        self.held[:, failed] = 0.0
        self.v[:, failed] = 0.0
        self.out[:, failed] = 0.0
        self.U[:, :, failed] = 0.0
        if not self.zoh:
            self.z[:, failed] = 0.0


def _dot(row, vec):
    """``sum_j row[j] * vec[j]`` over per-point arrays, left to right (no ``0 +``)."""
    acc = row[0] * vec[0]
    for j in range(1, len(row)):
        acc = acc + row[j] * vec[j]
    return acc


def _np_put(a, index, value):
    a[index] = value
    return a


# -- LTI loops through network channels -------------------------------------------------

#: how close to ``age_max`` (in ``T``) a sample's age counts as within it: the time-stamp
#: controller's own (``delaycomp.maths.stamped.SNAP``)
STAMP_SNAP = SNAP

#: ``run_lti_channels``' default chunk: points advanced together (measured in
#: ``bench/channels.py``: a few thousand keep a tick's rows and the channel's arrays of a
#: chunk in cache while the per-tick overhead of numpy's calls stays small)
CHANNEL_CHUNK = 2048
#: on a GPU (CuPy): the device memory a chunk's largest arrays may take [bytes] (the send
#: steps of an input channel, one per tick and point, and the draws of 64 packets): the
#: chunk is as many points as fit, at most ``GPU_CHANNEL_CHUNK_MAX``
GPU_CHANNEL_BYTES = 2**31
GPU_CHANNEL_CHUNK_MAX = 2**18


def _constant_shown(D: np.ndarray, steps: int, xp=np):
    """The send step a constant delay of ``D`` ticks (per point) shows at each step: ``k -
    D``, ``-1`` before ``D`` (``DelayLine``)."""
    s = xp.arange(steps, dtype=xp.int64)[:, None] - xp.asarray(D)[None, :]
    return xp.where(s >= 0, s, -1)


def channel_backend(backend: Backend | str) -> Backend:
    """The array library of ``run_lti_channels``: numpy, or CuPy on a GPU (``auto``: CuPy
    where it reaches a GPU, else numpy). JAX is refused: its arrays are immutable, and the
    channel's stepping writes into its rings in place."""
    name = backend.name if isinstance(backend, Backend) else backend
    if name == "jax":
        raise BatchError("array backend jax is not allowed with a network channel: must be "
                         "numpy, cupy or auto (the channel's stepping writes in place)")
    if isinstance(backend, Backend):
        return backend
    if name == "auto":
        try:
            return get_backend("cupy")
        except BatchError:
            return get_backend("numpy")
    return get_backend(name)


def run_lti_channels(design: LtiBatch, stop: float, *, meas=None, inp=None,
                     meas_seeds=None, input_seeds=None, record: bool = False,
                     stamps: bool = False, age_max=None, chunk: int | None = None,
                     backend: Backend | str = "numpy") -> BatchResult:
    """Advance the ``P`` LTI loops of ``design`` to ``stop`` with a network channel
    (``delaycomp.maths.channel.Channel``) in the place of the measurement delay (``meas``)
    and/or the input delay (``inp``), each point with its own seed: the loop of
    ``run_lti`` (zero-order hold, ``compensated`` or ``uncompensated``), numpy.

    The channel's fates are drawn for every point at once
    (``delaycomp.maths.channel_batch.shown``): at tick ``k`` the controller's
    measurement is the state at the send step of the packet the measurement channel shows
    (``x0`` before any), the plant's input the controller output at the send step of the
    packet the input channel shows (``u0`` before any); a role without a channel keeps the
    constant delay ``r_true`` or ``tau_true``. A packet is at most ``Q`` ticks old when
    it is delivered (``Q = steps_up(bound, h)``), so a ring of ``Q + 1`` past states and a
    latch per point hold what is needed. The arithmetic is ``run_lti``'s, in its order.

    On a GPU (``backend="cupy"``) the same steps run on CuPy's arrays, the points of a
    chunk on the device: every operation is elementwise IEEE arithmetic or integer
    indexing, so the results are numpy's bit for bit (the exponential and gamma delays,
    which need libm, are drawn on the host).

    With ``stamps=True`` the controller is the time-stamp controller
    (``delaycomp.maths.stamped.StampedController``, a loop file's ``[controller] stamps =
    true``) vectorized over the points: at ``t_i`` each point's estimate of ``x(t_i)`` is
    its sample carried from its stamp (the send tick of the packet shown; the history
    ``x0`` is the state at ``t0``) when the sample is newer than the last one used and at
    most ``age_max`` old, else its last estimate carried over ``T``; the output is ``K``
    times the estimate carried over the controller's ``tau`` (``compensated``) or ``K y``.
    The pieces of the plant's input are multiples of ``h`` long (the stamps, ``t_i`` and
    ``tau`` lie on the base grid), so their exact flows are computed once, for ``k h``,
    ``k = 0 .. N``, per distinct ``(A, B)``: no matrix exponential per run.

    Parameters
    ----------
    design : delaycomp.system.LtiBatch
        The loops; every point with the same ``T`` and ``N`` (one base step ``h``). The
        controller's ``r`` and ``tau`` are what it assumes (its predictor).
    stop : float
        Stop time, a multiple of ``h``.
    meas, inp : Channel, optional
        The channels; their ``seed`` is replaced by the points' seeds.
    meas_seeds, input_seeds : array_like of int, optional
        One seed per point (default ``0 .. P - 1``).
    record : bool
        Keep every tick's state and controller output.
    stamps : bool
        The time-stamp controller in the place of the paper's.
    age_max : float or array_like, optional
        With ``stamps``: the oldest sample used [s] (per point or one for all); default
        the measurement channel's largest delay (``Channel.bound``, else ``r_true``) plus
        ``T``, as in loop files.
    chunk : int, optional
        Points advanced together (default ``CHANNEL_CHUNK`` on the CPU; on a GPU as many
        as ``GPU_CHANNEL_BYTES`` hold): the batch runs chunk by chunk, so its per-tick
        arrays stay in the processor's cache; the results do not depend on it.
    backend : Backend or str
        The array library: ``numpy`` (default), ``cupy`` (a GPU) or ``auto`` (CuPy where
        it reaches a GPU, else numpy); ``channel_backend``.

    Returns
    -------
    BatchResult
        The sweep's metrics and ``cost``: ``sum_k h (|x_k|^2 + |v_k|^2)`` over the ticks
        before ``stop`` (``v`` the plant's input), the rectangle rule of
        ``int_0^stop x'x + v'v dt`` (``inf`` where the run failed).
    """
    from delaycomp.maths.channel_batch import period_steps, timeout_steps

    be = channel_backend(backend)
    bad = [md for md in set(design.mode.tolist()) if md not in MODES]
    if bad:
        raise BatchError(f"mode = {bad[0]!r} is not allowed: must be one of {', '.join(MODES)}")
    P = len(design)
    if P == 0:
        raise BatchError("the batch has no points")
    if not (np.all(design.N == design.N[0]) and np.all(design.T == design.T[0])):
        raise BatchError("T and N are not allowed to differ between the points of a batch "
                         "with a channel: must be the same at every point")
    N = int(design.N[0])
    plan = _lti_plan(design, N, float(stop))  # the checks, on every point
    h = float(plan.h[0])

    def seeds_of(given, name):
        s = np.arange(P) if given is None else np.broadcast_to(np.asarray(given), (P,))
        if not np.issubdtype(s.dtype, np.integer) or np.any(s < 0) or np.any(s > 2**31 - 1):
            raise BatchError(f"{name} are not allowed: must be integers in 0 .. {2**31 - 1}")
        return s

    def checked(channel, name):
        if channel is None:
            return None
        try:
            channel.check()
            timeout_steps(channel, h)
            period_steps(channel, h)
        except ValueError as exc:
            raise BatchError(f"{name.split('_')[0]} channel: {exc}") from None
        return seeds_of(meas_seeds if name == "meas_seeds" else input_seeds, name)

    seeds_m, seeds_i = checked(meas, "meas_seeds"), checked(inp, "input_seeds")
    ages = None
    if stamps:
        if age_max is None:
            bound = (np.full(P, float(meas.bound())) if meas is not None
                     else np.asarray(design.r_true, dtype=float))
            ages = bound + design.T
        else:
            ages = np.broadcast_to(np.asarray(age_max, dtype=float), (P,)).copy()
            if not np.all(np.isfinite(ages) & (ages >= 0)):
                raise BatchError(f"age_max = {age_max!r} is not allowed: must be a finite "
                                 "number >= 0 [s] (or one per point)")
    elif age_max is not None:
        raise BatchError("age_max is not allowed without stamps = True")
    if chunk is None:
        kmax = int(plan.stop_k.max())
        per_point = 8 * (kmax + 1) * (2 if inp is not None else 0) + 8 * 64 * 8 + 4096
        chunk = (CHANNEL_CHUNK if be.name == "numpy"
                 else max(CHANNEL_CHUNK, min(GPU_CHANNEL_CHUNK_MAX,
                                             GPU_CHANNEL_BYTES // per_point)))
    elif isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise BatchError(f"chunk = {chunk!r} is not allowed: must be an integer >= 1")
    flows: dict = {}
    parts = []
    for c0 in range(0, P, chunk):
        idx = np.arange(c0, min(P, c0 + chunk))
        whole = idx.size == P
        sub = design if whole else take(design, idx)
        part = _channel_chunk(sub, float(stop), meas, inp,
                              None if seeds_m is None else seeds_m[idx],
                              None if seeds_i is None else seeds_i[idx], record,
                              None if ages is None else ages[idx], flows,
                              plan if whole else _plan_take(plan, idx), be)
        parts.append((idx, part))
    return _merge(parts, P)


def _plan_take(plan: _LtiPlan, idx: np.ndarray) -> _LtiPlan:
    """The plan of the points ``idx`` of ``plan``'s."""
    return _LtiPlan(plan.N, plan.T[idx], plan.h[idx], plan.stop_k[idx], plan.Dr[idx],
                    plan.Dt[idx], plan.Ad[idx], plan.Bd[idx], plan.E[idx], plan.QB[:, idx])


def _channel_chunk(design: LtiBatch, stop: float, meas, inp, seeds_m, seeds_i,
                   record: bool, ages, flows: dict, plan: _LtiPlan, be: Backend
                   ) -> BatchResult:
    """``run_lti_channels`` of the (checked) points of one chunk, ``plan`` theirs, on the
    array library ``be``."""
    from delaycomp.maths.channel_batch import shown, timeout_steps
    from delaycomp.studies import channel_kernel

    xp = be.xp
    P, N = len(design), int(design.N[0])
    h = float(plan.h[0])
    kmax = int(plan.stop_k.max())

    def fates(channel, seeds, every=1):
        """The packets shown: the compiled draws on the CPU where they are available (the
        same integers), else the array library's."""
        if be.name == "numpy":
            got = channel_kernel.shown(channel, seeds, h, kmax + 1, every)
            if got is not None:
                return got
        return shown(channel, seeds, h, kmax + 1, every=every, xp=xp)

    # the measurement at the sampling ticks alone
    Sm = (_constant_shown(plan.Dr, kmax + 1, xp)[::N] if meas is None
          else fates(meas, seeds_m, N))
    if inp is not None:
        Si, Qi = fates(inp, seeds_i), timeout_steps(inp, h)
    else:
        Si, Qi = None, int(plan.Dt.max())
        if not np.all(plan.Dt == plan.Dt[0]):
            Si = _constant_shown(plan.Dt, kmax + 1, xp)
    stamped = None
    if ages is not None:
        delay = (np.full(P, float(meas.delay)) if meas is not None
                 else np.asarray(design.r_true, dtype=float))
        stamped = _Stamped(be, plan, design, _ticks("tau", design.tau, plan.h), ages, delay,
                           flows)
    const = inp is None and bool(np.all(plan.Dt == plan.Dt[0]))
    run = _ChannelStepper(be, plan, design, Sm, None if const else Si, Qi, record, stamped,
                          int(plan.Dt[0]) if const else None)
    acc = _BlockMetrics(be, P, N, plan.stop_k, int((plan.stop_k // N).max()))
    with np.errstate(all="ignore"):
        for i in range(kmax // N + 1):
            rows = min(N, kmax - i * N + 1)
            badc = run.sample(i)
            if badc.any():
                acc.cut(badc, i * N, "the control is not finite (the feedback diverged: "
                        "overflow)", plan.T, plan.h)
            blk, sqx = run.period(i, rows, i * N + rows - 1 == kmax)
            acc.block(blk, i * N, plan.T, plan.h, sqx)
    res = acc.finish(plan.T, plan.h)
    end = np.minimum(acc.cut_at, plan.stop_k + 1)
    cost = be.to_numpy(run.cost).copy()
    cost[~res.success] = np.inf
    res.cost = cost
    res.states, res.inputs = _trim(run.states, run.inputs, end)
    return res


class _ChannelStepper:
    """The stepping of ``run_lti_channels`` (numpy or CuPy, the points on the last axis).

    The states are kept in a ring of ``nb`` blocks of ``N`` ticks, ``xb[b, row]``, long
    enough for the oldest packet the measurement channel shows at a sampling tick (its
    age is known from the channel's fates, drawn before the run): the controller reads its
    sample there at the sampling ticks alone, and a block is the metrics' rows as it
    stands. The controller outputs are a ring of one per period; the plant's input a
    latch, updated where the input channel shows another packet (a constant delay: at
    the ticks its period's output arrives). Every value is computed as before, in the same
    order: the cost's sums a block at a time, row after row.
    """

    def __init__(self, be: Backend, plan: _LtiPlan, d: LtiBatch, Sm, Si, Qi: int,
                 record: bool, stamped: _Stamped | None = None, Dt_const: int | None = None):
        xp = be.xp
        P, n, m = d.B.shape
        N = plan.N
        self.be, self.xp = be, xp
        self.plan, self.N, self.n, self.m, self.P = plan, N, n, m, P
        self.Sm, self.Si, self.Dt_const = Sm, Si, Dt_const
        kmax = int(plan.stop_k.max())
        ticks = xp.arange(0, kmax + 1, N)[:, None]
        age = int(xp.max(xp.where(Sm >= 0, ticks - Sm, 0)))  # Sm: one row and column or more
        self.nb = age // N + 2  # blocks kept: the oldest sample read and this period's
        self.Lmax = plan.QB.shape[0]
        self.Ru = max(self.Lmax, 0 if stamped is None else stamped.back) + Qi // N + 3
        self.stamped = stamped
        self.comp = be.asarray(np.asarray(d.mode == "compensated"))  # on the device, once

        self.Ad, self.Bd, self.K, self.E, self.QB, self.x0, self.u0 = _coefficients(
            plan, d, lambda a: be.asarray(np.ascontiguousarray(a)), self.Lmax)
        self.xb = xp.zeros((self.nb, N, n, P))
        self.flat = self.xb.reshape(self.nb * N, n, P)
        self.flat[0] = self.x0
        self.y = self.x0.copy()
        self.v = self.u0.copy()  # the plant-input latch: u0 before any packet
        self.held = self.u0.copy()
        self.U = xp.zeros((self.Ru, m, P))
        self.bv = xp.stack([_dot(self.Bd[a], self.v) for a in range(n)])
        self.vb = xp.zeros((N, m, P))  # the plant's input at each tick of the block
        self.cost = xp.zeros(P)
        self.h = float(plan.h[0])  # one h in a channel batch
        self.prev_i = xp.full(P, -1, dtype=xp.int64)
        self.pidx = xp.arange(P)
        self.tmp = xp.empty(P)
        self.states = np.full((P, kmax + 1, n), np.nan) if record else None
        self.inputs = np.full((P, kmax + 1, m), np.nan) if record else None

    def sample(self, i: int) -> np.ndarray:
        """The controller at the sampling tick ``i N`` from the state at the send tick of
        the packet shown then (``x0`` before any); returns where its output is not finite
        from a finite measurement (on the host)."""
        xp = self.xp
        s = self.Sm[i]
        slot = s % (self.nb * self.N)
        y = self.y
        for a in range(self.n):
            xp.copyto(y[a], xp.where(s >= 0, self.flat[slot, a, self.pidx], self.x0[a]))
        n, U = self.n, self.U
        if self.stamped is not None:
            xhat = self.stamped.predict(i, y, s, U, self.Ru)
            phi = list(xp.where(self.comp, xhat, y))
        else:
            phi = [_dot(self.E[a], y) for a in range(n)]
            for q in range(self.Lmax):
                past = U[(i - q - 1) % self.Ru] if i - q - 1 >= 0 else self.u0
                for a in range(n):
                    phi[a] = phi[a] + _dot(self.QB[q][a], past)
        self.held = xp.stack([_dot(self.K[c], phi) for c in range(self.m)])
        self.U[i % self.Ru] = self.held
        return self.be.to_numpy(~xp.all(xp.isfinite(self.held), axis=0)
                                & xp.all(xp.isfinite(y), axis=0))

    def _input(self, k: int) -> None:
        """The plant-input latch at tick ``k``."""
        N = self.N
        if self.Dt_const is not None:  # a constant delay: the output of tick k - D
            s = k - self.Dt_const
            if s < 0 or s % N:
                return
            self.v = self.U[(s // N) % self.Ru].copy()
        else:
            s = self.Si[k]
            new = self.xp.flatnonzero(s != self.prev_i)
            if not new.size:
                return
            self.v[:, new] = self.U[(s[new] // N) % self.Ru, :, new].T
            self.prev_i = s
        self.bv = self.xp.stack([_dot(self.Bd[a], self.v) for a in range(self.n)])

    def period(self, i: int, rows: int, last: bool) -> tuple[np.ndarray, np.ndarray]:
        """The ticks of period ``i`` (``rows`` of them; ``last``: the run's last tick is
        among them, not stepped from): the input latch, the record, the plant's exact
        step into the next row of the ring; then the cost of the block. Returns the
        block of states and their ``|x|^2``."""
        N, n, nb, xp = self.N, self.n, self.nb, self.xp
        bi = i % nb
        blk, nxt = self.xb[bi], self.xb[(i + 1) % nb]
        Ad, tmp, vb = self.Ad, self.tmp, self.vb
        for row in range(rows):
            k = i * N + row
            self._input(k)
            vb[row] = self.v
            x = blk[row]
            if self.states is not None and self.inputs is not None:
                self.states[:, k] = self.be.to_numpy(x).T
                self.inputs[:, k] = self.be.to_numpy(self.held).T
            if last and row == rows - 1:
                break
            out = blk[row + 1] if row + 1 < N else nxt[0]
            for a in range(n):  # Ad[a] x + bv[a], left to right (_dot's order)
                xp.multiply(Ad[a][0], x[0], out=out[a])
                for b in range(1, n):
                    xp.multiply(Ad[a][b], x[b], out=tmp)
                    xp.add(out[a], tmp, out=out[a])
                xp.add(out[a], self.bv[a], out=out[a])
        # the cost: sum_k h (|x_k|^2 + |v_k|^2), each tick's term added in turn
        sqx = _sumsq(blk[:rows])
        stepped = rows - 1 if last else rows
        if stepped > 0:
            v = vb[:stepped]
            sq = sqx[:stepped] + v[:, 0] * v[:, 0]
            for c in range(1, self.m):
                sq += v[:, c] * v[:, c]
            sq *= self.h
            for row in range(stepped):
                xp.add(self.cost, sq[row], out=self.cost)
        return blk[:rows], sqx


class _Stamped:
    """The time-stamp controller's estimate and prediction for every point at once
    (``delaycomp.maths.stamped.StampedController``'s maths, in ticks): the plant's input
    is ``u_j`` over ticks ``[j N + Dtau, (j + 1) N + Dtau)`` (``u0`` for ``j < 0``), each
    piece of it ``L`` ticks long carried by the exact flow ``(F[L], G[L])`` of its point's
    ``(A, B)``, the flows of ``L = 0 .. N`` computed once. The decisions (a new sample,
    too old) compare the same doubles as the controller: the channel's stamps ``s h``
    (before any packet ``min(k h - delay, 0)``), ``t_i = i T`` and ``age_max + 1e-9 T``."""

    def __init__(self, be: Backend, plan: _LtiPlan, d: LtiBatch, Dtau: np.ndarray,
                 age_max: np.ndarray, delay: np.ndarray, cache: dict | None = None):
        from delaycomp.maths.lti import flow

        xp, dev = be.xp, be.asarray
        self.xp = xp
        P, n, m = d.B.shape
        N, h = plan.N, float(plan.h[0])
        self.N, self.n, self.m, self.h, self.T = N, n, m, h, float(plan.T[0])
        first, inv = _unique_rows(d.A, d.B)
        self.inv = dev(inv)
        cache = {} if cache is None else cache  # the flows of (A, B, h, N): chunks share them

        def flows_of(p):
            key = (d.A[p].tobytes(), d.B[p].tobytes(), d.A.shape, d.B.shape, h, N)
            if key not in cache:
                cache[key] = [flow(d.A[p], d.B[p], k * h) for k in range(N + 1)]
            return cache[key]

        flows = [flows_of(p) for p in first]
        self.F = dev(np.array([[f[0] for f in row] for row in flows]))  # (U, N + 1, n, n)
        self.G = dev(np.array([[f[1] for f in row] for row in flows]))  # (U, N + 1, n, m)
        self.Dtau = dev(Dtau.astype(np.int64))
        self.limit = dev(age_max + STAMP_SNAP * self.T)
        self.delay = dev(delay)
        self.u0 = dev(np.ascontiguousarray(d.u0.T))  # (m, P)
        #: the periods of outputs the carries reach back (the ring's length needed)
        self.back = int(np.max(np.floor(age_max / h).astype(np.int64) + Dtau)) // N + 3
        self.z = None  # the estimates of x(t_{i-1}), (n, P), of the backend
        self.last = xp.full(P, -np.inf)  # the stamp of the newest sample used

    def carry(self, x: np.ndarray, idx: np.ndarray, a: np.ndarray, b: np.ndarray,
              U: np.ndarray, Ru: int) -> np.ndarray:
        """The states ``x`` (``(n, len(idx))``) of the points ``idx`` carried from tick
        ``a`` to tick ``b`` (per point, ``a <= b``), piece by piece."""
        xp = self.xp
        x, a = x.copy(), a.copy()
        N, n, m = self.N, self.n, self.m
        Dtau = self.Dtau[idx]
        while True:
            on = xp.flatnonzero(a < b)
            if not on.size:
                return x
            p, aa = idx[on], a[on]
            j = (aa - Dtau[on]) // N  # the output the plant receives just after aa
            end = xp.minimum((j + 1) * N + Dtau[on], b[on])
            L = end - aa
            F, G = self.F[self.inv[p], L], self.G[self.inv[p], L]
            u = xp.where(j >= 0, U[j % Ru, :, p].T, self.u0[:, p])
            xo = x[:, on]
            for r in range(n):
                acc = F[:, r, 0] * xo[0]
                for c in range(1, n):
                    acc = acc + F[:, r, c] * xo[c]
                g = G[:, r, 0] * u[0]
                for c in range(1, m):
                    g = g + G[:, r, c] * u[c]
                x[r, on] = acc + g
            a[on] = end

    def predict(self, i: int, y: np.ndarray, sent: np.ndarray, U: np.ndarray,
                Ru: int) -> np.ndarray:
        """``x_hat`` of every point at ``t_i`` from the samples ``y`` (``(n, P)``) sent at
        ticks ``sent`` (``-1``: the history); stores the estimates of ``x(t_i)``."""
        xp = self.xp
        N, P = self.N, y.shape[1]
        k = i * N
        t = 0.0 + i * self.T
        stamp = xp.where(sent >= 0, 0.0 + sent * self.h,
                         xp.minimum((0.0 + k * self.h) - self.delay, 0.0))
        if self.z is None:  # the first instant always uses its sample
            new = xp.ones(P, dtype=bool)
        else:
            new = (stamp > self.last) & (t - xp.maximum(stamp, 0.0) <= self.limit)
        self.last = xp.where(new, xp.maximum(stamp, self.last), self.last)
        z = xp.empty_like(y)
        fresh = xp.flatnonzero(new)
        if fresh.size:
            z[:, fresh] = self.carry(y[:, fresh], fresh, xp.maximum(sent[fresh], 0),
                                     xp.full(fresh.size, k, dtype=xp.int64), U, Ru)
        old = xp.flatnonzero(~new)
        if old.size:
            assert self.z is not None
            z[:, old] = self.carry(self.z[:, old], old,
                                   xp.full(old.size, k - N, dtype=xp.int64),
                                   xp.full(old.size, k, dtype=xp.int64), U, Ru)
        self.z = z
        every = xp.arange(P)
        return self.carry(z, every, xp.full(P, k, dtype=xp.int64), k + self.Dtau, U, Ru)
