"""The batch engine behind ``delaycomp sweep``: grid points turned into batch ingredients.

Today's scenarios describe a loop as a :class:`~delaycomp.scenarios.LoopSpec`; this module
takes from each resolved point what :mod:`delaycomp.batch` needs (matrices and timing for
LTI scenarios; the model file, its parameters and timing for model scenarios), groups the
points that can share a batch (same dimensions, same model and string parameters), cuts the
groups into chunks that fit in memory, and runs the chunks here, on local worker processes
or on a Dask cluster. Every point of a chunk is computed independently of the others, so
the results do not depend on the chunking or on where a chunk runs (tested).

A point that cannot be batched (a model without ``BATCH = True`` or without an exact
``step``, or ``predictor=numerical``, which asks for the ODE-solved predictor) is returned
as ``None`` with the reason, for the per-point engine.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from . import batch

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
    """The sweep's metric dicts of every point of ``chunk`` (a top-level function)."""
    a = chunk.arrays
    if chunk.kind == "lti":
        res = batch.simulate_lti(a["A"], a["B"], a["K"], a["T"], a["N"], a["r"], a["tau"],
                                 a["x0"], a["u0"], list(a["mode"]), chunk.stop, a["r_true"],
                                 a["tau_true"], backend=chunk.backend)
    else:
        from .model import load_model

        model = load_model(chunk.model_path)
        res = batch.simulate_model(model, model.params(**dict(chunk.params)), a["T"], a["N"],
                                   a["r"], a["tau"], a["x0"], a["u0"], chunk.stop,
                                   a["r_true"], a["tau_true"], pad=chunk.pad)
    return res.rows()


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
    """Memory per point of :func:`delaycomp.batch.simulate_lti`, a generous estimate."""
    floats = ((ring_ticks // N + 2) * N * n + (L + ring_ticks // N + 3) * m
              + 3 * n * n + 2 * n * m + L * n * m + periods + 16)
    return 8 * floats * 2


def prepare(sc, points: list[dict], stop: float, backend: str,
            workers: int, limit: int | None) -> tuple[list, list[tuple[int, str]], list[str]]:
    """Chunks for the batchable points, and ``(index, reason)`` for the others.

    Returns ``(chunks, fallback, notes)`` where each chunk comes with the point indices it
    covers: ``[(indices, Chunk), ...]``.
    """
    groups: dict[tuple, list[int]] = {}
    fallback: list[tuple[int, str]] = []
    notes: list[str] = []
    extra: dict[tuple, dict] = {}
    mats: dict[int, list] = {}
    for i, p in enumerate(points):
        if sc.lti is not None:
            mats[i] = [np.atleast_2d(np.asarray(M, dtype=float)) for M in sc.lti(p)]
            key = ("lti", mats[i][0].shape, mats[i][1].shape)
            extra.setdefault(key, {})
        else:
            spec = sc.make(p)
            path = spec.instances["plant"][1]["model"]
            from .model import load_model

            model = load_model(path)
            why = batch.batchable(model)
            if why is None and p.get("predictor") == "numerical":
                why = "predictor=numerical asks for the ODE-solved predictor"
            if why is not None:
                fallback.append((i, why))
                continue
            params = tuple(sorted((k, p[k]) for k in ("law", "p") if k in p))
            key = ("model", str(path), params, bool(p.get("pad", False)))
            extra.setdefault(key, {"model": model})
        groups.setdefault(key, []).append(i)
    if backend != "numpy" and any(k[0] == "model" for k in groups):
        notes.append(f"array backend {backend}: model loops run on numpy (their f, k and "
                     "step are numpy code)")
    chunks = []
    for key, idx in groups.items():
        P = len(idx)
        if key[0] == "lti":
            arr = _lti_arrays([mats[i] for i in idx], [points[i] for i in idx])
            n, m = key[1][0], key[2][1]
            Nmax = int(arr["N"].max())
            h = arr["T"] / arr["N"]
            ring = int(np.max(np.rint(np.maximum(arr["r_true"], arr["tau_true"]) / h)))
            L = int(np.max(np.floor((arr["r"] + arr["tau"]) / arr["T"]))) + 2
            periods = math.ceil(stop / float(arr["T"].min()))
            per = _lti_bytes(n, m, Nmax, periods, ring, L)
        else:
            arr = _model_arrays([points[i] for i in idx])
            n = extra[key]["model"].n
            h = arr["T"] / arr["N"]
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


def _lti_arrays(mats: list, points: list[dict]) -> dict:
    n, m = mats[0][1].shape
    return {
        "A": np.stack([M[0] for M in mats]), "B": np.stack([M[1] for M in mats]),
        "K": np.stack([M[2].reshape(m, n) for M in mats]),
        "T": np.array([p["T"] for p in points], dtype=float),
        "N": np.array([p["N"] for p in points], dtype=np.int64),
        "r": np.array([p["r"] for p in points], dtype=float),
        "tau": np.array([p["tau"] for p in points], dtype=float),
        "r_true": np.array([p["r"] if p.get("r_true") is None else p["r_true"]
                            for p in points], dtype=float),
        "tau_true": np.array([p["tau"] if p.get("tau_true") is None else p["tau_true"]
                              for p in points], dtype=float),
        "x0": np.array([np.ravel(p["x0"]) for p in points], dtype=float).reshape(-1, n),
        "u0": np.array([np.ravel(p["u0"]) for p in points], dtype=float).reshape(-1, m),
        "mode": np.array([p["mode"] for p in points], dtype=object),
    }


def _model_arrays(points: list[dict]) -> dict:
    return {
        "T": np.array([p["T"] for p in points], dtype=float),
        "N": np.array([p["N"] for p in points], dtype=np.int64),
        "r": np.array([p["r"] for p in points], dtype=float),
        "tau": np.array([p["tau"] for p in points], dtype=float),
        "r_true": np.array([p["r"] if p.get("r_true") is None else p["r_true"]
                            for p in points], dtype=float),
        "tau_true": np.array([p["tau"] if p.get("tau_true") is None else p["tau_true"]
                              for p in points], dtype=float),
        "x0": np.array([np.ravel(p["x0"]) for p in points], dtype=float),
        "u0": np.array([np.ravel(p["u0"]) for p in points], dtype=float),
    }


def run_chunks(chunks: list, workers: int, scheduler: str | None, progress) -> list[list]:
    """Results of every chunk, in order: here, on processes, or on a Dask cluster."""
    jobs = [c for _, c in chunks]
    if scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise RuntimeError("--scheduler needs Dask: pip install 'delaycomp[dask]'") from None
        with Client(scheduler) as client:
            out = client.gather(client.map(run_chunk, jobs, pure=False))
        progress.tick(sum(len(i) for i, _ in chunks))
        return out
    if workers > 1 and len(jobs) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        from .sweep import _worker_init

        ctx = multiprocessing.get_context("spawn")
        out = []
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx,
                                 initializer=_worker_init) as pool:
            for (idx, _), res in zip(chunks, pool.map(run_chunk, jobs)):
                out.append(res)
                progress.tick(len(idx))
        return out
    out = []
    for idx, job in chunks:
        out.append(run_chunk(job))
        progress.tick(len(idx))
    return out
