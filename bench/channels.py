"""delaycomp benchmark: Monte Carlo runs of a loop through a network channel, one core.

Run from the repository root (it writes ``BENCHMARKS-channels.md``)::

    python bench/channels.py            # 10^6 runs of each, a few minutes
    python bench/channels.py --quick    # 20 000 runs: a smoke test of the script

Issue 29, item 4: 10^6 Monte Carlo runs of Example 3.6 (``x' = x + u``, ``T = 1``,
``N = 100``, 20 s) with the measurement through a channel with uniform jitter up to 2 T
(``delay = r = 0.3``, ``jitter = 2``) and Bernoulli loss 0.3, one seed per run, on one
core (the process pinned to one CPU, BLAS on one thread), target under 60 s. Columns,
side by side in one process:

- ``paper``: the paper's controller (``run_lti_channels``);
- ``stamps``: the time-stamp controller (``run_lti_channels(stamps=True)``);
- ``per point``: the in-process engine, a few seeds of the same loop (``--per-point``),
  timed and scaled to the run count: the ratio the batch gains;

each with a packet every base step (``period = 0``, the channel's default: 2001 packets a
run) and with one packet per sample (``period = T``, a sensor that sends what it samples:
21 packets a run).

Each batch column runs the whole count once per repeat, alternately, medians reported;
the batch results are checked against the per-point runs of the sampled seeds (the
largest difference of the quadratic cost, relative). Where CuPy reaches a GPU, each column
also runs on it (``run_lti_channels(backend="cupy")``), its results compared with the
CPU's exactly; ``--cpu-runs`` times the CPU on fewer runs, scaled.
"""

from __future__ import annotations

import argparse
import copy
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from delaycomp import __version__, api  # noqa: E402
from delaycomp.maths.channel import Channel  # noqa: E402
from delaycomp.orchestrator.simulate import single_threaded_blas  # noqa: E402
from delaycomp.paper.scenarios import loop_file  # noqa: E402
from delaycomp.studies import batch, channel_kernel  # noqa: E402
from delaycomp.studies.sweep_batch import lti_point  # noqa: E402
from delaycomp.system import lti_designs  # noqa: E402
from delaycomp.system.loopfile import build  # noqa: E402

TARGET_S = 60.0
STOP = 20.0
MEAS = {"distribution": "uniform", "delay": 0.3, "jitter": 2.0, "loss_model": "bernoulli",
        "loss": 0.3}


def example_3_6() -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    return tomllib.loads(Path(loop_file("example-3.6")).read_text("utf-8"))


def design_of(data: dict, runs: int):
    one = lti_designs([lti_point(build(data, REPO, name="p"))])
    return batch.take(one, np.zeros(runs, dtype=np.int64))  # the same loop, runs times


def per_point(data: dict, seeds: list[int], stamps: bool, period: float = 0.0
              ) -> tuple[float, list[float]]:
    """Seconds per run of the in-process engine and each run's cost (the batch's sum)."""
    times, costs = [], []
    for seed in seeds:
        d = copy.deepcopy(data)
        d["meas_delay"] = {**MEAS, "seed": seed, "period": period}
        d["controller"] = {**d["controller"], "stamps": stamps}
        loop = build(d, REPO, name="c")
        t = time.perf_counter()
        res = api.run(loop, engine="inprocess", stop_time=STOP)
        times.append(time.perf_counter() - t)
        x, u = res.data[:-1, 0], res.data[:-1, 1]  # tau = 0: the plant's input is u
        costs.append(float(np.sum(0.01 * (x * x + u * u))))
    return statistics.median(times), costs


def gpu_backend():
    """CuPy's backend where it reaches a GPU, else ``None``."""
    try:
        be = batch.channel_backend("auto")
    except batch.BatchError:
        return None
    return be if be.name == "cupy" else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 000 runs, one repeat")
    ap.add_argument("--runs", type=int, default=10**6)
    ap.add_argument("--cpu-runs", type=int, default=None,
                    help="runs the CPU columns time (default --runs), scaled to --runs: a "
                         "shorter bench where a GPU runs the whole count")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--per-point", type=int, default=5, help="seeds the per-point engine runs")
    ap.add_argument("--out", type=Path, default=REPO / "BENCHMARKS-channels.md")
    args = ap.parse_args(argv)
    if args.quick:
        args.runs, args.repeats, args.per_point = 20_000, 1, 2
    cpu_runs = min(args.runs, args.cpu_runs or args.runs)
    gpu = gpu_backend()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    data = example_3_6()
    T = float(data["T"])
    #: column -> (stamps, the channel's period)
    columns = {"paper": (False, 0.0), "stamps": (True, 0.0),
               "paper, period = T": (False, T), "stamps, period = T": (True, T)}
    samples: dict[str, list[float]] = {key: [] for key in columns}
    gpu_samples: dict[str, list[float]] = {key: [] for key in columns}
    results, gpu_results = {}, {}

    def run(key, runs, backend="numpy"):
        stamps, period = columns[key]
        return batch.run_lti_channels(design_of(data, runs), STOP,
                                      meas=Channel(**MEAS, period=period),
                                      meas_seeds=np.arange(runs), stamps=stamps,
                                      backend=backend)

    warm = {}
    if gpu is not None:  # CuPy compiles each kernel on first use: not timed
        for key in columns:
            t = time.perf_counter()
            run(key, 10_000, gpu)
            warm[key] = time.perf_counter() - t
    with single_threaded_blas():
        for _ in range(args.repeats):
            for key in columns:
                print(f"{key}: {cpu_runs} runs ...", flush=True)
                t = time.perf_counter()
                results[key] = run(key, cpu_runs)
                samples[key].append(time.perf_counter() - t)
                if gpu is not None:
                    print(f"{key}: {args.runs} runs on the GPU ...", flush=True)
                    t = time.perf_counter()
                    gpu_results[key] = run(key, args.runs, gpu)
                    gpu_samples[key].append(time.perf_counter() - t)
        sampled = [int(s) for s in np.linspace(0, cpu_runs - 1, args.per_point)]
        pp = {key: per_point(data, sampled, *columns[key]) for key in samples}
    scale = args.runs / cpu_runs
    med = {k: statistics.median(v) * scale for k, v in samples.items()}
    gpu_label = gpu.device if gpu is not None else "none seen by CuPy (no GPU column)"
    lines = [
        "# Benchmark: Monte Carlo runs through a network channel (one core; a GPU)", "",
        f"delaycomp {__version__}, Python {platform.python_version()}, numpy "
        f"{np.__version__}, {platform.machine()}; draws on the CPU: "
        f"{channel_kernel.status()}; GPU: {gpu_label}; "
        f"`python bench/channels.py{' --quick' if args.quick else ''}"
        f"{f' --cpu-runs {cpu_runs}' if cpu_runs != args.runs else ''}`", "",
        f"Example 3.6 to {STOP:g} s (2001 ticks a run), the measurement through uniform "
        f"jitter {MEAS['jitter']:g} s (2 T) and Bernoulli loss {MEAS['loss']:g}, one seed "
        f"a run, a packet every base step (period 0) or one per sample (period = T); "
        f"{args.runs} runs, {args.repeats} repeat(s), medians; one CPU"
        + (f" (timed on {cpu_runs} runs, scaled)" if cpu_runs != args.runs else "")
        + (", and the GPU (CuPy) on every run" if gpu is not None else "") + ".", "",
        "| controller | batch, 1 core [s] | runs/s | per point [ms/run] | ratio | "
        "10^6 runs, 1 core [s] | batch, GPU [s] | GPU vs 1 core | GPU = CPU | "
        "cost vs per point |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for key in samples:
        per, costs = pp[key]
        got = results[key].cost
        assert got is not None
        diff = max(abs(float(got[s]) - c) / max(1.0, abs(c)) for s, c in zip(sampled, costs))
        rate = args.runs / med[key]
        if gpu is not None:
            g = statistics.median(gpu_samples[key])
            same = all(np.array_equal(getattr(gpu_results[key], f)[:cpu_runs],
                                      getattr(results[key], f), equal_nan=True)
                       for f in ("cost", "rho", "stable", "final_norm", "peak_norm"))
            gpu_cells = (f"{g:.2f} | {med[key] / g:.0f}x | "
                         f"{'bit for bit' if same else 'DIFFERENT'} ({cpu_runs} runs)")
        else:
            gpu_cells = "- | - | -"
        lines.append(f"| {key} | {med[key]:.2f} | {rate:.0f} | {per * 1e3:.1f} | "
                     f"{per * rate:.0f}x | {1e6 / rate:.1f} | {gpu_cells} | {diff:.1e} |")
    lines += ["", f"Target: 10^6 runs under {TARGET_S:g} s on one core."]
    if gpu is not None:
        lines += ["", "GPU: the same code on CuPy's arrays, chunked in device memory "
                  f"(`GPU_CHANNEL_BYTES`); a first call of 10 000 runs per column compiles "
                  f"CuPy's kernels and is not timed ({', '.join(f'{v:.1f}' for v in warm.values())}"
                  " s). `GPU = CPU`: the cost, rho, stable flag and norms of the runs the CPU "
                  "timed, compared exactly."]
    text = "\n".join(lines) + "\n"
    args.out.write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
