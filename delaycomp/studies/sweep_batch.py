"""The batch engine behind ``delaycomp sweep``: grid points turned into batch ingredients.

Each grid point is a typed loop (``delaycomp.system.Loop``, from a scenario or a loop
file); this module takes from it what ``delaycomp.studies.batch`` needs (the LTI design and
timing; or the model file, its parameters and timing), groups the points that can share a
batch (same dimensions, same model and string parameters), stacks each group into the
engine's typed batch (``delaycomp.system.LtiBatch``, which a scenario or a loop file
may also hand over whole, or ``delaycomp.studies.batch.ModelBatch``), cuts the groups
into chunks that fit in memory, and runs the chunks here, on local worker processes or on
a Dask cluster. Every point of a chunk is computed independently of the others, so
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
    """One batch: picklable, for worker processes and Dask. ``points`` is a
    ``delaycomp.system.LtiBatch`` (an LTI chunk, run on ``backend``) or a
    ``delaycomp.studies.batch.ModelBatch`` of the model file ``model_path`` with its
    parameters ``params`` and padding ``pad`` (a model chunk, run on numpy)."""

    points: LtiBatch | batch.ModelBatch
    stop: float
    backend: str
    model_path: str | None = None
    params: tuple = ()
    pad: bool = False

    @property
    def kind(self) -> str:
        """``lti`` or ``model``."""
        return "lti" if isinstance(self.points, LtiBatch) else "model"


def run_chunk(chunk: Chunk) -> list[dict]:
    """The sweep's metric dicts of every point of ``chunk``."""
    return compute_chunk(chunk).rows()


def compute_chunk(chunk: Chunk) -> batch.BatchResult:
    """The metrics of every point of ``chunk`` as arrays (a top-level function: worker
    processes and Dask run it and send the arrays back, which pickle much faster than one
    dict per point)."""
    if isinstance(chunk.points, LtiBatch):
        res = batch.run_lti(chunk.points, chunk.stop, backend=chunk.backend)
    else:
        from delaycomp.maths.model import load_model

        # a model chunk names its model file (``prepare`` sets it)
        model = load_model(cast(str, chunk.model_path))
        res = batch.run_model(model, model.params(**dict(chunk.params)), chunk.points,
                              chunk.stop, pad=chunk.pad)
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
    ``workers`` chunks in flight, at most ``CHUNK_MAX`` (or ``limit``), at least 1."""
    budget = available_memory() * MEMORY_SHARE / max(1, workers)
    size = int(budget // max(1, bytes_per_point))
    return max(1, min(size, limit or CHUNK_MAX))


def _lti_bytes(n: int, m: int, N: int, periods: int, ring_ticks: int, L: int) -> int:
    """Memory per point of ``delaycomp.studies.batch.run_lti``, a generous estimate."""
    floats = ((ring_ticks // N + 2) * N * n + (L + ring_ticks // N + 3) * m
              + 3 * n * n + 2 * n * m + L * n * m + periods + 16)
    return 8 * floats * 2


def lti_point(loop) -> dict | str:
    """The batch ingredients of an LTI loop (``delaycomp.system.Loop``, or the
    ``delaycomp.system.LtiPoint`` of a grid point whose loop is the standard one by
    construction), or why not."""
    if isinstance(loop, Loop):
        why = _standard(loop, BuiltinFmu)
        if why:
            return why
    d = loop.lti
    if d.pad:  # run by the per-point engine, which has the padded controller
        return "controller.pad = true (the batch engine has no padded LTI controller)"
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


def _what(source) -> str:
    """An instance's source in words, for the reason a loop is not batched."""
    if isinstance(source, BuiltinFmu):
        return f"delaycomp's {source.kind.replace('_', ' ')} FMU"
    if isinstance(source, ModelFmu):
        return "a model file's"
    return "an FMU file"


def _standard(loop, kind) -> str | None:
    """Why ``loop`` is not the standard four-instance loop the batch engine runs (constant
    delays, the paper's controller)."""
    roles = {i.role: i for i in loop.instances}
    if len(loop.instances) != 4 or len(roles) != 4:
        return "the loop is not the standard plant, delays and controller"
    for role in ("meas_delay", "input_delay"):
        src = roles[role].source
        if not (isinstance(src, BuiltinFmu) and src.kind == "delay"):
            return f"the {role} is {_what(src)}"
    for role in ("plant", "controller"):
        src = roles[role].source
        if not isinstance(src, kind) or (isinstance(src, BuiltinFmu)
                                         and src.kind not in ("plant", "controller")):
            return f"the {role} is {_what(src)}"
    if roles["controller"].parameters.get("held_sample"):
        return "held_sample is set (a third-party master's timing)"
    return None


def prepare(loops: list | LtiBatch, stop: float, backend: str, workers: int,
            limit: int | None) -> tuple[list, list[tuple[int, str]], list[str]]:
    """Chunks for the batchable points, and ``(index, reason)`` for the others.

    ``loops`` are the grid's points (``delaycomp.system.Loop`` or
    ``delaycomp.system.LtiPoint`` each), or all of them as one
    ``delaycomp.system.LtiBatch`` (one group, cut into chunks as it is). Returns
    ``(chunks, fallback, notes)`` where each chunk comes with the point indices it covers:
    ``[(indices, Chunk), ...]``. ``groups`` then ``cut``.
    """
    found, fallback, models = groups(loops)
    chunks, notes = cut(found, models, stop, backend, workers, limit)
    return chunks, fallback, notes


Groups = dict[tuple, tuple[list[int], LtiBatch | batch.ModelBatch]]


def groups(loops: list | LtiBatch) -> tuple[Groups, list[tuple[int, str]], dict[tuple, Model]]:
    """The batchable points of ``loops`` (as ``prepare`` takes them) in groups that
    share a batch, each group's indices and points stacked (an LTI group keyed by its
    dimensions, a model's by its model file, string parameters and padding); ``(index,
    reason)`` for the others; each model group's model. Groups of several parts of a grid
    may be joined (``join``) before they are cut into chunks (``cut``).

    Examples
    --------
    >>> from delaycomp.paper.scenarios import get
    >>> sc = get("example-3.6")
    >>> pts = sc.resolve_grid([], [("r=0",), ("r=0.5",)]).designs
    >>> found, fallback, models = groups(pts)
    >>> [(key, idx, len(points)) for key, (idx, points) in found.items()], fallback
    ([(('lti', (1, 1), (1, 1)), [0, 1], 2)], [])
    """
    if isinstance(loops, LtiBatch):  # all points in one group, already arrays
        key = ("lti", loops.A.shape[1:], loops.B.shape[1:])
        return {key: (list(range(len(loops))), loops)}, [], {}
    return _groups(loops)


def join(parts: list[LtiBatch | batch.ModelBatch]) -> LtiBatch | batch.ModelBatch:
    """The points of a group's ``parts`` (of one type, one key of ``groups``) in one
    batch, in order."""
    if len(parts) == 1:
        return parts[0]
    kind = type(parts[0])
    return kind(*(np.concatenate([getattr(p, f.name) for p in parts])
                  for f in dataclasses.fields(kind)))


def cut(found: Groups, models: dict[tuple, Model], stop: float, backend: str, workers: int,
        limit: int | None) -> tuple[list, list[str]]:
    """The groups ``found`` (``groups``) cut into chunks: ``[(indices, Chunk), ...]``
    and notes (model loops on numpy where ``backend`` is another library)."""
    notes: list[str] = []
    if backend != "numpy" and any(k[0] == "model" for k in found):
        notes.append(f"array backend {backend}: model loops run on numpy (their f, k and "
                     "step are numpy code)")
    chunks = []
    for key, (idx, points) in found.items():
        if isinstance(points, LtiBatch):
            per = _lti_batch_bytes(points, stop)
            cap = CHUNK_MAX if backend == "numpy" else CHUNK_MAX_GPU
        else:
            per = _model_batch_bytes(points, models[key].n, stop)
            cap = CHUNK_MAX
        size = chunk_size(per, workers, limit or cap)
        for s in range(0, len(idx), size):
            sel = slice(s, s + size)
            part = batch.take(points, sel)
            if isinstance(part, LtiBatch):
                chunks.append((idx[sel], Chunk(part, stop, backend)))
            else:
                chunks.append((idx[sel], Chunk(part, stop, "numpy", key[1], key[2], key[3])))
    return chunks, notes


def _groups(loops: list) -> tuple[dict[tuple, tuple[list[int], LtiBatch | batch.ModelBatch]],
                                  list[tuple[int, str]], dict[tuple, Model]]:
    """The batchable points in groups that share a batch (LTI: the same dimensions; a
    model: the same model file, string parameters and padding), each group's indices and
    points stacked; ``(index, reason)`` for the others; each model group's model."""
    groups: dict[tuple, list[int]] = {}
    fallback: list[tuple[int, str]] = []
    data: dict[int, dict] = {}
    models: dict[tuple, Model] = {}
    for i, loop in enumerate(loops):
        if loop.lti is not None:
            got = lti_point(loop)
            if isinstance(got, str):
                fallback.append((i, got))
                continue
            data[i] = got
            key: tuple = ("lti", got["A"].shape, got["B"].shape)
        else:
            found = model_point(loop)
            if isinstance(found, str):
                fallback.append((i, found))
                continue
            data[i], mkey, model = found
            key = ("model", *mkey)
            models[key] = model
        groups.setdefault(key, []).append(i)
    stacked = {key: (idx, _stack([data[i] for i in idx], key[0] == "lti"))
               for key, idx in groups.items()}
    return stacked, fallback, models


def _lti_batch_bytes(points: LtiBatch, stop: float) -> int:
    """Memory per point of a chunk of ``points`` (``_lti_bytes`` of the largest)."""
    h = points.T / points.N
    n, m = points.B.shape[1:]
    ring = int(np.max(np.rint(np.maximum(points.r_true, points.tau_true) / h)))
    L = int(np.max(np.floor((points.r + points.tau) / points.T))) + 2
    periods = math.ceil(stop / float(points.T.min()))
    return _lti_bytes(n, m, int(points.N.max()), periods, ring, L)


def _model_batch_bytes(points: batch.ModelBatch, n: int, stop: float) -> int:
    """Memory per point of a chunk of ``points`` of a model with ``n`` states, a generous
    estimate."""
    h = points.T / points.N
    ring = int(np.max(np.rint((points.r_true + points.tau_true + points.r + points.tau
                               + points.T) / h)))
    return 8 * 4 * (ring * (n + 2) + int(stop / float(points.T.min())) + 64)


def _stack(points: list[dict], lti: bool) -> LtiBatch | batch.ModelBatch:
    """Per-point ingredients stacked into arrays (a leading axis of points): an
    ``LtiBatch`` or a ``ModelBatch``."""
    out = {key: np.array([p[key] for p in points], dtype=float)
           for key in ("T", "r", "tau", "r_true", "tau_true")}
    out["N"] = np.array([p["N"] for p in points], dtype=np.int64)
    out["x0"] = np.array([p["x0"] for p in points], dtype=float).reshape(len(points), -1)
    out["u0"] = np.array([p["u0"] for p in points], dtype=float).reshape(len(points), -1)
    if not lti:
        return batch.ModelBatch(**out)
    for key in ("A", "B", "K"):
        out[key] = np.stack([p[key] for p in points])
    out["mode"] = np.array([p["mode"] for p in points], dtype=object)
    return LtiBatch(**out)


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
