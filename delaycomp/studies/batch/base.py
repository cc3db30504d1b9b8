"""What the batch engines share: the refusal (``BatchError``), the result
(``BatchResult``, and ``merge``, which puts the results of groups back in input order),
the grid arithmetic (a time as whole base steps, ``grid_ticks``) and the points of a
batch (``ModelBatch``, ``take``, and the broadcast and checks that gather loose per-point
arguments).

The LTI, model and channel engines (``.lti``, ``.model``, ``.channels``) each keep their
own plan and stepping; what they have in common is here, written once.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TypeVar, cast

import numpy as np

from delaycomp.errors import DelaycompError, is_divergence
from delaycomp.maths.grid import on_grid_array
from delaycomp.system import LtiBatch


class BatchError(DelaycompError, ValueError):
    """A batch ingredient is out of range or inconsistent (one-line message)."""


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


def merge(parts: list[tuple[np.ndarray, BatchResult]], P: int) -> BatchResult:
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

def grid_ticks(name: str, value: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``value / h`` as integers; ``BatchError`` if some point is off the base grid."""
    ratio = np.asarray(value, dtype=float) / h
    steps = np.rint(ratio)
    bad = ~on_grid_array(value, h)
    if np.any(bad) or np.any(ratio < 0):
        p = int(np.flatnonzero(bad | (ratio < 0))[0])
        raise BatchError(f"{name} = {float(np.ravel(value)[p])!r} (point {p}) is not allowed: "
                         f"must be a multiple >= 0 of the base step h = {float(h[p])!r}")
    return steps.astype(np.int64)


def per_point(value, P: int, shape: tuple, name: str) -> np.ndarray:
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


def checked_points(P: int, n: int, m: int, T, r, tau, N, r_true, tau_true, x0, u0) -> ModelBatch:
    """Timing and histories per point, broadcast and checked: ``T > 0``, delays ``>= 0``
    and finite, ``N >= 1``; the true delays default to the assumed ones."""
    T = per_point(T, P, (), "T")
    r = per_point(r, P, (), "r")
    tau = per_point(tau, P, (), "tau")
    r_true = r if r_true is None else per_point(r_true, P, (), "r_true")
    tau_true = tau if tau_true is None else per_point(tau_true, P, (), "tau_true")
    x0 = per_point(x0, P, (n,), "x0")
    u0 = per_point(u0, P, (m,), "u0")
    Ns = np.broadcast_to(np.asarray(N), (P,)).astype(np.int64)
    for name, v in (("T", T), ("r", r), ("tau", tau), ("r_true", r_true),
                    ("tau_true", tau_true)):
        if not np.all(np.isfinite(v)) or np.any(v < 0) or (name == "T" and np.any(v <= 0)):
            raise BatchError(f"{name} is not allowed: must be finite and "
                             f"{'> 0' if name == 'T' else '>= 0'} at every point")
    if np.any(Ns < 1):
        raise BatchError("N is not allowed: must be a positive integer at every point")
    return ModelBatch(T, Ns, r, tau, r_true, tau_true, x0, u0)


def count_points(matrices, scalars, vectors, mode=None) -> int:
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


def unique_rows(*arrays) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the first occurrence of each distinct row, and the inverse map."""
    key = np.concatenate([np.ascontiguousarray(a).reshape(len(a), -1) for a in arrays],
                         axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


def trim(states, inputs, end: np.ndarray):
    """Recorded trajectories with the ticks from ``end[p]`` on of each point ``p`` set to
    ``nan`` (``None`` stays ``None``)."""
    if states is not None:
        for p, e in enumerate(end.tolist()):
            states[p, e:] = np.nan
            inputs[p, e:] = np.nan
    return states, inputs
