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
largest difference of the quadratic cost, relative).
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
from delaycomp.studies import batch  # noqa: E402
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 000 runs, one repeat")
    ap.add_argument("--runs", type=int, default=10**6)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--per-point", type=int, default=5, help="seeds the per-point engine runs")
    ap.add_argument("--out", type=Path, default=REPO / "BENCHMARKS-channels.md")
    args = ap.parse_args(argv)
    if args.quick:
        args.runs, args.repeats, args.per_point = 20_000, 1, 2
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    data = example_3_6()
    design = design_of(data, args.runs)
    T = float(data["T"])
    #: column -> (stamps, the channel's period)
    columns = {"paper": (False, 0.0), "stamps": (True, 0.0),
               "paper, period = T": (False, T), "stamps, period = T": (True, T)}
    seeds = np.arange(args.runs)
    samples: dict[str, list[float]] = {key: [] for key in columns}
    results = {}
    with single_threaded_blas():
        for _ in range(args.repeats):
            for key, (stamps, period) in columns.items():
                print(f"{key}: {args.runs} runs ...", flush=True)
                t = time.perf_counter()
                results[key] = batch.run_lti_channels(design, STOP,
                                                      meas=Channel(**MEAS, period=period),
                                                      meas_seeds=seeds, stamps=stamps)
                samples[key].append(time.perf_counter() - t)
        sampled = [int(s) for s in np.linspace(0, args.runs - 1, args.per_point)]
        pp = {key: per_point(data, sampled, *columns[key]) for key in samples}
    med = {k: statistics.median(v) for k, v in samples.items()}
    lines = [
        "# Benchmark: Monte Carlo runs through a network channel (one core)", "",
        f"delaycomp {__version__}, Python {platform.python_version()}, numpy "
        f"{np.__version__}, {platform.machine()}; `python bench/channels.py"
        f"{' --quick' if args.quick else ''}`", "",
        f"Example 3.6 to {STOP:g} s (2001 ticks a run), the measurement through uniform "
        f"jitter {MEAS['jitter']:g} s (2 T) and Bernoulli loss {MEAS['loss']:g}, one seed "
        f"a run, a packet every base step (period 0) or one per sample (period = T); "
        f"{args.runs} runs, {args.repeats} repeat(s), medians; one CPU.", "",
        "| controller | batch wall [s] | runs/s | per point [ms/run] | ratio | "
        "10^6 runs [s] | cost vs per point |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for key in samples:
        per, costs = pp[key]
        got = results[key].cost
        assert got is not None
        diff = max(abs(float(got[s]) - c) / max(1.0, abs(c)) for s, c in zip(sampled, costs))
        rate = args.runs / med[key]
        lines.append(f"| {key} | {med[key]:.2f} | {rate:.0f} | {per * 1e3:.1f} | "
                     f"{per * rate:.0f}x | {1e6 / rate:.1f} | {diff:.1e} |")
    lines += ["", f"Target: 10^6 runs under {TARGET_S:g} s on one core."]
    text = "\n".join(lines) + "\n"
    args.out.write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
