"""The batch engine behind ``delaycomp sweep``: grid points turned into batch ingredients.

Each grid point is a typed loop (:class:`delaycomp.system.Loop`, from a scenario or a loop
file); this module takes from it what :mod:`delaycomp.studies.batch` needs (the LTI design and
timing; or the model file, its parameters and timing), groups the
points that can share a batch (same dimensions, same model and string parameters), cuts the
groups into chunks that fit in memory, and runs the chunks here, on local worker processes
or on a Dask cluster. Every point of a chunk is computed independently of the others, so
the results do not depend on the chunking or on where a chunk runs (tested).

A point that cannot be batched (a model without ``BATCH = True`` or without an exact
``step``, ``predictor=numerical``, which asks for the ODE-solved predictor, a loop with an
FMU file or ``held_sample``) is returned with the reason, for the per-point engine.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from delaycomp.studies import batch
from delaycomp.studies.pool import on_dask, on_processes
from delaycomp.system import BuiltinFmu, Loop, LtiBatch, ModelFmu

if TYPE_CHECKING:
    from delaycomp.maths.model import Model

#: Points per chunk at most: arrays of this many float64 (128 KiB) stay in a core's L2
#: cache, where one ufunc call costs the least per point (measured in bench/batch.py).
CHUNK_MAX = 16384
#: Points per chunk at most on a GPU library: there a launch costs the same for any size.
CHUNK_MAX_GPU = 1 << 20
#: Share of the available memory the chunks of all workers may use together.
MEMORY_SHARE = 0.25


@dataclass(frozen=True)
class Chunk:
    """One batch: picklable, for worker processes and Dask."""

    kind: str  # "lti" or "model"
    arrays: dict
    stop: float
    backend: str
    model_path: str | None = None
    params: tuple = ()
    pad: bool = False


def run_chunk(chunk: Chunk) -> list[dict]:
    """The sweep's metric dicts of every point of ``chunk``."""
    return compute_chunk(chunk).rows()


def compute_chunk(chunk: Chunk) -> batch.BatchResult:
    """The metrics of every point of ``chunk`` as arrays (a top-level function: worker
    processes and Dask run it and send the arrays back, which pickle much faster than one
    dict per point)."""
    a = chunk.arrays
    if chunk.kind == "lti":
        res = batch.simulate_lti(a["A"], a["B"], a["K"], a["T"], a["N"], a["r"], a["tau"],
                                 a["x0"], a["u0"], list(a["mode"]), chunk.stop, a["r_true"],
                                 a["tau_true"], backend=chunk.backend)
    else:
        from delaycomp.maths.model import load_model

        # a model chunk names its model file (:func:`prepare` sets it)
        model = load_model(cast(str, chunk.model_path))
        res = batch.simulate_model(model, model.params(**dict(chunk.params)), a["T"], a["N"],
                                   a["r"], a["tau"], a["x0"], a["u0"], chunk.stop,
                                   a["r_true"], a["tau_true"], pad=chunk.pad)
    return res.without_trajectories()


def available_memory() -> int:
    """Bytes of memory available now (``MemAvailable``), or 2 GiB if unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 2 << 30


def chunk_size(bytes_per_point: int, workers: int, limit: int | None = None) -> int:
    """Points per chunk: what ``MEMORY_SHARE`` of the available memory holds for each of
    ``workers`` chunks in flight, at most :data:`CHUNK_MAX` (or ``limit``), at least 1."""
    budget = available_memory() * MEMORY_SHARE / max(1, workers)
    size = int(budget // max(1, bytes_per_point))
    return max(1, min(size, limit or CHUNK_MAX))


def _lti_bytes(n: int, m: int, N: int, periods: int, ring_ticks: int, L: int) -> int:
    """Memory per point of :func:`delaycomp.studies.batch.simulate_lti`, a generous estimate."""
    floats = ((ring_ticks // N + 2) * N * n + (L + ring_ticks // N + 3) * m
              + 3 * n * n + 2 * n * m + L * n * m + periods + 16)
    return 8 * floats * 2


def lti_point(loop) -> dict | str:
    """The batch ingredients of an LTI loop (:class:`delaycomp.system.Loop`, or the
    :class:`delaycomp.system.LtiPoint` of a grid point whose loop is the standard one by
    construction), or why not."""
    if isinstance(loop, Loop):
        why = _standard(loop, BuiltinFmu)
        if why:
            return why
    d = loop.lti
    return dict(A=d.A, B=d.B, K=d.K, T=loop.timing.T, N=loop.timing.N, r=d.r, tau=d.tau,
                r_true=d.r if d.r_true is None else d.r_true,
                tau_true=d.tau if d.tau_true is None else d.tau_true,
                x0=d.x0, u0=d.u0, mode=d.mode)


def model_point(loop) -> tuple[dict, tuple, Model] | str:
    """The batch ingredients of a model loop, its group key and model, or why not."""
    from delaycomp.maths.model import load_model

    why = _standard(loop, ModelFmu)
    if why:
        return why
    plant, ctrl = loop.by_role("plant"), loop.by_role("controller")
    if plant.source.model != ctrl.source.model:
        return "the plant and the controller are of different models"
    model = load_model(plant.source.model)
    why = batch.batchable(model)
    if why:
        return why
    cp = ctrl.parameters
    predictor = cp.get("predictor", "closed" if model.predictor is not None else "numerical")
    if predictor != "closed":
        return f"predictor={predictor} asks for the ODE-solved predictor"
    if cp.get("mode", model.control) != model.control:
        return f"mode={cp['mode']} is not the model's {model.control} control"
    x0 = [float(plant.parameters[f"x0[{i + 1}]"]) for i in range(model.n)]
    u0 = [float(cp[f"u0[{j + 1}]"]) for j in range(model.m)]
    z0 = [float(cp.get(f"z0[{i + 1}]", x0[i])) for i in range(model.n)]
    if model.control == "continuous" and z0 != x0:
        return "z0 differs from x0 (the batch starts the controller's copy at x0)"
    params = tuple(sorted((k, cp[k]) for k in model.parameters if k in cp))
    md, idl = loop.by_role("meas_delay"), loop.by_role("input_delay")
    point = dict(T=loop.T, N=loop.N, r=float(cp["r"]), tau=float(cp["tau"]),
                 r_true=float(md.parameters["delay"]),
                 tau_true=float(idl.parameters["delay"]), x0=x0, u0=u0)
    return point, (str(plant.source.model), params, bool(cp.get("pad", False))), model


def _standard(loop, kind) -> str | None:
    """Why ``loop`` is not the standard four-instance loop the batch engine runs."""
    roles = {i.role: i for i in loop.instances}
    if len(loop.instances) != 4 or len(roles) != 4:
        return "the loop is not the standard plant, delays and controller"
    for role in ("meas_delay", "input_delay"):
        if not isinstance(roles[role].source, BuiltinFmu):
            return f"the {role} is an FMU file"
    for role in ("plant", "controller"):
        if not isinstance(roles[role].source, kind):
            return f"the {role} is an FMU file"
    if roles["controller"].parameters.get("held_sample"):
        return "held_sample is set (a third-party master's timing)"
    return None


def prepare(loops: list, stop: float, backend: str, workers: int,
            limit: int | None) -> tuple[list, list[tuple[int, str]], list[str]]:
    """Chunks for the batchable points, and ``(index, reason)`` for the others.

    ``loops`` are the grid's points (:class:`delaycomp.system.Loop` or
    :class:`delaycomp.system.LtiPoint` each), or all of them as one
    :class:`delaycomp.system.LtiBatch`. Returns ``(chunks, fallback, notes)`` where each
    chunk comes with the point indices it covers: ``[(indices, Chunk), ...]``.
    """
    groups: dict[tuple, list[int]] = {}
    fallback: list[tuple[int, str]] = []
    notes: list[str] = []
    data: dict[int, dict] = {}
    models: dict[tuple, Model] = {}
    stacked: dict[tuple, dict] = {}
    if isinstance(loops, LtiBatch):  # all points in one group, already arrays
        key: tuple = ("lti", loops.A.shape[1:], loops.B.shape[1:])
        groups[key] = list(range(len(loops)))
        stacked[key] = {f.name: getattr(loops, f.name) for f in dataclasses.fields(loops)}
        loops = []
    for i, loop in enumerate(loops):
        if loop.lti is not None:
            got = lti_point(loop)
            if isinstance(got, str):
                fallback.append((i, got))
                continue
            data[i] = got
            key = ("lti", got["A"].shape, got["B"].shape)
        else:
            found = model_point(loop)
            if isinstance(found, str):
                fallback.append((i, found))
                continue
            data[i], mkey, model = found
            key = ("model", *mkey)
            models[key] = model
        groups.setdefault(key, []).append(i)
    if backend != "numpy" and any(k[0] == "model" for k in groups):
        notes.append(f"array backend {backend}: model loops run on numpy (their f, k and "
                     "step are numpy code)")
    chunks = []
    for key, idx in groups.items():
        P = len(idx)
        arr = stacked.get(key) or _arrays([data[i] for i in idx], key[0] == "lti")
        h = arr["T"] / arr["N"]
        if key[0] == "lti":
            n, m = key[1][0], key[2][1]
            Nmax = int(arr["N"].max())
            ring = int(np.max(np.rint(np.maximum(arr["r_true"], arr["tau_true"]) / h)))
            L = int(np.max(np.floor((arr["r"] + arr["tau"]) / arr["T"]))) + 2
            periods = math.ceil(stop / float(arr["T"].min()))
            per = _lti_bytes(n, m, Nmax, periods, ring, L)
        else:
            n = models[key].n
            ring = int(np.max(np.rint((arr["r_true"] + arr["tau_true"] + arr["r"]
                                       + arr["tau"] + arr["T"]) / h)))
            per = 8 * 4 * (ring * (n + 2) + int(stop / float(arr["T"].min())) + 64)
        size = chunk_size(per, workers, limit or (
            CHUNK_MAX if key[0] == "model" or backend == "numpy" else CHUNK_MAX_GPU))
        for s in range(0, P, size):
            sel = slice(s, s + size)
            part = {k: v[sel] for k, v in arr.items()}
            if key[0] == "lti":
                chunks.append((idx[sel], Chunk("lti", part, stop, backend)))
            else:
                chunks.append((idx[sel], Chunk("model", part, stop, "numpy", key[1], key[2],
                                               key[3])))
    return chunks, fallback, notes


def _arrays(points: list[dict], lti: bool) -> dict:
    """Per-point ingredients stacked into arrays (a leading axis of points)."""
    out = {key: np.array([p[key] for p in points], dtype=float)
           for key in ("T", "r", "tau", "r_true", "tau_true")}
    out["N"] = np.array([p["N"] for p in points], dtype=np.int64)
    out["x0"] = np.array([p["x0"] for p in points], dtype=float).reshape(len(points), -1)
    out["u0"] = np.array([p["u0"] for p in points], dtype=float).reshape(len(points), -1)
    if lti:
        for key in ("A", "B", "K"):
            out[key] = np.stack([p[key] for p in points])
        out["mode"] = np.array([p["mode"] for p in points], dtype=object)
    return out


def run_chunks(chunks: list, workers: int, scheduler: str | None, progress) -> list[list]:
    """Results of every chunk, in order: here, on processes, or on a Dask cluster."""
    jobs = [c for _, c in chunks]
    sizes = [len(idx) for idx, _ in chunks]
    if scheduler:
        return [r.rows() for r in on_dask(compute_chunk, jobs, scheduler, progress, sizes)]
    if workers > 1 and len(jobs) > 1:
        return [r.rows() for r in on_processes(compute_chunk, jobs, workers, progress, sizes)]
    out = []
    for job, size in zip(jobs, sizes):
        out.append(run_chunk(job))
        progress.tick(size)
    return out
