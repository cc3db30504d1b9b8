"""delaycomp benchmark: the batch engine against the per-point engine, side by side.

Run from the repository root (it writes ``BENCHMARKS-batch.md``)::

    python bench/batch.py            # the full run, several minutes
    python bench/batch.py --quick    # small grids, one repeat: a smoke test of the script

Grids (the issue's):

1. Example 3.6, 50 x 50 (``k`` = 0.5..3, ``r`` = 0..0.98, uncompensated, 20 s, N = 100);
2. Example 2.4, 30 x 30 (``r``, ``tau`` = 0..0.58, continuous input, 30 s, N = 100);
3. Proposition 4.2, 30 x 30 initial states (``x``, ``y`` = -2..2, ``theta`` = 0.5, 10 s);
4. Example 3.6, 1000 x 1000 = 10^6 points, the batch engine alone on one core.

Columns: the per-point in-process engine on one worker (``--per-point-sample`` points of
the grid, evenly spread, timed and scaled to the grid: running all of them would take
hours for Example 2.4; ``--per-point-sample 0`` runs every point), the batch engine on one
core (one process, BLAS on one thread), the batch engine on all cores (one chunk per
core, worker processes), and on a GPU when CuPy or JAX sees one. The compared runs are
timed alternately, repeat after repeat, medians reported. Every batch result is checked
against the per-point engine on the sampled points (the largest difference of ``rho`` is
reported beside the timings).
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from delaycomp import __version__  # noqa: E402
from delaycomp.maths.model import load_model  # noqa: E402
from delaycomp.orchestrator.simulate import run_loop, single_threaded_blas  # noqa: E402
from delaycomp.paper import scenarios  # noqa: E402
from delaycomp.paper.models import path as model_path  # noqa: E402
from delaycomp.studies import batch, pool, sweep  # noqa: E402
from delaycomp.studies.axes import format_value, parse_grid, points  # noqa: E402
from delaycomp.studies.sweep import SweepOptions  # noqa: E402
from delaycomp.system import LtiBatch  # noqa: E402

TARGET_3_6 = 1000.0
TARGET_2_4 = 50.0
TARGET_MILLION_S = 60.0


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def per_point_rows(name: str, point_sets: list[list[str]], stop: float) -> tuple[float, list]:
    """Seconds per point (median) of the in-process engine, and its metric rows."""
    sc = scenarios.get(name)
    times, rows = [], []
    with single_threaded_blas():
        for sets in point_sets:
            p = sc.resolve(sets)
            spec = sc.make(p)
            dt, res = timed(lambda spec=spec: run_loop(spec, stop, engine="inprocess"))
            rows.append(sweep.result_metrics(spec, res))
            times.append(dt)
    return statistics.median(times), rows


def sample(count: int, P: int, k: int) -> list[int]:
    if k <= 0 or k >= P:
        return list(range(P))
    return sorted({round(float(i)) for i in np.linspace(0, P - 1, k)})


def rho_diff(a: list[dict], b: list[dict]) -> float:
    """Largest |rho| difference where both are finite and not dead-beat noise."""
    d = 0.0
    for x, y in zip(a, b):
        if y["deadbeat_time"] is None and math.isfinite(y["rho"]):
            d = max(d, abs(x["rho"] - y["rho"]) / max(1.0, abs(y["rho"])))
        elif x["stable"] != y["stable"]:
            return math.inf
    return d


def gpu_backend() -> str | None:
    try:
        be = batch.get_backend("auto")
    except batch.BatchError:
        return None
    return be.name if be.device != "cpu" else None


# -- the sweep grids ---------------------------------------------------------------------

def bench_sweep(label, name, sets, grids, stop, repeats, k_sample, cores, gpu):
    axes = [parse_grid(g) for g in grids]
    pts = points(axes)
    P = len(pts)
    names = [a.name for a in axes]
    idx = sample(P, P, k_sample)
    point_sets = [[*sets, *(f"{n}={format_value(v)}" for n, v in zip(names, pts[i]))]
                  for i in idx]
    def batch_rows(**options):
        return sweep.run_sweep(name, axes, sets, SweepOptions(stop=stop, engine="batch",
                                                              **options))

    runs = {
        "batch_1": lambda: batch_rows(workers=1),
        "batch_all": lambda: batch_rows(workers=cores, chunk=max(1, math.ceil(P / cores))),
    }
    if gpu:
        runs["batch_gpu"] = lambda: batch_rows(array_backend=gpu)
    from delaycomp.studies import sweep_batch
    sc = scenarios.get(name)
    loops = [sc.loop([*sets, *(f"{n}={format_value(v)}" for n, v in zip(names, pt))])
             for pt in pts]
    chunks, fallback, _ = sweep_batch.prepare(loops, stop, "numpy", 1, None)
    assert not fallback
    samples = {key: [] for key in (*runs, "per_point", "engine_1")}
    results = {}
    pp_rows = None
    for _ in range(repeats):
        for key, fn in runs.items():
            dt, results[key] = timed(fn)
            samples[key].append(dt)
        dt, _ = timed(lambda: sweep_batch.run_chunks(chunks, 1, None, pool.Progress(P)))
        samples["engine_1"].append(dt)
        per, pp_rows = per_point_rows(name, point_sets, stop)
        samples["per_point"].append(per * P)
    med = {k: statistics.median(v) for k, v in samples.items()}
    diff = max(rho_diff([results[k][i] for i in idx], pp_rows) for k in runs)
    return dict(label=label, P=P, sampled=len(idx), diff=diff, **med)


def bench_proposition_4_2(repeats, k_sample, cores, side):
    """A grid over initial states: the API (a sweep grid holds scalars; x0 is a vector)."""
    name, stop = "proposition-4.2", 10.0
    sc = scenarios.get(name)
    model = load_model(model_path("proposition_4_2"))
    xs = np.linspace(-2, 2, side)
    x0 = np.array([(x, y, 0.5) for x in xs for y in xs])
    P = len(x0)
    base = sc.resolve([])

    def run(workers):
        from delaycomp.studies import sweep_batch
        pts = batch.ModelBatch(T=np.full(P, base["T"]), N=np.full(P, base["N"]),
                               r=np.full(P, base["r"]), tau=np.full(P, base["tau"]),
                               r_true=np.full(P, base["r"]), tau_true=np.full(P, base["tau"]),
                               x0=x0, u0=np.zeros((P, 2)))
        size = max(1, math.ceil(P / workers))
        chunks = [(list(range(s, min(P, s + size))),
                   sweep_batch.Chunk(batch.take(pts, slice(s, s + size)), stop, "numpy",
                                     str(model.source), (("law", "corrected"),), False))
                  for s in range(0, P, size)]
        out = sweep_batch.run_chunks(chunks, workers, None, pool.Progress(P))
        return [row for rows in out for row in rows]

    idx = sample(P, P, k_sample)
    point_sets = [[f"x0={float(x0[i][0])!r},{float(x0[i][1])!r},0.5"] for i in idx]
    samples = {"batch_1": [], "batch_all": [], "per_point": []}  # batch_1 is the engine
    results = {}
    pp_rows = None
    for _ in range(repeats):
        dt, results["batch_1"] = timed(lambda: run(1))
        samples["batch_1"].append(dt)
        dt, results["batch_all"] = timed(lambda: run(cores))
        samples["batch_all"].append(dt)
        per, pp_rows = per_point_rows(name, point_sets, stop)
        samples["per_point"].append(per * P)
    med = {k: statistics.median(v) for k, v in samples.items()}
    med["engine_1"] = med["batch_1"]
    diff = max(rho_diff([results[k][i] for i in idx], pp_rows) for k in results)
    return dict(label=f"Proposition 4.2, {side} x {side} initial states", P=P,
                sampled=len(idx), diff=diff, **med)


def bench_million(side, gpu, cores):
    """The 10^6-point map of Example 3.6, the batch engine alone (chunks, one core)."""
    from threadpoolctl import threadpool_limits

    ks = np.linspace(0.5, 3.0, side)
    rs = np.round(np.linspace(0.0, 0.98, side) * 100) / 100  # on the base grid h = 0.01
    K = -np.repeat(ks, side).reshape(-1, 1, 1)
    R = np.tile(rs, side)
    P = len(R)
    size = 16384
    out = {}
    with threadpool_limits(limits=1, user_api="blas"):
        t = time.perf_counter()
        stable = 0
        for s in range(0, P, size):
            res = batch.simulate_lti([[1.0]], [[1.0]], K[s:s + size], 1.0, 100, R[s:s + size],
                                     0.0, 1.0, 0.0, "uncompensated", 20.0)
            stable += int(res.stable.sum())
        out["cpu"] = time.perf_counter() - t
    if cores > 1:
        from delaycomp.studies import sweep_batch
        chunks = []
        for s in range(0, P, size):
            n_s = len(R[s:s + size])
            design = LtiBatch(A=np.ones((n_s, 1, 1)), B=np.ones((n_s, 1, 1)), K=K[s:s + size],
                              T=np.ones(n_s), N=np.full(n_s, 100), r=R[s:s + size],
                              tau=np.zeros(n_s), x0=np.ones((n_s, 1)), u0=np.zeros((n_s, 1)),
                              mode=np.array(["uncompensated"] * n_s, dtype=object),
                              r_true=R[s:s + size], tau_true=np.zeros(n_s))
            chunks.append((list(range(s, s + n_s)),
                           sweep_batch.Chunk(design, 20.0, "numpy")))
        t = time.perf_counter()
        rows = sweep_batch.run_chunks(chunks, cores, None, pool.Progress(P))
        out["all"] = time.perf_counter() - t
        out["all_stable_equal"] = sum(r["stable"] for rr in rows for r in rr) == stable
    # end to end, as `delaycomp sweep` runs it (every point resolved and validated, rows)
    axes = [sweep.Axis("k", tuple(float(k) for k in ks)), sweep.Axis("r", tuple(
        float(r) for r in rs))]
    with threadpool_limits(limits=1, user_api="blas"):
        t = time.perf_counter()
        rows = sweep.run_sweep("example-3.6", axes, ["mode=uncompensated"],
                               SweepOptions(stop=20.0, engine="batch", workers=1, verbosity=0))
        out["end_to_end"] = time.perf_counter() - t
    out["end_to_end_stable_equal"] = sum(r["stable"] for r in rows) == stable
    del rows
    if gpu:
        t = time.perf_counter()
        res = batch.simulate_lti([[1.0]], [[1.0]], K, 1.0, 100, R, 0.0, 1.0, 0.0,
                                 "uncompensated", 20.0, backend=gpu)
        out["gpu"] = time.perf_counter() - t
        out["gpu_stable_equal"] = int(res.stable.sum()) == stable
    out["P"] = P
    out["stable"] = stable
    return out


# -- report ----------------------------------------------------------------------------------

def report(rows, million, gpu, args, cores) -> str:
    import scipy

    sampled = ("every point" if args.per_point_sample <= 0
               else f"{args.per_point_sample} points per grid, scaled")
    lines = [
        "# Batch engine benchmark",
        "",
        f"Written by `python bench/batch.py{' --quick' if args.quick else ''}` "
        f"(delaycomp {__version__}).",
        "",
        f"- machine: {platform.machine()}, {cores} cores ({os.cpu_count()} logical), "
        f"{platform.system()} {platform.release()}",
        f"- Python {platform.python_version()}, numpy {np.__version__}, scipy "
        f"{scipy.__version__}",
        f"- GPU: {gpu or 'none seen by CuPy or JAX (no GPU column)'}",
        f"- repeats: {args.repeats} (medians); per-point engine: "
        f"{sampled}",
        "",
        "| grid | points | per-point, 1 worker [s] | batch, 1 core [s] | batch engine alone, "
        "1 core [s] | batch, all cores [s] | batch, GPU [s] | 1 core vs per-point | engine "
        "alone vs per-point | target | max rel. rho diff |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    targets = {"Example 3.6": TARGET_3_6, "Example 2.4": TARGET_2_4}
    for r in rows:
        ratio = r["per_point"] / r["batch_1"]
        target = next((t for key, t in targets.items() if r["label"].startswith(key)), None)
        verdict = "-" if target is None else (
            f">= {target:g}x: not judged (--quick)" if args.quick else
            f">= {target:g}x: {'met' if ratio >= target else 'NOT met'}")
        gpu_cell = f"{r['batch_gpu']:.3f}" if "batch_gpu" in r else "-"
        lines.append(f"| {r['label']} | {r['P']} | {r['per_point']:.1f} | {r['batch_1']:.3f} | "
                     f"{r['engine_1']:.3f} | {r['batch_all']:.3f} | {gpu_cell} | "
                     f"{ratio:.0f}x | {r['per_point'] / r['engine_1']:.0f}x | {verdict} | "
                     f"{r['diff']:.1e} |")
    lines += [
        "",
        f"Example 3.6 map of {million['P']} points (20 s, N = 100, the batch engine "
        f"in chunks of 16384 on one core): {million['cpu']:.1f} s "
        + ("(--quick: the 10^6 target is not judged); " if args.quick else
           f"(target for 10^6 points < {TARGET_MILLION_S:g} s: "
           f"{'met' if million['cpu'] < TARGET_MILLION_S else 'NOT met'}); ")
        + f"{million['stable']} stable points. End to end through `run_sweep` on one "
        f"core (every point resolved and validated, one row each, as `delaycomp sweep` "
        f"runs it): {million['end_to_end']:.1f} s"
        + ("" if args.quick else
           f" (target < {TARGET_MILLION_S:g} s: "
           f"{'met' if million['end_to_end'] < TARGET_MILLION_S else 'NOT met'})")
        + f", same stable count: {million['end_to_end_stable_equal']}."
        + (f" On all {cores} cores (worker processes, same chunks): {million['all']:.1f} s, "
           f"same stable count: {million['all_stable_equal']}." if "all" in million else "")
        + (f" On the GPU ({gpu}, one chunk): {million['gpu']:.2f} s, same stable count: "
           f"{million['gpu_stable_equal']}." if "gpu" in million else " No GPU measured."),
        "",
        "Times are wall-clock seconds of `run_sweep` end to end (resolving every point, "
        "building the batch, the runs, the metrics; for Proposition 4.2, whose grid is over "
        "a vector parameter, the chunks through the API), and of the batch engine alone "
        "(the chunks, already built), as for the 10^6 map. The target column judges the "
        "end-to-end ratio. The all-cores column spawns one worker process per core (a "
        "second or more of start-up on a small grid). "
        "The per-point column is the median time of the sampled points times the grid size. "
        "The last column compares each batch run with the per-point engine on the sampled "
        "points (dead-beat points, whose rho is round-off noise, compare by verdict).",
    ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small grids, one repeat")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--per-point-sample", type=int, default=20,
                    help="points of each grid the per-point engine runs (0: all)")
    ap.add_argument("--out", type=Path, default=REPO / "BENCHMARKS-batch.md")
    args = ap.parse_args(argv)
    if args.quick:
        args.repeats = 1
        args.per_point_sample = min(args.per_point_sample, 3) or 3
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)
    gpu = gpu_backend()
    side36, side24, side42, million = (6, 4, 4, 100) if args.quick else (50, 30, 30, 1000)
    rows = []
    print("Example 3.6 ...", flush=True)
    rows.append(bench_sweep(f"Example 3.6, {side36} x {side36} (k, r)", "example-3.6",
                            ["mode=uncompensated"],
                            [f"k=0.5:3:{side36}", f"r=0:{0.02 * (side36 - 1):.2f}:{side36}"],
                            20.0, args.repeats, args.per_point_sample, cores, gpu))
    print("Example 2.4 ...", flush=True)
    rows.append(bench_sweep(f"Example 2.4, {side24} x {side24} (r, tau)", "example-2.4", [],
                            [f"r=0:{0.02 * (side24 - 1):.2f}:{side24}",
                             f"tau=0:{0.02 * (side24 - 1):.2f}:{side24}"],
                            30.0, args.repeats, args.per_point_sample, cores, gpu))
    print("Proposition 4.2 ...", flush=True)
    rows.append(bench_proposition_4_2(args.repeats, args.per_point_sample, cores, side42))
    print("10^6 map ...", flush=True)
    mil = bench_million(million, gpu, cores)
    text = report(rows, mil, gpu, args, cores)
    args.out.write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
