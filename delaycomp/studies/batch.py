"""Many closed loops at once: the sampled-data loop advanced for a batch of points.

A maths module (numpy/scipy; no FMI, no scenario): it takes the loop's ingredients as
arrays, one entry per point, and advances every point together on the base grid, tick by
tick, vectorized over the points. It computes what the per-point engine (the master
stepping the slaves) computes, in the same order, so the sweep's metrics come out the same:

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

- :func:`simulate_lti`: ``x' = A x + B u``, exactly discretized (per-point matrices, one
  matrix exponential per distinct ``(A, B, h)``), the zero-order-hold controller of
  Theorem 3.2 with the closed-form predictor of Corollary 3.4 (``compensated``) or
  ``u = K y`` (``uncompensated``). Any array library with numpy's API (numpy, CuPy, JAX)
  through :func:`get_backend`.
- :func:`simulate_model`: a model (:mod:`delaycomp.maths.model`) that declares ``BATCH = True``
  and has an exact ``step``: its ``f``, ``k`` and ``step`` accept a batch (states of shape
  ``(n, P)``). Zero-order hold (Theorem 3.2, with Remark 3.3(b) padding) and continuous
  input (Theorem 2.1, the controller's copy ``z`` integrated on the base grid and reset to
  ``Phi`` at every sample after the first). ``Phi`` is the composition of exact steps over
  the stored window (the per-point engine's closed forms compose the same exact flows).
  numpy only.

Failures follow the per-point engine: a control that is not finite (from a finite
measurement) refuses the tick (not recorded), a plant state that is not finite after a
step ends the run after the last recorded tick; the point then has ``rho = inf``.

Metrics (the sweep's, :mod:`delaycomp.studies.sweep`): ``rho`` from a least-squares line through
the logarithm of the per-period root-sum-square of ``|x|`` after the first fifth of the
periods, ``stable``, ``final_norm``, ``peak_norm``, ``deadbeat_time`` (the time from which
``|x| < 1e-9`` holds to the end; ``nan`` if never).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from delaycomp.errors import DelaycompError
from delaycomp.maths.grid import on_grid_array
from delaycomp.maths.grid import periods as zoh_periods
from delaycomp.maths.lti import MODES, LTIPredictor, discretize
from delaycomp.maths.nlcontrol import padded_delay

#: ``|x|`` below this counts as zero for the dead-beat time (``delaycomp.studies.sweep.ZERO``).
ZERO = 1e-9
#: Array libraries :func:`get_backend` knows; ``auto`` takes the first GPU library found.
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
    """The array library ``name`` (one of :data:`BACKENDS`), checked to be usable.

    ``jax`` runs in double precision (``jax_enable_x64`` is switched on: the maths needs
    float64). ``auto`` is CuPy if it sees a GPU, else JAX if it sees one, else numpy.
    Raises :class:`BatchError` naming what is missing.
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

    ``deadbeat_time`` is ``nan`` where ``|x|`` never stays below :data:`ZERO` (and where the
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

    def rows(self) -> list[dict]:
        """One dict per point with the sweep's metric columns (``None`` for never)."""
        deadbeat = [None if math.isnan(d) else d for d in np.asarray(
            self.deadbeat_time, dtype=float).tolist()]
        # tolist() gives Python floats and ints at once (a float() per value is 10x slower)
        return [{"rho": a, "stable": b, "final_norm": c, "peak_norm": d, "deadbeat_time": e}
                for a, b, c, d, e in zip(np.asarray(self.rho, dtype=float).tolist(),
                                         np.asarray(self.stable).astype(int).tolist(),
                                         np.asarray(self.final_norm, dtype=float).tolist(),
                                         np.asarray(self.peak_norm, dtype=float).tolist(),
                                         deadbeat)]

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
    return BatchResult(**out, message=message, states=states, inputs=inputs)


# -- grid arithmetic --------------------------------------------------------------------

def _ticks(name: str, value: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``value / h`` as integers; :class:`BatchError` if some point is off the base grid."""
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


# -- LTI loops --------------------------------------------------------------------------

def simulate_lti(A, B, K, T, N, r, tau, x0, u0, mode, stop: float, r_true=None,
                 tau_true=None, *, record: bool = False,
                 backend: Backend | str = "numpy") -> BatchResult:
    """Advance ``P`` LTI loops of Theorem 3.2 / Corollary 3.4 together to ``stop``.

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
        Array library (:func:`get_backend`).

    Returns
    -------
    BatchResult
    """
    be = backend if isinstance(backend, Backend) else get_backend(backend)
    A = np.asarray(A, dtype=float)
    P = _count([A, B, K], [T, r, tau, N, r_true, tau_true], [x0, u0], mode)
    n = A.shape[-1]
    m = np.asarray(B, dtype=float).shape[-1]
    A = _per_point(A, P, (n, n), "A")
    B = _per_point(B, P, (n, m), "B")
    K = _per_point(K, P, (m, n), "K")
    T, r, tau, r_true, tau_true, x0, u0, Ns = _timing(P, n, m, T, r, tau, N, r_true,
                                                      tau_true, x0, u0)
    modes = np.broadcast_to(np.asarray(mode, dtype=object), (P,))
    bad = [md for md in set(modes.tolist()) if md not in MODES]
    if bad:
        raise BatchError(f"mode = {bad[0]!r} is not allowed: must be one of {', '.join(MODES)}")
    parts = []
    for Nv in np.unique(Ns):
        idx = np.flatnonzero(Ns == Nv)
        res = _lti_group(be, A[idx], B[idx], K[idx], T[idx], int(Nv), r[idx], tau[idx],
                         r_true[idx], tau_true[idx], x0[idx], u0[idx],
                         modes[idx] == "compensated", float(stop), record)
        parts.append((idx, res))
    return _merge(parts, P)


def _timing(P: int, n: int, m: int, T, r, tau, N, r_true, tau_true, x0, u0):
    """Timing and histories per point, checked: ``T > 0``, delays ``>= 0`` and finite,
    ``N >= 1``; the true delays default to the assumed ones."""
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
    return T, r, tau, r_true, tau_true, x0, u0, Ns


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


def _lti_group(be: Backend, A, B, K, T, N, r, tau, r_true, tau_true, x0, u0, comp,
               stop, record) -> BatchResult:
    xp = be.xp
    P, n, m = B.shape
    h = T / N
    stop_k = _ticks("stop", np.full(P, stop), h)
    _ticks("r", r, h)
    Dr = _ticks("r_true", r_true, h)
    Dt = _ticks("tau_true", tau_true, h)
    for p in _unique_rows(tau, T)[0]:
        try:
            zoh_periods(float(tau[p]), float(T[p]))
        except ValueError as exc:
            raise BatchError(f"{exc} (point {p})") from None
    # exact discretization, once per distinct (A, B, h)
    first, inv = _unique_rows(A, B, h)
    Ad_u, Bd_u = zip(*(discretize(A[i], B[i], float(h[i])) for i in first))
    Ad = np.stack(Ad_u)[inv]
    Bd = np.stack(Bd_u)[inv]
    # predictor Phi = E y + sum_p QB_p u_{i-p}, once per distinct (A, B, T, r, tau);
    # an uncompensated point has E = I, QB = 0, hence u = K y
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
    Lmax = int(L.max())
    QB = np.zeros((Lmax, P, n, m))
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
    kmax = int(stop_k.max())
    nb = int(Dr.max()) // N + 2  # blocks of N ticks kept for the measurement delay
    Ru = max(Lmax, int(Dt.max()) // N + 1) + 2
    dev = be.asarray
    is_np = be.name == "numpy"
    # per-point coefficients as contiguous (P,) arrays, points on the last axis
    Ad_d = [[dev(np.ascontiguousarray(Ad[:, a, b])) for b in range(n)] for a in range(n)]
    Bd_d = [[dev(np.ascontiguousarray(Bd[:, a, c])) for c in range(m)] for a in range(n)]
    K_d = [[dev(np.ascontiguousarray(K[:, c, a])) for a in range(n)] for c in range(m)]
    E_d = [[dev(np.ascontiguousarray(E[:, a, b])) for b in range(n)] for a in range(n)]
    QB_d = [[[dev(np.ascontiguousarray(QB[q, :, a, c])) for c in range(m)] for a in range(n)]
            for q in range(Lmax)]
    x0_d = dev(np.ascontiguousarray(x0.T))
    u0_d = dev(np.ascontiguousarray(u0.T))
    pidx = dev(np.arange(P))
    Dr_uniform = bool(np.all(Dr == Dr[0]))
    Dt_uniform = bool(np.all(Dt == Dt[0]))
    Dr_d = dev(Dr)
    xb = xp.zeros((nb, N, n, P))  # states of the last nb blocks of N ticks
    U = xp.zeros((Ru, m, P))  # controller outputs, one per period
    x = [x0_d[a] for a in range(n)]
    v = u0_d
    held = u0_d
    tmp = np.empty(P) if is_np else None
    acc = _BlockMetrics(be, P, N, stop_k, int((stop_k // N).max()))
    states = inputs = None
    if record:
        states = np.full((P, kmax + 1, n), np.nan)
        inputs = np.full((P, kmax + 1, m), np.nan)
    # the plant input changes at the ticks k with (k - Dt) % N == 0: rows Dt % N of a block
    change_rows = {int(c) for c in np.unique(Dt % N)}
    Dt_rows = Dt % N

    def plant_input(k, row, v):
        """``v`` at tick ``k``: the controller output of tick ``k - Dt``."""
        if row not in change_rows:
            return v, False
        if Dt_uniform:
            s = k - int(Dt[0])
            return (U[(s // N) % Ru], True) if s >= 0 else (v, False)
        due = (Dt_rows == row) & (k - Dt >= 0)
        if not due.any():
            return v, False
        s = np.maximum(k - Dt, 0)
        return xp.where(dev(due), U[dev((s // N) % Ru), :, pidx].T, v), True

    def forced(v):
        return [_dot(Bd_d[a], v) for a in range(n)]

    bv = forced(v)
    scalar = is_np and n == 1
    A00 = Ad_d[0][0]
    with np.errstate(all="ignore"):  # overflow is detected per block, as the FMUs refuse
        for a in range(n):
            xb = be.put(xb, (0, 0, a), x[a])
        for i in range(kmax // N + 1):
            k0 = i * N
            bi = i % nb
            if not is_np and i > 0:  # row 0 of this block: the last step's result
                xb = be.put(xb, (bi, 0), xp.stack(x))
            # the controller at the sampling instant k0
            if Dr_uniform:
                src = k0 - int(Dr[0])
                y = xb[(src // N) % nb, src % N] if src >= 0 else x0_d
            else:
                src = k0 - Dr_d
                y = xp.where(src >= 0, xb[(src // N) % nb, src % N, :, pidx].T, x0_d)
            phi = [_dot(E_d[a], y) for a in range(n)]
            for q in range(Lmax):
                past = U[(i - q - 1) % Ru] if i - q - 1 >= 0 else u0_d
                for a in range(n):
                    phi[a] = phi[a] + _dot(QB_d[q][a], past)
            held = xp.stack([_dot(K_d[c], phi) for c in range(m)])
            bad = ~xp.all(xp.isfinite(held), axis=0) & xp.all(xp.isfinite(y), axis=0)
            if bool(xp.any(bad)):
                acc.cut(be.to_numpy(bad), k0, "the control is not finite (the feedback "
                        "overflowed)", T, h)
            U = be.put(U, i % Ru, held)
            rows = min(N, kmax - k0 + 1)
            later = []  # other libraries: rows 1.. of this block, written once at its end
            for row in range(rows):
                k = k0 + row
                v, changed = plant_input(k, row, v)
                if changed:
                    bv = forced(v)
                if record:
                    assert states is not None and inputs is not None  # set when record
                    states[:, k] = be.to_numpy(xp.stack(x)).T
                    inputs[:, k] = be.to_numpy(held).T
                if k == kmax:
                    break
                # the plant's step to tick k + 1, into its row of the block ring
                bi1, row1 = (bi, row + 1) if row + 1 < N else ((i + 1) % nb, 0)
                if scalar:  # n = 1 on numpy: the hot path, two ufunc calls a tick
                    out = xb[bi1, row1, 0]
                    np.multiply(A00, x[0], out=out)
                    np.add(out, bv[0], out=out)
                    x = [out]
                elif is_np:
                    assert tmp is not None  # the scratch row of numpy
                    for a in range(n):
                        out = xb[bi1, row1, a]
                        np.multiply(Ad_d[a][0], x[0], out=out)
                        for b in range(1, n):
                            np.multiply(Ad_d[a][b], x[b], out=tmp)
                            np.add(out, tmp, out=out)
                        np.add(out, bv[a], out=out)
                    x = [xb[bi1, row1, a] for a in range(n)]
                else:  # JAX arrays are immutable: one write a block, not one a tick
                    x = [_dot(Ad_d[a], x) + bv[a] for a in range(n)]
                    if row1:
                        later.append(xp.stack(x))
            if later:
                xb = be.put(xb, (bi, slice(1, 1 + len(later))), xp.stack(later))
            acc.block(xb[bi, :rows], k0, T, h)
    res = acc.finish(T, h)
    if record:
        assert states is not None and inputs is not None
        for p, (c, e) in enumerate(zip(acc.cut_at, stop_k)):
            states[p, min(int(c), int(e) + 1):] = np.nan
            inputs[p, min(int(c), int(e) + 1):] = np.nan
    res.states, res.inputs = states, inputs
    return res


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
        new = mask & (self.cut_at > k)
        if not new.any():
            return
        self.cut_at[new] = k
        t = (k // self.N) * T + (k % self.N) * h
        for p in np.flatnonzero(new):
            self.messages[p] = f"{why} at t = {float(t[p])!r}"

    def block(self, xs, start: int, T, h) -> None:
        """Rows ``xs[j]`` (shape ``(n, P)``) are the states of ticks ``start + j``.

        Three passes over the block in the common case (squares, their column maxima and
        sums): ``sqrt`` is monotonic, so the largest norm is the root of the largest square,
        and norms are taken only on the rows a metric reads.
        """
        xp = self.xp
        R = xs.shape[0]
        sq = xs[:, 0] * xs[:, 0]
        for a in range(1, xs.shape[1]):
            sq = sq + xs[:, a] * xs[:, a]
        colmax = xp.max(sq, axis=0)
        if not bool(xp.isfinite(xp.max(colmax))):  # rare: states not finite, or |x|^2 overflow
            bad = ~xp.all(xp.isfinite(xs), axis=1)  # (a norm may overflow, finite states)
            has = self.be.to_numpy(xp.any(bad, axis=0))
            first = self.be.to_numpy(xp.argmax(bad, axis=0))
            for p in np.flatnonzero(has):
                self.cut(np.arange(self.P) == p, start + int(first[p]),
                         "the plant state is not finite (the plant diverged: overflow)", T, h)
        end = np.minimum(self.cut_at, self.ticks + 1)
        if np.any(end < start + R) or not bool(xp.isfinite(xp.max(colmax))):
            norms = xp.sqrt(sq)
            rows = xp.asarray(start + np.arange(R))[:, None]
            incl = rows < xp.asarray(end)[None, :]
            sq_in = xp.where(incl, sq, 0.0)
            above = incl & ~(norms < ZERO)
            self.peak = xp.maximum(self.peak, xp.max(xp.where(incl, norms, 0.0), axis=0))
            last_row = above[R - 1]
            need = self.be.to_numpy(xp.any(above, axis=0) & ~last_row)
        else:
            sq_in = sq
            above = None
            self.peak = xp.maximum(self.peak, xp.sqrt(colmax))
            last_row = xp.sqrt(sq[R - 1]) >= ZERO
            need = self.be.to_numpy((xp.sqrt(colmax) >= ZERO) & ~last_row)
        # the last tick with |x| >= ZERO: the block's last row for most points; a search
        # only where some earlier row is above and the last is not
        self.last_above = xp.where(last_row, start + R - 1, self.last_above)
        if need.any():
            sel = np.flatnonzero(need)
            cols = self.be.asarray(sel)
            sub = above[:, cols] if above is not None else xp.sqrt(sq[:, cols]) >= ZERO
            last = (R - 1) - self.be.to_numpy(xp.argmax(sub[::-1], axis=0))
            host = self.be.to_numpy(self.last_above).copy()
            host[sel] = start + last
            self.last_above = self.be.asarray(host)
        j = start // self.N
        if j < self.periods_max and R == self.N:
            self.envsq[j] = self.be.to_numpy(xp.sum(sq_in, axis=0))
        # the last recorded norm of points whose record ends in this block (or just before)
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


def _rates(envsq: np.ndarray, periods: np.ndarray) -> np.ndarray:
    """``rho`` per point from the per-period sums of ``|x|^2`` (``envsq[j, p]``)."""
    P = len(periods)
    rho = np.full(P, np.nan)
    for S in np.unique(periods):
        sel = np.flatnonzero(periods == S)
        start = max(1, int(S) // 5)
        tail = np.sqrt(envsq[start:S, sel]).T  # (points, tail length)
        if tail.shape[1] < 2:
            continue  # too few periods to estimate a rate: nan, as the per-point metric
        zero = np.any(tail == 0.0, axis=1)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            y = np.log(tail)
            t = np.arange(tail.shape[1], dtype=float)
            tc = t - t.mean()
            slope = ((y - y.mean(axis=1, keepdims=True)) @ tc) / (tc @ tc)
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
    """Advance ``P`` loops of a batchable model (:func:`batchable`) together to ``stop``.

    Parameters
    ----------
    model : delaycomp.maths.model.Model
        With ``BATCH = True`` and an exact ``step``.
    params : dict
        The model's parameters, shared by every point (numbers may be arrays of length P).
    T, N, r, tau, x0, u0, stop, r_true, tau_true :
        As in :func:`simulate_lti`; ``x0`` is also the controller's initial ``z``
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
    n, m = model.n, model.m
    T, r, tau, r_true, tau_true, x0, u0, Ns = _timing(P, n, m, T, r, tau, N, r_true,
                                                      tau_true, x0, u0)
    parts = []
    for Nv in np.unique(Ns):
        idx = np.flatnonzero(Ns == Nv)
        p_idx = {key: (np.asarray(val)[idx] if np.ndim(val) == 1 and np.size(val) == P
                       else val) for key, val in params.items()}
        res = _model_group(model, p_idx, T[idx], int(Nv), r[idx], tau[idx], r_true[idx],
                           tau_true[idx], x0[idx], u0[idx], float(stop), pad, record)
        parts.append((idx, res))
    return _merge(parts, P)


def _model_group(model, params, T, N, r, tau, r_true, tau_true, x0, u0, stop, pad,
                 record) -> BatchResult:
    P = len(T)
    n, m = model.n, model.m
    h = T / N
    stop_k = _ticks("stop", np.full(P, stop), h)
    Dr_true = _ticks("r_true", r_true, h)
    Dt_true = _ticks("tau_true", tau_true, h)
    Dr = _ticks("r", r, h)
    zoh = model.control == "zoh"
    p = dict(params)
    p["T"] = T
    if zoh:
        tau_eff = np.array([padded_delay(tau[i], T[i]) for i in range(P)])
        if not pad and np.any(tau_eff != tau):
            i = int(np.flatnonzero(tau_eff != tau)[0])
            try:
                zoh_periods(float(tau[i]), float(T[i]), padding=True)
            except ValueError as exc:
                raise BatchError(str(exc)) from None
        Dpad = _ticks("padding", tau_eff - tau, h)
        W = Dr + np.rint(tau_eff / h).astype(np.int64)
    else:
        Dpad = np.zeros(P, dtype=np.int64)
        W = Dr + _ticks("tau", tau, h)
    Dt = Dt_true + Dpad  # controller's held value -> plant input, in ticks
    kmax = int(stop_k.max())
    periods = stop_k // N
    Rx = int(Dr_true.max()) + 1
    pidx = np.arange(P)
    x = x0.T.copy()
    xring = np.zeros((Rx, n, P))
    metrics = _Metrics(np, P, N, stop_k, int(periods.max()))
    failed = np.zeros(P, dtype=bool)
    fail_norm = np.zeros(P)
    fail_peak = np.zeros(P)
    messages = [""] * P
    norm_prev = np.zeros(P)
    u0T = u0.T.copy()
    states = inputs = None
    if record:
        states = np.full((P, kmax + 1, n), np.nan)
        inputs = np.full((P, kmax + 1, m), np.nan)
    if zoh:
        nfull, rem = W // N, W % N
        nseg = nfull + (rem > 0)
        Ru = max(int(nseg.max()), int(Dt.max()) // N + 1) + 2
    else:
        Ru = max(int(W.max()), int(Dt.max())) + 2
        z = x0.T.copy()
    U = np.zeros((Ru, m, P))  # per period (zoh) or per tick (continuous)
    held = u0T.copy()
    v = u0T.copy()
    out = u0T.copy()

    def past(j):
        """Controller output of slot index ``j`` (period or tick), ``u0`` before t = 0."""
        return U[j % Ru] if j >= 0 else u0T

    def fail(mask, norms, why, k):
        nonlocal x, held, v, out
        new = mask & ~failed
        if not new.any():
            return
        fail_norm[new] = norms[new]
        fail_peak[new] = metrics.peak[new]
        t = (k // N) * T + (k % N) * h
        for i in np.flatnonzero(new):
            messages[i] = f"{why} at t = {float(t[i])!r}"
        failed[new] = True
        x[:, failed] = 0.0
        held[:, failed] = 0.0
        v[:, failed] = 0.0
        out[:, failed] = 0.0
        U[:, :, failed] = 0.0
        if not zoh:
            z[:, failed] = 0.0

    with np.errstate(all="ignore"):
        for k in range(kmax + 1):
            xring[k % Rx] = x
            i, jj = divmod(k, N)
            if k % N == 0:
                src = k - Dr_true
                y = np.where(src >= 0, xring[src % Rx, :, pidx].T, x0.T)
            if zoh:
                if k % N == 0:
                    xs = y.copy()
                    for e in range(int(nseg.max()), 0, -1):
                        active = (e <= nfull) | ((e == nfull + 1) & (rem > 0))
                        dur = np.where(e <= nfull, N * h, rem * h)
                        stepped = np.asarray(model.step(xs, past(i - e), dur, p), dtype=float)
                        xs = np.where(active, stepped, xs)
                    held = np.asarray(model.k(xs, p), dtype=float).reshape(m, P)
                    bad = ~np.all(np.isfinite(held), axis=0) & np.all(np.isfinite(y), axis=0)
                    if bad.any():
                        fail(bad, norm_prev, "the control is not finite (the predictor or "
                             "the feedback diverged)", k)
                    U[i % Ru] = held
                s = k - Dt
                due = (s >= 0) & (s % N == 0)
                if due.any():
                    v = np.where(due, U[(s // N) % Ru, :, pidx].T, v)
                if record:
                    sp = k - Dpad
                    out = np.where(sp >= 0, U[(sp // N) % Ru, :, pidx].T, u0T)
            else:
                if k % N == 0 and k > 0:
                    xs = y.copy()
                    for e in range(int(W.max()), 0, -1):
                        stepped = np.asarray(model.step(xs, past(k - e), h, p), dtype=float)
                        xs = np.where(e <= W, stepped, xs)
                    z = xs
                t = i * T + jj * h
                held = np.asarray(model.k(t + tau, z, p), dtype=float).reshape(m, P)
                bad = ~np.all(np.isfinite(held), axis=0) & np.all(np.isfinite(y), axis=0)
                if bad.any():
                    fail(bad, norm_prev, "the control is not finite (the predictor or the "
                         "feedback diverged)", k)
                U[k % Ru] = held
                s = k - Dt
                v = np.where(s >= 0, U[s % Ru, :, pidx].T, u0T)
                out = held
            sq = x[0] * x[0]
            for a in range(1, n):
                sq = sq + x[a] * x[a]
            norm = np.sqrt(sq)
            metrics.record(k, np.where(failed, 0.0, norm), _np_put)
            if record:
                assert states is not None and inputs is not None  # set when record
                states[:, k] = x.T
                inputs[:, k] = out.T
                states[failed, k] = np.nan
                inputs[failed, k] = np.nan
            if k == kmax:
                break
            if not zoh:
                z = np.asarray(model.step(z, held, h, p), dtype=float)
            x = np.asarray(model.step(x, v, h, p), dtype=float)
            bad = ~np.all(np.isfinite(x), axis=0)
            if bad.any():
                fail(bad, norm, "the plant state is not finite", k + 1)
            norm_prev = norm
    if record:
        assert states is not None and inputs is not None
        for i in range(P):
            states[i, stop_k[i] + 1:] = np.nan
            inputs[i, stop_k[i] + 1:] = np.nan
    res = _finish(metrics, get_backend("numpy"), failed, fail_norm, fail_peak, T, h, N,
                  messages)
    res.states, res.inputs = states, inputs
    return res


def _dot(row, vec):
    """``sum_j row[j] * vec[j]`` over per-point arrays, left to right (no ``0 +``)."""
    acc = row[0] * vec[0]
    for j in range(1, len(row)):
        acc = acc + row[j] * vec[j]
    return acc


def _np_put(a, index, value):
    a[index] = value
    return a
