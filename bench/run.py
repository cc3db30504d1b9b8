"""delaycomp benchmark: engines, master overhead, predictor cost, accuracy against cost.

Run from the repository root (it writes ``BENCHMARKS.md`` and
``docs/figures/benchmarks.png``)::

    python bench/run.py            # the full run, a few minutes
    python bench/run.py --quick    # one repeat, one scenario: a smoke test of the script
    python bench/run.py --sections 10   # only section 10, put into the BENCHMARKS.md there

Everything is measured side by side in one run and reported as medians of repeated runs
and as ratios, because absolute times on a shared machine drift from minute to minute:
the two engines of a comparison are timed alternately, repeat after repeat. BLAS runs on
one thread throughout, as in ``delaycomp run`` (see ``delaycomp.orchestrator.simulate``).

Sections (the targets are those of the performance issue):

1. wall time per simulated second of every scenario at N = 10, 100, 1000, with the FMUs
   (``fmu``) and in-process (``inprocess``); the ratio between them; Example 3.6 (20 s,
   N = 100) against real time (target >= 100x) and the in-process speed-up (target >= 20x);
2. the master's own share: the master stepping the FMUs against a bare loop making the
   same FMU calls (target <= 1.2x);
3. predictor cost per sample for n = 3 and a window r + tau = 2 s: the closed forms
   against the numerical Phi (targets: numerical <= 1 ms, closed-form LTI <= 50 us);
4. accuracy against cost: the largest error against the reference traces as N grows, with
   the observed order of the continuous-input loops;
5. native C FMUs (``delaycomp build --native``): Example 3.6 (20 s, N = 100) in our master
   with the native FMUs against the Python FMUs (target: native >= 3x faster), and in the
   C host (``fmus/native/host``, run under ``env -i``) against real time (target >=
   10 000x);
6. start: whole processes of ``delaycomp --help`` and ``delaycomp list`` against a bare
   ``python -c pass`` (target: within 6x), alternately;
7. Python FMUs: what instantiating each one imports in a fresh interpreter, as pythonfmu's
   binary does in a host (``delaycomp.fmu.build.probe_instantiation``), and how long it takes;
8. a packed loop: Example 3.6 packed with ``ssp --native`` and run to 40 s (4 000 base
   steps) and to 2000 s (200 000), a CSV of the results, whole processes, alternately:
   ``python -c pass``, ``python -c "import fmpy"``, ``delaycomp run`` with the Python master
   (``--stepping python``, before) and with the native stepping core (``--stepping
   native-core``, after: a first run, and a later run replayed from the recipe the first
   kept), and OMSimulator's command line on the same archive (where it is installed;
   targets: the replayed run at most 0.5x OMSimulator at 2000 s, at most 1x at 40 s), with
   the import time of the replayed 40 s run (``python -X importtime``);
9. exact-grid steps: the C host stepping a native LTI loop of n = 2 and n = 40 states for
   50 000 steps with ``--exact-grid`` (``t_k = t0 + k h``, steps ``t_{k+1} - t_k``)
   against constant steps ``h``, alternately (target: about 1x);
10. native model controllers and loops (issue 23, item 6): per sample, the controller of
   each nonlinear scenario alone, its Python FMU against its native FMU, both through fmpy
   with the same measurements (target: native >= 30x faster); the whole loop in our master
   with all-Python against all-native FMUs; Example 2.4 in the C host (under ``env -i``)
   against real time (target >= 1000x);
11. exported controllers (issue 33, item 5): ``delaycomp export-c`` of LTI loops (n = 2,
   n = 20) and of each nonlinear scenario (closed-form and numerical predictor), driven
   by ``bench/export_timing.c`` for 10^6 base steps: median, 99.9th percentile and
   maximum of one step's time, beside the bound on its work (reported, not gated on);
12. per-point sweep of a native model loop (issue 53): ``delaycomp sweep example-2.4 --set
   predictor=numerical`` over 8 values of r (10 s each, one worker), whose points the batch
   engine cannot vectorize: the default (the per-point ``fmu`` engine, native FMUs stepped
   by the native core: after) against ``--engine inprocess`` (before), whole processes,
   alternately: wall time and points per second.

``--sections`` runs only the sections named and puts their target rows and tables into
the report already at ``--out``, where the other sections keep the numbers of their run.

The package's modules are byte-compiled first, as ``pip install`` does: a checkout run
with ``PYTHONDONTWRITEBYTECODE`` would otherwise compile them in every process it starts.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import re
import shutil
import statistics
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from delaycomp import __version__  # noqa: E402
from delaycomp.fmu.cache import fmu_path  # noqa: E402
from delaycomp.orchestrator.simulate import (  # noqa: E402
    make_master,
    run_loop,
    single_threaded_blas,
)
from delaycomp.paper import scenarios  # noqa: E402
from delaycomp.verify import check  # noqa: E402

TARGET_REALTIME = 100.0
TARGET_INPROCESS = 20.0
TARGET_MASTER = 1.2
TARGET_NUMERICAL_PHI = 1e-3
TARGET_LTI_PHI = 50e-6
TARGET_NATIVE = 3.0
TARGET_HOST_REALTIME = 10_000.0
TARGET_START = 6.0
#: section 8's stop times (s) and the target of each: ``delaycomp run`` of the native
#: Example 3.6 archive (the native stepping core) at most this many times OMSimulator's
#: command line on the same archive
TARGET_PACKED = {2000.0: 0.5, 40.0: 1.0}
TARGET_NATIVE_SAMPLE = 30.0
TARGET_HOST_MODEL_REALTIME = 1000.0


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def alternate(fns: dict, repeats: int) -> dict:
    """Median wall time of each callable, timed alternately (side by side)."""
    samples = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            samples[name].append(time.perf_counter() - t)
    return {name: statistics.median(v) for name, v in samples.items()}


def stop_for(sc, N: int, T: float) -> float:
    """About 2000 base steps, a whole number of periods, at most the scenario's stop time."""
    periods = max(1, min(round(sc.default_stop_time / T), round(2000 / N)))
    return periods * T


# -- 1. engines ----------------------------------------------------------------------------

def bench_engines(names, Ns, repeats, fmu_dir):
    rows = []
    for name in names:
        sc = scenarios.get(name)
        for N in Ns:
            p = sc.resolve([f"N={N}"])
            spec = sc.make(p)
            stop = stop_for(sc, N, p["T"])
            for inst in spec.instances:
                fmu_path(*inst.source.build_key(), fmu_dir)  # built before timing
            med = alternate({
                "fmu": lambda spec=spec, stop=stop: run_loop(spec, stop, fmu_dir),
                "inprocess": lambda spec=spec, stop=stop: run_loop(spec, stop,
                                                                   engine="inprocess"),
            }, repeats)
            rows.append(dict(scenario=name, N=N, stop=stop,
                             fmu=med["fmu"] / stop, inprocess=med["inprocess"] / stop,
                             ratio=med["fmu"] / med["inprocess"]))
            print(f"  {name:16s} N={N:<5d} fmu {med['fmu'] / stop * 1e3:8.2f} ms/s  "
                  f"inprocess {med['inprocess'] / stop * 1e3:8.2f} ms/s  "
                  f"ratio {med['fmu'] / med['inprocess']:5.1f}", flush=True)
    return rows


_COLD = """
import sys, time
from delaycomp.paper import scenarios
from delaycomp.orchestrator.simulate import run_loop
sc = scenarios.get("example-3.6")
spec = sc.make(sc.resolve([]))
t = time.perf_counter()
run_loop(spec, 20.0, sys.argv[1])
print(time.perf_counter() - t)
"""


def bench_example_3_6(repeats, fmu_dir):
    """Repeated runs in one process (FMUs unpacked once, as in a sweep), and the first run
    in a fresh process (unpacking the FMUs included, as a single `delaycomp run`)."""
    import subprocess

    sc = scenarios.get("example-3.6")
    spec = sc.make(sc.resolve([]))
    med = alternate({
        "fmu": lambda: run_loop(spec, 20.0, fmu_dir),
        "inprocess": lambda: run_loop(spec, 20.0, engine="inprocess"),
    }, repeats)
    cold = statistics.median(
        float(subprocess.run([sys.executable, "-c", _COLD, str(fmu_dir)], check=True,
                             capture_output=True, text=True).stdout.split()[-1])
        for _ in range(max(1, repeats // 2)))
    return dict(fmu=med["fmu"], inprocess=med["inprocess"], realtime=20.0 / med["fmu"],
                realtime_inprocess=20.0 / med["inprocess"],
                ratio=med["fmu"] / med["inprocess"], cold=cold)


# -- 5. native C FMUs ----------------------------------------------------------------------

def bench_native(repeats, fmu_dir, work: Path):
    """Example 3.6 (20 s, N = 100): native FMUs against the Python FMUs in our master
    (alternately), and the C host with the native FMUs (its stepping loop, timed inside the
    host, and the whole process: loading, initialization and exit included)."""
    import subprocess

    from delaycomp.fmu.host import compile_host, host_argv, unpack
    from delaycomp.fmu.twins import native_fmus

    sc = scenarios.get("example-3.6")
    spec = sc.make(sc.resolve([]))
    fmus = native_fmus(spec, work / "native")
    med = alternate({
        "python": lambda: run_loop(spec, 20.0, fmu_dir),
        "native": lambda: run_loop(spec, 20.0, fmus=fmus),
    }, repeats)
    exe = compile_host(work / "host")
    argv = ["env", "-i", *host_argv(exe, spec, 20.0, unpack(fmus, work / "unpacked"),
                                    timing=True)]
    loops, whole = [], []
    for _ in range(max(repeats, 3)):
        started = time.perf_counter()
        proc = subprocess.run(argv, capture_output=True, text=True, check=True)
        whole.append(time.perf_counter() - started)
        loops.append(float(proc.stderr.split(" in ")[-1].split()[0]))
    loop, proc_time = statistics.median(loops), statistics.median(whole)
    return dict(python=med["python"], native=med["native"],
                ratio=med["python"] / med["native"], host_loop=loop, host_process=proc_time,
                host_rt=20.0 / loop, host_rt_process=20.0 / proc_time,
                rows=len(proc.stdout.splitlines()) - 1)


# -- 6. start -------------------------------------------------------------------------------

def bench_start(repeats):
    """Whole processes, timed alternately: a bare interpreter, ``delaycomp --help`` and
    ``delaycomp list`` (``python -m delaycomp``, as the console script runs it)."""
    import subprocess

    def proc(*argv):
        return lambda: subprocess.run([sys.executable, *argv], cwd=REPO, check=True,
                                      capture_output=True)

    med = alternate({"python": proc("-c", "pass"),
                     "help": proc("-m", "delaycomp", "--help"),
                     "list": proc("-m", "delaycomp", "list")}, max(2 * repeats - 1, 3))
    return dict(med, help_ratio=med["help"] / med["python"],
                list_ratio=med["list"] / med["python"])


# -- 8. a packed loop against OMSimulator -----------------------------------------------

def _import_seconds(stderr: str) -> float:
    """The seconds a process spent importing, from its ``python -X importtime`` report:
    the sum of the cumulative times of the top-level imports."""
    total = 0
    for line in stderr.splitlines():
        parts = line.split("|")
        if len(parts) == 3 and parts[0].startswith("import time:") \
                and parts[1].strip().isdigit() and not parts[2][1:].startswith(" "):
            total += int(parts[1])
    return total * 1e-6


def bench_packed(repeats, work: Path, rounds: int | None = None):
    """The native Example 3.6 archive (``ssp example-3.6 --native``) run to each stop time
    of ``TARGET_PACKED`` with a CSV out, whole processes timed alternately: ``python -c
    pass``, a bare ``python -c "import fmpy"`` (what any master on fmpy pays before its
    first step), ``delaycomp run`` with the Python master (``--stepping python``, before the
    native stepping core) and with the core (``--stepping native-core``) twice: a first run
    (``first``: its recipe removed from a cache of its own before each) and a run replayed
    from the recipe of the first (``core``, ``delaycomp.cli.recipes``), and OMSimulator's
    command line on the same archive. Also the import time of the replayed shortest run
    (``python -X importtime``), and whether the CSVs of the core's first run and of a
    replayed run (``same``, ``same_replayed``) are the Python master's bytes. None where
    OMSimulator is not installed."""
    import subprocess

    from delaycomp.verify.omsimulator import NotInstalled, cli_command

    ssp = work / "ex36-native.ssp"
    try:
        cli_command(ssp, 40.0, work / "oms.csv")
    except NotInstalled as exc:
        print(f"   (no OMSimulator: {exc})", flush=True)
        return None
    subprocess.run([sys.executable, "-m", "delaycomp", "ssp", "example-3.6", "--native",
                    "--out", str(ssp), "-q"], cwd=REPO, check=True, capture_output=True)

    def proc(argv, env=None):
        return lambda: subprocess.run(argv, cwd=work, env=env, check=True,
                                      capture_output=True)

    def ours(stop, stepping, out="dc.csv", verbosity="-q"):
        return [sys.executable, "-m", "delaycomp", "run", str(ssp), "--stop-time", f"{stop:g}",
                "--out", str(work / out), verbosity, "--stepping", stepping]

    # the core's first run, each time: a cache of its own whose recipes are removed before
    # each run (about a millisecond, timed with it); the rest of that cache (the core's
    # library, compiled by the run before the timed rounds) stays, as in the bench's cache
    first_cache = work / "first-cache"
    first_env = {**os.environ, "DELAYCOMP_CACHE_DIR": str(first_cache)}

    def first(argv):
        run = proc(argv, first_env)

        def timed():
            shutil.rmtree(first_cache / "recipes", ignore_errors=True)
            run()
        return timed

    short = min(TARGET_PACKED)
    # first runs (the page cache, the archive's FMUs unpacked once, the core's recipe of
    # this command kept), and the same rows
    for stepping in ("python", "native-core"):
        proc(ours(short, stepping, f"dc-{stepping}.csv"))()
    same = (work / "dc-python.csv").read_bytes() == (work / "dc-native-core.csv").read_bytes()
    # the same command again is replayed from that recipe (``-v`` says so), the same rows
    done = subprocess.run(ours(short, "native-core", "dc-replayed.csv", "-v"), cwd=work,
                          check=True, capture_output=True, text=True)
    if "replayed from the recipe of its first run" not in done.stderr:
        raise RuntimeError("section 8: the core's second run was not replayed from its "
                           f"recipe:\n{done.stderr}")
    same_replayed = ((work / "dc-python.csv").read_bytes()
                     == (work / "dc-replayed.csv").read_bytes())
    rows = []
    for stop in sorted(TARGET_PACKED):
        oms_argv, oms_env = cli_command(ssp, stop, work / "oms.csv")
        fns = {
            "python": proc([sys.executable, "-c", "pass"]),
            "fmpy": proc([sys.executable, "-c", "import fmpy"]),
            "master": proc(ours(stop, "python")),
            "first": first(ours(stop, "native-core")),
            "core": proc(ours(stop, "native-core")),
            "omsimulator": proc(oms_argv, oms_env),
        }
        # once before the timed rounds: the core's first run at this stop time keeps the
        # recipe its timed runs replay, and the first run's compiles the core's library
        # into its own cache
        fns["core"]()
        fns["first"]()
        med = alternate(fns, rounds or max(2 * repeats - 1, 3))
        rows.append(dict(med, stop=stop, steps=round(stop / 0.01),
                         target=TARGET_PACKED[stop],
                         ratio=med["core"] / med["omsimulator"],
                         first_ratio=med["first"] / med["omsimulator"],
                         master_ratio=med["master"] / med["omsimulator"],
                         speedup=med["master"] / med["core"]))
    # what the shortest replayed run of the core spends importing, and its whole process
    # beside it
    imports, walls = [], []
    for _ in range(rounds or max(repeats, 3)):
        t = time.perf_counter()
        done = subprocess.run([sys.executable, "-X", "importtime", *ours(short, "native-core")[1:]],
                              cwd=work, check=True, capture_output=True, text=True)
        walls.append(time.perf_counter() - t)
        imports.append(_import_seconds(done.stderr))
    return {"rows": rows, "same": same, "same_replayed": same_replayed,
            "imports": statistics.median(imports), "imports_wall": statistics.median(walls)}


# -- 12. per-point sweep of a native model loop -----------------------------------------

def bench_sweep_points(repeats, work: Path, count: int = 8, rounds: int | None = None):
    """``delaycomp sweep example-2.4 --set predictor=numerical`` over ``count`` values of r
    (10 s each, one worker, a CSV out), whole processes timed alternately: the default
    engine (batch, whose points fall back to the per-point ``fmu`` engine, native FMUs
    stepped by the native core: after) against ``--engine inprocess`` (before), ``rounds``
    rounds (default: from ``repeats``). A first run of the default builds the native FMUs
    and tells which engine the points ran on; without ``rounds``, a first run of the other
    too."""
    import subprocess

    argv = [sys.executable, "-m", "delaycomp", "sweep", "example-2.4", "--set",
            "predictor=numerical", "--grid", f"r=0.1:0.5:{count}", "--stop-time", "10",
            "--workers", "1", "--out", str(work / "s.csv")]

    def proc(*extra):
        return lambda: subprocess.run([*argv, "-q", *extra], cwd=work, check=True,
                                      capture_output=True)

    said = subprocess.run(argv, cwd=work, check=True, capture_output=True, text=True)
    engine = next((line.strip() for line in (said.stdout + said.stderr).splitlines()
                   if line.startswith("per-point engine")), "")
    if rounds is None:  # a first run of the other (the quick bench times one round only)
        proc("--engine", "inprocess")()
    med = alternate({"inprocess": proc("--engine", "inprocess"), "core": proc()},
                    rounds or max(2 * repeats - 1, 3))
    return dict(med, points=count, engine=engine, ratio=med["inprocess"] / med["core"])


def report_sweep_points(swp) -> list[str]:
    n = swp["points"]
    return ["", "## 12. Per-point sweep of a native model loop", "",
            f"`delaycomp sweep example-2.4 --set predictor=numerical --grid r=0.1:0.5:{n} "
            "--stop-time 10 --workers 1 --out s.csv -q`: points the batch engine cannot "
            "vectorize (the ODE-solved predictor), whole processes timed alternately "
            "(medians), start-up and the CSV included. Before: `--engine inprocess`, point by "
            "point in Python; after: the default, whose points fall back to the per-point "
            f"`fmu` engine with the native FMUs stepped by the native core (its run says: "
            f"\"{swp['engine'] or 'no per-point engine named'}\").", "",
            "| engine | points | wall time [ms] | points per second | against inprocess |",
            "|---|---|---|---|---|",
            f"| `--engine inprocess` (before) | {n} | {swp['inprocess'] * 1e3:.0f} | "
            f"{n / swp['inprocess']:.1f} | 1x |",
            f"| default: per-point `fmu`, native core (after) | {n} | {swp['core'] * 1e3:.0f} | "
            f"{n / swp['core']:.1f} | {swp['ratio']:.1f}x faster |"]


# -- 7. Python FMUs -----------------------------------------------------------------------

def bench_fmu_imports(repeats, fmu_dir):
    """Each Python FMU instantiated in a fresh interpreter (pythonfmu's way), ``repeats``
    times round-robin: the median time and what the first probe imported."""
    from delaycomp.fmu.build import probe_instantiation
    from delaycomp.paper.models import path as builtin_model

    model = {"model": str(builtin_model("example_2_4"))}
    fmus = {"delay (n = 1)": fmu_path("delay", {"n": 1}, fmu_dir),
            "LTI plant (n = 1)": fmu_path("plant", dict(sc_key("example-3.6", "plant")),
                                          fmu_dir),
            "LTI controller (n = 1)": fmu_path("controller",
                                               dict(sc_key("example-3.6", "controller")),
                                               fmu_dir),
            "model plant (Example 2.4)": fmu_path("model_plant", model, fmu_dir),
            "model controller (Example 2.4)": fmu_path("model_controller", model, fmu_dir)}
    probes = {name: [] for name in fmus}
    for _ in range(max(repeats, 3)):
        for name, fmu in fmus.items():
            probes[name].append(probe_instantiation(fmu))
    return [dict(fmu=name, seconds=statistics.median(p.seconds for p in runs),
                 packages=runs[0].packages,
                 scipy=[s for s in runs[0].subpackages if s.startswith("scipy.")],
                 delaycomp=[m.split(".", 1)[1] for m in runs[0].delaycomp_modules],
                 modules=len(runs[0].modules))
            for name, runs in probes.items()]


def sc_key(scenario: str, kind: str) -> dict:
    """The build configuration of the ``kind`` FMU of ``scenario``."""
    sc = scenarios.get(scenario)
    return next(cfg for k, cfg in (i.source.build_key() for i in sc.loop([]).instances)
                if k == kind)
# -- 9. exact-grid steps -----------------------------------------------------------------------

def bench_exact_grid(repeats, work: Path, steps: int = 50_000):
    """The C host with native FMUs on a loop of n = 2 and n = 40 states (a stable chain
    ``x_i' = -x_i + x_{i+1}``, the input at the end, a small feedback) for ``steps`` steps:
    ``--exact-grid`` against constant steps, whole runs timed alternately (the host's
    stepping loop, timed inside it, and the whole process under ``env -i``)."""
    import subprocess

    from delaycomp.fmu.host import compile_host, host_argv, unpack
    from delaycomp.fmu.twins import native_fmus
    from delaycomp.paper.scenarios import lti_loop

    exe = compile_host(work / "host-exact-grid")
    rows = []
    for n in (2, 40):
        A = -np.eye(n) + np.eye(n, k=1)
        B = np.zeros((n, 1))
        B[-1, 0] = 1.0
        K = np.full((1, n), -0.05)
        spec = lti_loop(A, B, K, T=0.1, r=0.05, tau=0.1, N=10, mode="compensated",
                        x0=np.ones(n), u0=(0.0,))
        stop = steps * spec.T / spec.N
        dirs = unpack(native_fmus(spec, work / f"native-grid-{n}"), work / f"grid-{n}")
        argv = {exact: ["env", "-i", *host_argv(exe, spec, stop, dirs, timing=True,
                                                exact_grid=exact)]
                for exact in (False, True)}
        loops = {False: [], True: []}
        whole = {False: [], True: []}
        for _ in range(max(repeats, 3)):
            for exact in (False, True):
                started = time.perf_counter()
                proc = subprocess.run(argv[exact], stdout=subprocess.DEVNULL,
                                      stderr=subprocess.PIPE, text=True, check=True)
                whole[exact].append(time.perf_counter() - started)
                loops[exact].append(float(proc.stderr.split(" in ")[-1].split()[0]))
        loop = {k: statistics.median(v) for k, v in loops.items()}
        proc_time = {k: statistics.median(v) for k, v in whole.items()}
        rows.append(dict(n=n, steps=steps, constant=loop[False], exact=loop[True],
                         ratio=loop[True] / loop[False], constant_process=proc_time[False],
                         exact_process=proc_time[True],
                         ratio_process=proc_time[True] / proc_time[False]))
    return rows


def report_exact_grid(rows) -> list[str]:
    """Section 7 of the report."""
    L = ["", "## 9. Exact-grid steps", "",
         "The C host (`--exact-grid`: `t_k = t0 + k h` computed from `k`, each step "
         "`t_{k+1} - t_k`, as the FMI guides ask of an importer) against constant steps `h`, "
         "native FMUs, whole runs timed alternately: the host's stepping loop and the whole "
         "process (writing the CSV included). The plant keys its discretization on its own "
         "grid (`delaycomp.maths.grid.same_step`): steps within `GRID_RTOL` of `h` reuse it "
         "(target: exact grid about 1x constant steps; before, keyed on the step's bits, a "
         "matrix exponential per step: at n = 40, 57.6x in the stepping loop and 9.0x the "
         "whole process, measured on the machine of the change).", "",
         "| states | steps | constant [ms] | exact grid [ms] | exact / constant | "
         "whole process: constant [ms] | exact grid [ms] | exact / constant |",
         "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        L.append(f"| {r['n']} | {r['steps']:,} | {r['constant'] * 1e3:.1f} | "
                 f"{r['exact'] * 1e3:.1f} | {r['ratio']:.2f}x | "
                 f"{r['constant_process'] * 1e3:.1f} | {r['exact_process'] * 1e3:.1f} | "
                 f"{r['ratio_process']:.2f}x |")
    return L


# -- 11. exported controllers: the time of one step -------------------------------------

def _lti_timing_loop(n: int):
    """A stable LTI loop with n states, one input (T = 0.5, r = 0.35, tau = 0.5, N = 10):
    its controller's work is what is timed (the measurements are synthetic)."""
    import numpy as np

    from delaycomp import api
    rng = np.random.default_rng(n)
    A = -np.eye(n) + 0.1 * rng.standard_normal((n, n))
    B = rng.standard_normal((n, 1))
    K = -0.01 * rng.standard_normal((1, n))
    return api.lti(A, B, K, T=0.5, r=0.35, tau=0.5, N=10, x0=[0.0] * n,
                   name=f"lti-n{n}")


def _work_bound(loop) -> str:
    """The bound of item 1 on the work of one step of the loop's exported controller."""
    from delaycomp.formats.exportc import MAX_ODE_STEPS, _controller
    from delaycomp.maths.nlcontrol import ZOHModelController

    _, kind, slave = _controller(loop)
    ctrl = slave.ctrl
    if kind == "controller":
        n, m, L = ctrl.n, ctrl.m, ctrl.predictor.L
        return (f"sample: {n * n + n * m * L + m * n} multiply-adds (L = {L}); "
                "between: a copy")
    W = ctrl.history.W
    zoh = isinstance(ctrl, ZOHModelController)
    if slave.predictor == "closed":
        where = "" if zoh else " + 1 per step (z)"
        return f"<= {W} exact steps per sample{where}"
    M = MAX_ODE_STEPS
    bound = f"<= 12 (M + 1) + 2 W = {12 * (M + 1) + 2 * W:,} f-evaluations per sample"
    if not zoh:
        bound += f", + {12 * (M + 1) + 2:,} per step (z's flow)"
    return bound + f" (M = {M:,}, W = {W})"


def bench_export(ticks: int, work: Path) -> list[dict]:
    """Each case's controller exported, driven for ``ticks`` base steps by
    ``bench/export_timing.c`` (-O2): the median, 99.9th percentile and maximum of the time
    of one step, and of the sample steps."""
    import subprocess

    from delaycomp.fmu.native import compiler
    from delaycomp.formats.exportc import closed_loop_io, export_c

    cases = [(f"LTI n = {n}, m = 1", _lti_timing_loop(n)) for n in (2, 20)]
    for name, sets in SPEED_CASES:
        if "p=sin" in sets:
            continue
        sc = scenarios.get(name)
        cases.append((_case_label(name, sets), sc.make(sc.resolve(list(sets)))))
    rows = []
    for label, loop in cases:
        folder = work / f"export-{len(rows)}"
        export_c(loop, folder, "ctl")
        exe = folder / "timing"
        subprocess.run([*compiler(), "-std=c99", "-O2", "-DPREFIX=ctl", "-include",
                        str(folder / "ctl.h"), "-I", str(folder),
                        str(REPO / "bench" / "export_timing.c"), str(folder / "ctl.c"),
                        "-o", str(exe), "-lm"], check=True)
        episode = 20 * loop.N  # 20 periods of the closed loop, from its start
        ys, _ = closed_loop_io(loop, episode, work / "export-fmus")
        feed = f"{episode}\n" + "".join(" ".join(repr(float(v)) for v in y) + "\n"
                                         for y in ys)
        out = subprocess.run([str(exe), str(ticks)], input=feed, capture_output=True,
                             text=True, check=True).stdout.split()
        median, p999, worst, s_median, s_worst = (float(v) * 1e-9 for v in out)
        rows.append({"case": label, "N": loop.N, "median": median, "p999": p999,
                     "max": worst, "sample_median": s_median, "sample_max": s_worst,
                     "bound": _work_bound(loop), "ticks": ticks})
        print(f"  {label}: median {median * 1e9:.0f} ns, max {worst * 1e6:.1f} us",
              flush=True)
    return rows


def report_export(rows) -> list[str]:
    """Section 11 of the report."""
    ticks = rows[0]["ticks"] if rows else 0
    L = ["", "## 11. Exported controllers: the time of one step", "",
         f"`delaycomp export-c` of each loop, compiled at -O2 and driven by "
         f"`bench/export_timing.c` for {ticks:,} base steps: episodes of 20 periods from "
         "the controller's start, along the measurements of a closed-loop run of the loop's "
         "native FMUs (`delaycomp.formats.exportc.closed_loop_io`); each step (`NAME_sample` "
         "and `NAME_output` at a sample instant, `NAME_output` between) timed with the "
         "monotonic clock. The maximum is "
         "reported, not gated on: this machine is shared, and a step that the scheduler "
         "interrupts shows here. The last column is the bound on a step's work (issue 33, "
         "item 1): what a target's worst case is made of.", "",
         "| controller | N | median [us] | p99.9 [us] | max [us] | at a sample: median [us] "
         "| at a sample: max [us] | work bound |",
         "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        L.append(f"| {r['case']} | {r['N']} | {r['median'] * 1e6:.3f} | "
                 f"{r['p999'] * 1e6:.2f} | {r['max'] * 1e6:.1f} | "
                 f"{r['sample_median'] * 1e6:.2f} | {r['sample_max'] * 1e6:.1f} | "
                 f"{r['bound']} |")
    return L


# -- 10. speed: the native model controller and loops -----------------------------------

SPEED_CASES = (("example-2.4", ()), ("example-2.4", ("predictor=numerical",)),
               ("example-3.8", ()), ("example-3.8", ("predictor=numerical",)),
               ("example-3.8", ("p=sin",)), ("corollary-4.1", ()),
               ("proposition-4.2", ()))


def _case_label(name: str, sets) -> str:
    return " ".join((name, *sets))


def _measurements(loop, periods: int):
    """What the controller reads in the loop: the plant's states recorded by a run of
    ``periods`` sampling periods, delayed by ``r`` (``r / h`` ticks, the first held), one
    row per base step (``periods * N + 1`` rows), and the controller's input names."""
    h = loop.T / loop.N
    res = run_loop(loop, periods * loop.T)
    cols = [i for i, n in enumerate(res.names) if n.startswith("plant.")]
    x = res.data[:, cols]
    ctrl = loop.instance("controller")
    lag = round(ctrl.parameters["r"] / h)
    y = np.vstack([np.repeat(x[:1], lag, axis=0), x[:len(x) - lag]])
    return y.tolist(), [f"y_{res.names[i].split('.', 1)[1]}" for i in cols]


def _drive(path, name, params, ins, outs, rows, h, stop):
    """One FMU alone through fmpy (``FmuComponent``), as our master calls it: the
    inputs of t = 0, then per base step ``do_step``, the inputs, the outputs. The wall
    time of the stepping (setup and initialization excluded)."""
    from delaycomp.orchestrator.fmu import FmuComponent

    comp = FmuComponent(name, path)
    comp.setup(0.0, stop, params)
    try:
        comp.initialize()
        outs = outs or comp.output_names
        started = time.perf_counter()
        comp.set_inputs(ins, rows[0])
        comp.get_outputs(outs)
        for k in range(1, len(rows)):
            comp.do_step((k - 1) * h, h)
            comp.set_inputs(ins, rows[k])
            comp.get_outputs(outs)
        return time.perf_counter() - started
    finally:
        comp.terminate()


def _host_loop_time(argv, env) -> float:
    """The stepping loop's seconds, as the C host prints them with ``--timing``. With the
    Python FMUs the host may crash at exit after a complete run (pythonfmu finalizes Python
    in a thread of its own at unload: ``test_native``), so only the timing line counts."""
    import subprocess

    proc = subprocess.run(argv, capture_output=True, text=True, env=env)
    if " in " not in proc.stderr or (env is None and proc.returncode != 0):
        raise RuntimeError(f"C host failed ({proc.returncode}): {proc.stderr[-500:]}")
    return float(proc.stderr.split(" in ")[-1].split()[0])


def bench_speed(cases, repeats, fmu_dir, work: Path, max_periods: int = 20):
    """Issue 23, item 6. Per sample: the model controller alone, its Python FMU against
    its native FMU, both through fmpy, fed the same measurements (the loop's plant states
    delayed by r) for the same sampling periods (N base steps each, the sample's
    prediction included), timed alternately; the same fmpy calls on the loop's native
    measurement delay (a trivial step) show what the calls themselves cost. The whole
    loop: our master with all-Python FMUs against all-native FMUs (the scenario's stop
    time), alternately; Example 2.4 in the C host (under ``env -i``) with the native FMUs:
    its stepping loop and the whole process against real time."""
    import subprocess

    from delaycomp.fmu.host import compile_host, host_argv, unpack
    from delaycomp.fmu.twins import native_fmus
    from delaycomp.verify.omsimulator import cli_env

    samples, loops = [], []
    for name, sets in cases:
        label = _case_label(name, sets)
        sc = scenarios.get(name)
        loop = sc.make(sc.resolve(list(sets)))
        ctrl, delay = loop.instance("controller"), loop.instance("meas_delay")
        periods = max(1, min(round(sc.default_stop_time / loop.T), max_periods))
        rows, ins = _measurements(loop, periods)
        h, stop = loop.T / loop.N, periods * loop.T
        native = native_fmus(loop, work / "native-speed")
        python = fmu_path(ctrl.source.kind, dict(ctrl.source.config), fmu_dir)
        common = dict(rows=rows, h=h, stop=stop)
        med = alternate({
            "python": partial(_drive, python, "controller", ctrl.parameters, ins, None,
                              **common),
            "native": partial(_drive, native["controller"], "controller", ctrl.parameters,
                              ins, None, **common),
            "calls": partial(_drive, native["meas_delay"], "meas_delay", delay.parameters,
                             [f"u{i + 1}" for i in range(len(ins))],
                             [f"y{i + 1}" for i in range(len(ins))], **common),
        }, repeats)
        per = {k: v / periods for k, v in med.items()}
        # the same periods of the whole native loop (plant, delays, controller) in the C
        # host: what the native controller costs where no Python calls it, at most
        exe = work / "host-speed"
        if not exe.exists():
            compile_host(exe)
        argv = ["env", "-i", *host_argv(exe, loop, stop, unpack(
            native, work / "unpacked-speed" / label.replace(" ", "_")), timing=True)]
        # the same loop in the same C host with the Python controller in place of the
        # native one (plant and delays native; pythonfmu's three settings), alternately:
        # (P - rest) / native controller >= P / (rest + native controller), so the ratio
        # of the two stepping loops is a lower bound of the controller's own ratio
        py_argv = [*host_argv(exe, loop, stop, unpack(
            {**native, "controller": python},
            work / "unpacked-speed-py" / label.replace(" ", "_")), timing=True)]
        # one BLAS thread, as our master runs the Python FMUs (run_loop's BLAS limit)
        py_env = cli_env({**{k: v for k, v in os.environ.items() if k.startswith("OPENBLAS_")},
                          "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})
        in_host, in_host_py = [], []
        for _ in range(max(repeats, 3)):
            in_host.append(_host_loop_time(argv, None))
            in_host_py.append(_host_loop_time(py_argv, py_env))
        host_per = statistics.median(in_host) / periods
        host_py_per = statistics.median(in_host_py) / periods
        samples.append(dict(case=label, N=loop.N, periods=periods, python=per["python"],
                            native=per["native"], calls=per["calls"],
                            ratio=med["python"] / med["native"], host=host_per,
                            host_ratio=per["python"] / host_per, host_py=host_py_per,
                            same_host_ratio=host_py_per / host_per))
        print(f"  {label:34s} per sample: python {per['python'] * 1e3:7.3f} ms  native "
              f"{per['native'] * 1e3:7.3f} ms  ratio {med['python'] / med['native']:5.1f}  "
              f"(fmpy calls {per['calls'] * 1e3:.3f} ms; native loop in the C host "
              f"{host_per * 1e3:.4f} ms, {per['python'] / host_per:,.0f}x; with the Python "
              f"controller in the C host {host_py_per * 1e3:.3f} ms, "
              f"{host_py_per / host_per:,.0f}x)", flush=True)
        if "predictor=numerical" in sets:
            continue  # the loops run each scenario once, as it comes
        lstop = sc.default_stop_time if max_periods > 2 else stop
        for inst in loop.instances:
            fmu_path(*inst.source.build_key(), fmu_dir)  # built before timing
        med = alternate({"python": partial(run_loop, loop, lstop, fmu_dir),
                         "native": partial(run_loop, loop, lstop, fmus=native)}, repeats)
        loops.append(dict(case=label, stop=lstop, python=med["python"], native=med["native"],
                          ratio=med["python"] / med["native"]))
        print(f"  {label:34s} loop ({lstop:g} s): python {med['python'] * 1e3:8.1f} ms  "
              f"native {med['native'] * 1e3:7.1f} ms  ratio "
              f"{med['python'] / med['native']:5.1f}", flush=True)

    sc = scenarios.get("example-2.4")
    loop = sc.make(sc.resolve([]))
    hstop = sc.default_stop_time
    exe = compile_host(work / "host-speed")
    dirs = unpack(native_fmus(loop, work / "native-speed"), work / "unpacked-speed")
    argv = ["env", "-i", *host_argv(exe, loop, hstop, dirs, timing=True)]
    host_loops, whole = [], []
    for _ in range(max(repeats, 3)):
        started = time.perf_counter()
        proc = subprocess.run(argv, capture_output=True, text=True, check=True)
        whole.append(time.perf_counter() - started)
        host_loops.append(float(proc.stderr.split(" in ")[-1].split()[0]))
    hl, hp = statistics.median(host_loops), statistics.median(whole)
    host = dict(stop=hstop, loop=hl, process=hp, rt=hstop / hl, rt_process=hstop / hp,
                rows=len(proc.stdout.splitlines()) - 1)
    print(f"  C host, Example 2.4 ({hstop:g} s): stepping loop {hl * 1e3:.2f} ms "
          f"({host['rt']:,.0f}x real time), whole process {hp * 1e3:.1f} ms "
          f"({host['rt_process']:,.0f}x)", flush=True)
    return dict(samples=samples, loops=loops, host=host)


# -- 2. master overhead ----------------------------------------------------------------------

def _ready_master(spec, stop, fmu_dir, record=True):
    master, recorder = make_master(spec, fmu_dir)
    if not record:
        master._observers.remove(recorder)  # the bare master: no recording
    master.setup(stop, spec.parameters())
    master.initialize()
    return master


def _bare_loop(master, ticks):
    """The FMU calls the master makes per tick, in the same order, with nothing around."""
    plan = master._plan
    heads = [(c.fmu.getReal, c._vrs(outs)) for c, outs, _ in plan.heads]
    chain = [(c.fmu.setReal, c._vrs(ins), c.fmu.getReal, c._vrs(outs))
             for c, ins, _, outs, _ in plan.chain]
    tails = [(c.fmu.setReal, c._vrs(ins)) for c, ins, _ in plan.tails]
    steps = [c.fmu.doStep for c in master.components.values()]
    h = master.h
    values = [0.0] * 4
    for k in range(ticks):
        t = k * h
        for step in steps:
            step(t, h)
        for get, vrs in heads:
            values = get(vrs)
        for set_, ivrs, get, ovrs in chain:
            set_(ivrs, values[:len(ivrs)])
            values = get(ovrs)
        for set_, ivrs in tails:
            set_(ivrs, values[:len(ivrs)])


def bench_master(names, repeats, fmu_dir):
    rows = []
    for name in names:
        sc = scenarios.get(name)
        p = sc.resolve([])
        spec = sc.make(p)
        stop = stop_for(sc, 100, p["T"])
        ticks = round(stop / (p["T"] / 100))
        master_t, bare_t = [], []
        for _ in range(repeats):
            for which in ("master", "bare"):
                m = _ready_master(spec, stop, fmu_dir)
                try:
                    t = time.perf_counter()
                    if which == "master":
                        m.run_until(ticks)
                    else:
                        _bare_loop(m, ticks)
                    (master_t if which == "master" else bare_t).append(
                        time.perf_counter() - t)
                finally:
                    m.terminate()
        mt, bt = statistics.median(master_t), statistics.median(bare_t)
        rows.append(dict(scenario=name, ticks=ticks, master=mt / ticks, bare=bt / ticks,
                         ratio=mt / bt))
        print(f"  {name:16s} master {mt / ticks * 1e6:6.1f} us/tick  bare FMU calls "
              f"{bt / ticks * 1e6:6.1f} us/tick  ratio {mt / bt:5.2f}", flush=True)
    return rows


# -- 3. predictor cost -------------------------------------------------------------------------

def bench_predictors(repeats):
    from delaycomp.maths.lti import LTIPredictor
    from delaycomp.maths.model import load_model
    from delaycomp.maths.predictors import deadbeat_gain, numerical_predictor
    from delaycomp.maths.zoh import ZOHController
    from delaycomp.paper.models import path

    rows = []
    rng = np.random.default_rng(0)
    # LTI, n = 3 chain of integrators, r = 1, tau = 1, T = 1: closed form (3.15)
    A, B = np.eye(3, k=1), np.eye(3)[:, -1:]
    pred = LTIPredictor(A, B, 1.0, 1.0, 1.0)
    past = [rng.normal(size=1) for _ in range(pred.L)]
    y = rng.normal(size=3)
    n_calls = 2000
    t = median_time(lambda: [pred.predict(y, past) for _ in range(n_calls)], repeats)
    rows.append(dict(what="LTI closed form (3.15), n = 3, r + tau = 2 s", per=t / n_calls,
                     target=TARGET_LTI_PHI))
    ctrl = ZOHController(A, B, deadbeat_gain(3, 1.0), 1.0, 1.0, 1.0, "compensated", [0.0])
    t = median_time(lambda: [ctrl.propose(y) for _ in range(n_calls)], repeats)
    rows.append(dict(what="LTI controller sample K Phi, n = 3, r + tau = 2 s", per=t / n_calls,
                     target=TARGET_LTI_PHI))

    # nonlinear n = 3: the unicycle under ZOH (T = 1: window of 2 segments + a part) and
    # Example 2.4 under continuous input (T = 0.5, N = 100: 200 segments of h = 0.005)
    for module, label, seg_len, n_seg in (
            ("proposition_4_2", "unicycle (4.12), ZOH T = 1", 1.0, 2),
            ("example_2_4", "Example 2.4 (2.16)-(2.17), continuous, h = 0.01", 0.01, 200)):
        model = load_model(path(module))
        prm = model.params(T=1.0)
        segs = [(seg_len, rng.normal(size=model.m) * 0.3) for _ in range(n_seg)]
        x = np.array([1.0, -1.0, 0.5])
        phi_num = numerical_predictor(model.f)
        reps = 3 if n_seg > 10 else 50
        t_closed = median_time(lambda phi=model.predictor, x=x, segs=segs, prm=prm, reps=reps:
                               [phi(x, segs, prm) for _ in range(reps)], repeats) / reps
        t_num = median_time(lambda phi=phi_num, x=x, segs=segs, prm=prm, reps=reps:
                            [phi(x, segs, prm) for _ in range(reps)], repeats) / reps
        diff = float(np.abs(model.predictor(x, segs, prm) - phi_num(x, segs, prm)).max())
        rows.append(dict(what=f"{label}: closed form", per=t_closed, target=None))
        rows.append(dict(what=f"{label}: numerical (DOP853, 1e-10), {n_seg} segments",
                         per=t_num, target=TARGET_NUMERICAL_PHI, diff=diff))
    for r in rows:
        tgt = "" if r["target"] is None else f" (target {r['target'] * 1e6:g} us)"
        print(f"  {r['what']}: {r['per'] * 1e6:.1f} us{tgt}", flush=True)
    return rows


# -- 4. accuracy against cost -------------------------------------------------------------

def bench_accuracy(case_ids, Ns, repeats):
    rows = []
    for cid in case_ids:
        c = check.case(cid)
        sc = scenarios.get(c.scenario)
        header, ref = c.reference()
        stop = float(ref[-1, 0])
        prev = None
        for N in Ns:
            sets = [*c.sets, f"N={N}"]
            spec = sc.make(sc.resolve(sets))
            res = run_loop(spec, stop, engine="inprocess")
            cost = median_time(lambda spec=spec, stop=stop: run_loop(spec, stop,
                                                                     engine="inprocess"),
                               repeats)
            # the reference is on the N = 100 grid: compare on the common points
            if N >= 100:
                got, want = res.data[:: N // 100], ref[:, 1:]
            else:
                got, want = res.data, ref[:: 100 // N, 1:]
            cols = [res.names.index(n) for n in header[1:]]
            err = float(np.abs(got[:, cols] - want).max())
            order = math.log2(prev / err) if prev and err > 0 and c.kind != "exact" else None
            prev = err
            rows.append(dict(case=cid, kind=c.kind, N=N, error=err, cost=cost, order=order))
            o = "" if order is None else f" order {order:.2f}"
            print(f"  {cid:26s} N={N:<4d} error {err:.3e} cost {cost * 1e3:7.1f} ms{o}",
                  flush=True)
    return rows


# -- report ----------------------------------------------------------------------------------

def versions() -> str:
    import fmpy
    import pythonfmu
    import scipy

    return (f"delaycomp {__version__}, Python {platform.python_version()}, numpy "
            f"{np.__version__}, scipy {scipy.__version__}, fmpy {fmpy.__version__}, "
            f"pythonfmu {pythonfmu.__version__}")


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{platform.system()} {platform.machine()}, {os.cpu_count()} cores ({cpu}); "
            f"load average at start {load:.2f}")


def ok(flag: bool) -> str:
    return "met" if flag else "NOT met"


def speed_targets(spd) -> list[str]:
    """Section 10's rows of the targets table."""
    worst = min(spd["samples"], key=lambda r: r["ratio"])
    best = max(spd["samples"], key=lambda r: r["ratio"])
    same = min(spd["samples"], key=lambda r: r.get("same_host_ratio", 0.0))
    own = min(spd["samples"], key=lambda r: r.get("host_ratio", 0.0))
    host = spd["host"]
    return [f"| native model controller >= {TARGET_NATIVE_SAMPLE:g}x faster per sample than "
            f"the Python one (every nonlinear scenario; both in the same C host, the loop "
            f"with the Python controller against the all-native loop: a lower bound of the "
            f"controllers' own ratio) | worst {same.get('same_host_ratio', 0.0):,.0f}x "
            f"({same['case']}); the Python FMU through fmpy against the native loop in the "
            f"C host: worst {own.get('host_ratio', 0.0):,.0f}x; both through fmpy: worst "
            f"{worst['ratio']:.1f}x ({worst['case']}), best {best['ratio']:.1f}x "
            f"({best['case']}), fmpy's calls being nearly all of the native cost | "
            f"{ok(same.get('same_host_ratio', 0.0) >= TARGET_NATIVE_SAMPLE)} |",
            f"| C host with native FMUs >= {TARGET_HOST_MODEL_REALTIME:,.0f}x real time "
            f"(Example 2.4, {host['stop']:g} s) | {host['rt']:,.0f}x "
            f"({host['loop'] * 1e3:.2f} ms; the whole process: {host['rt_process']:,.0f}x, "
            f"{host['process'] * 1e3:.1f} ms) | "
            f"{ok(host['rt'] >= TARGET_HOST_MODEL_REALTIME)} |"]


def report_speed(spd) -> list[str]:
    """Section 10 of the report."""
    host = spd["host"]
    L = ["", "## 10. Native model controllers and loops", "",
         "Per sample: the model controller alone, its Python FMU (pythonfmu) and its native "
         "FMU (`fmus/controller/model_controller.c`), both driven through fmpy as our master "
         "drives them (per base step `doStep`, `setReal` of the measurements, `getReal` of "
         "the input), fed the same measurements (the plant's states of a loop run, delayed "
         "by r) for the same sampling periods with the loop's T, N, r, tau and parameters, "
         "timed alternately: the time of one sampling period (N base steps, the sample's "
         "prediction included). The last column makes the same fmpy calls on the loop's "
         "native measurement delay (a step that copies a few numbers): what the calls "
         "themselves cost, nearly all of the native controller's column (see the notes). "
         "The last two: the same periods of the whole native loop (plant, delays and "
         "controller) in the C host under `env -i`, per sample (its stepping loop: what "
         "the native controller costs where no Python calls it, at most), and the Python "
         "controller's column over it. Then the same loop in the same C host with "
         "the Python controller FMU in place of the native one (plant and delays native; "
         "libpython preloaded, `PYTHONHOME`, `PYTHONPATH`), timed alternately with the "
         "all-native loop, and the ratio of the two: with P, R and C the costs of the "
         "Python controller, the rest of the loop and the native controller, "
         "`(P + R) / (R + C) <= P / C`, so it is a lower bound of the controllers' own "
         "ratio, measured in one host.", "",
         "| scenario | N | periods | Python [ms/sample] | native [ms/sample] | "
         "Python / native | fmpy calls alone [ms/sample] | native loop, C host "
         "[ms/sample] | Python / C host | loop with the Python controller, C host "
         "[ms/sample] | same host: Python / native |",
         "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in spd["samples"]:
        host_cols = (f"{r['host'] * 1e3:.4f} | {r['host_ratio']:,.0f}x" if "host" in r
                     else "- | -")
        host_cols += (f" | {r['host_py'] * 1e3:.3f} | {r['same_host_ratio']:,.0f}x"
                      if "host_py" in r else " | - | -")
        L.append(f"| {r['case']} | {r['N']} | {r['periods']} | {r['python'] * 1e3:.3f} | "
                 f"{r['native'] * 1e3:.3f} | {r['ratio']:.1f}x | {r['calls'] * 1e3:.3f} | "
                 f"{host_cols} |")
    L += ["", "The whole loop (plant, delays, controller) in our master with all-Python FMUs "
          "and with all-native FMUs, to the scenario's stop time, timed alternately; and "
          f"Example 2.4 ({host['stop']:g} s, {host['rows']:,} rows) in the C host "
          "(`env -i`, no Python in the process) with the native FMUs: its stepping loop and "
          "the whole process (loading, initialization, CSV output, exit).", "",
          "| loop | simulated s | Python FMUs [ms] | native FMUs [ms] | Python / native |",
          "|---|---|---|---|---|"]
    for r in spd["loops"]:
        L.append(f"| {r['case']} | {r['stop']:g} | {r['python'] * 1e3:.1f} | "
                 f"{r['native'] * 1e3:.1f} | {r['ratio']:.1f}x |")
    L += ["", "| C host, Example 2.4 | wall time [ms] | faster than real time |",
          "|---|---|---|",
          f"| stepping loop | {host['loop'] * 1e3:.2f} | {host['rt']:,.0f}x |",
          f"| whole process | {host['process'] * 1e3:.1f} | {host['rt_process']:,.0f}x |"]
    return L


def _steps(n: int) -> str:
    """``n`` with its thousands spaced: 200 000."""
    return f"{n:,}".replace(",", " ")


def _packed_target_name(stop: float, target: float) -> str:
    return (f"`delaycomp run` of Example 3.6 packed with `--native`, `--stop-time {stop:g}` "
            f"({_steps(round(stop / 0.01))} base steps, CSV out, the native stepping core) "
            f"at most {target:g}x OMSimulator's command line (whole processes)")


def packed_targets(pac) -> list[str]:
    return [f"| {_packed_target_name(r['stop'], r['target'])} | {r['ratio']:.2f}x "
            f"(the run replayed from its first run's recipe: {r['core'] * 1e3:.0f} ms against "
            f"{r['omsimulator'] * 1e3:.0f} ms; the first run: {r['first'] * 1e3:.0f} ms, "
            f"{r['first_ratio']:.2f}x; the Python master: {r['master'] * 1e3:.0f} ms, "
            f"{r['master_ratio']:.2f}x) | {ok(r['ratio'] <= r['target'])} |"
            for r in reversed(pac["rows"])]


def report_packed(pac) -> list[str]:
    L = ["", "## 8. A packed loop against OMSimulator", ""]
    if pac is None:
        return [*L, "OMSimulator is not installed here (`DELAYCOMP_OMSIMULATOR`): not "
                    "measured."]
    rows = pac["rows"]
    short = rows[0]
    L += ["Example 3.6 packed with `delaycomp ssp example-3.6 --native` (four native C FMUs, "
          "ticks of 10 ms) and run to each stop time by each command line writing a CSV of "
          "its results; whole processes, timed alternately (medians). `delaycomp run` with "
          "the Python master (`--stepping python`, before) and with the native stepping core "
          "(`--stepping native-core`, after; what `auto` picks here), the latter as a first "
          "run (its recipe removed from a cache of its own before each run) and as a later "
          "run of the same command, replayed from the recipe the first run kept "
          "(`delaycomp.cli.recipes`); the two bare interpreters show what a Python master on "
          "fmpy pays before its first step.", "",
          "| command | " + " | ".join(f"{r['stop']:g} s [ms] | against OMSimulator"
                                     for r in rows) + " |",
          "|---|" + "---|---|" * len(rows)]
    for key, label in (
            ("python", "`python -c pass`"),
            ("fmpy", "`python -c \"import fmpy\"` (numpy, lxml, attrs)"),
            ("master", "`delaycomp run ex36-native.ssp --stop-time S --out dc.csv -q "
                       "--stepping python` (before)"),
            ("first", "`delaycomp run` (native core, first run: FMUs set up through fmpy)"),
            ("core", "`delaycomp run` (native core, replayed from the first run's recipe)"),
            ("omsimulator", "`OMSimulator --stopTime=S --resultFile=oms.csv "
                            "ex36-native.ssp`")):
        L.append(f"| {label} | " + " | ".join(
            f"{r[key] * 1e3:.0f} | {r[key] / r['omsimulator']:.2f}x" for r in rows) + " |")
    start = min((short["python"] + pac["imports"]) / pac["imports_wall"], 1.0)
    stops = " and ".join(f"{r['stop']:g}" for r in rows)
    met = short["ratio"] <= short["target"]
    L += ["", "The Python master takes " + " and ".join(
              f"{r['master'] / r['first']:.1f}x" for r in rows)
          + f" the core's first run's time at {stops} s; the replayed run takes "
          + " and ".join(f"{r['core'] / r['first']:.0%}" for r in rows)
          + " of the first run's. The core's first run writes the Python master's CSV, byte "
            "for byte"
          + ("" if pac["same"] else " (**not here: they differ**)")
          + ", and so does the replayed run"
          + ("" if pac["same_replayed"] else " (**not here: they differ**)")
          + f" (compared at {short['stop']:g} s). The replayed run imports neither numpy nor "
          f"fmpy: at {short['stop']:g} s ({_steps(short['steps'])} base steps) its process "
          f"takes {short['core'] * 1e3:.0f} ms; run under `python -X importtime` it spends "
          f"{pac['imports'] * 1e3:.0f} ms of {pac['imports_wall'] * 1e3:.0f} ms importing "
          f"({pac['imports'] / pac['imports_wall']:.0%}), and with the bare interpreter's "
          f"start (`python -c pass`, {short['python'] * 1e3:.0f} ms) {start:.0%}"
          + ((": Python's start-up and imports, not the stepping, set the short run's time"
              + ("." if met else ", which is why its target is not met."))
             if start >= 0.5 else ("." if met else ". Its target is not met."))]
    return L


def command_options(args) -> str:
    return ((" --quick" if args.quick else "")
            + ("" if args.sections is None
               else " --sections " + ",".join(map(str, sorted(args.sections)))))


def _chunks(text: str) -> list[list[str]]:
    """A report cut before each ``## `` heading and before the figure."""
    out = [[]]
    for line in text.split("\n"):
        if line.startswith(("## ", "![](")):
            out.append([])
        out[-1].append(line)
    return out


def _section_number(chunk) -> float:
    head = chunk[0]
    if head.startswith("## ") and head[3:].split(".")[0].isdigit():
        return int(head[3:].split(".")[0])
    return math.inf if head.startswith("![](") else -1


def merge_report(old: str, new: str, args) -> str:
    """``old`` with what ``new`` (a ``--sections`` run) measured put in: its target rows
    replace those with the same target (first cell) or are added, its sections and notes
    replace those with the same heading or are added in order; the rest of ``old``, its
    numbers and their date, stays, with a line saying what was regenerated when."""
    old_chunks, new_chunks = _chunks(old), _chunks(new)
    heads = [c[0] for c in old_chunks]

    def key(row):
        return row.split("|")[1].strip()

    for chunk in new_chunks[1:]:
        if chunk[0] == "## Targets":
            if "## Targets" not in heads:
                continue
            table = old_chunks[heads.index("## Targets")]
            rows = [i for i, line in enumerate(table) if line.startswith("| ")][1:]
            index = {key(table[i]): i for i in rows}
            added = []
            for line in [x for x in chunk if x.startswith("| ")][1:]:
                if key(line) in index:
                    table[index[key(line)]] = line
                else:
                    added.append(line)
            at = rows[-1] + 1 if rows else len(table)
            table[at:at] = added
        elif chunk[0].startswith("## ") and chunk[0] in heads:
            old_chunks[heads.index(chunk[0])] = chunk
        elif chunk[0].startswith("## "):
            n = _section_number(chunk)
            at = next((i for i, c in enumerate(old_chunks) if i and _section_number(c) > n),
                      len(old_chunks))
            old_chunks.insert(at, chunk)
            heads.insert(at, chunk[0])
    # one note per section run alone, in section order: this run's replace their own,
    # the other sections' notes stay
    pre = old_chunks[0]
    when = time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())
    notes = {_note_section(line): line for line in pre if _note_section(line) is not None}
    for n in args.sections:
        notes[n] = (f"- Section {n} regenerated by `python bench/run.py"
                    f"{command_options(args)}` on {when} (medians of {args.repeats} "
                    "repeats); the other numbers are from the run above.")
    pre = [line for line in pre if _note_section(line) is None]
    at = max((i for i, line in enumerate(pre) if line.startswith("- ")), default=len(pre) - 1)
    pre[at + 1:at + 1] = [notes[n] for n in sorted(notes)]
    old_chunks[0] = pre
    return "\n".join(line for chunk in old_chunks for line in chunk)


def _note_section(line: str) -> int | None:
    """The section number of a report's note ``- Section N regenerated by ...``, else
    ``None``."""
    m = re.match(r"- Section (\d+) regenerated by ", line)
    return int(m[1]) if m else None


def write_report(path, results, args) -> None:
    """The report of the sections in ``results``: all of them, or with ``--sections``,
    those put into the report already at ``path`` (``merge_report``)."""
    e36, eng, mas, pred, acc, nat, sta, imp, pac, spd = (results.get(k) for k in (
        "ex36", "engines", "master", "predictors", "accuracy", "native", "start",
        "fmu_imports", "packed", "speed"))
    L = ["# Benchmarks", "",
         f"Generated by `python bench/run.py{command_options(args)}` on "
         f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.", "",
         f"- Machine: {machine()}",
         f"- Versions: {versions()}",
         f"- Medians of {args.repeats} repeats; the compared runs are timed alternately. BLAS "
         "on one thread.", "",
         "## Targets", "",
         "| target | measured | status |", "|---|---|---|"]
    if e36 is not None:
        L.append(f"| Example 3.6 (20 s, N = 100, FMUs) >= {TARGET_REALTIME:g}x real time | "
                 f"{e36['realtime']:.0f}x ({e36['fmu'] * 1e3:.0f} ms; the first run in a fresh "
                 f"process, unpacking the FMUs: {20.0 / e36['cold']:.0f}x, "
                 f"{e36['cold'] * 1e3:.0f} ms) | {ok(e36['realtime'] >= TARGET_REALTIME)} |")
        L.append(f"| in-process >= {TARGET_INPROCESS:g}x faster than the FMU loop (Example 3.6, "
                 f"20 s) | {e36['ratio']:.1f}x ({e36['inprocess'] * 1e3:.1f} ms) | "
                 f"{ok(e36['ratio'] >= TARGET_INPROCESS)} |")
    if mas is not None:
        worst = max(mas, key=lambda r: r["ratio"])
        L.append(f"| master <= {TARGET_MASTER:g}x the bare FMU calls | worst "
                 f"{worst['ratio']:.2f}x ({worst['scenario']}) | "
                 f"{ok(worst['ratio'] <= TARGET_MASTER)} |")
    if pred is not None:
        for r in pred:
            if r["target"] is not None:
                L.append(f"| {r['what']} <= {r['target'] * 1e6:g} us | {r['per'] * 1e6:.1f} us | "
                         f"{ok(r['per'] <= r['target'])} |")
    if nat is not None:
        L.append(f"| native FMUs in our master >= {TARGET_NATIVE:g}x faster than the Python FMUs "
                 f"(Example 3.6, 20 s) | {nat['ratio']:.1f}x ({nat['native'] * 1e3:.1f} ms against "
                 f"{nat['python'] * 1e3:.1f} ms) | {ok(nat['ratio'] >= TARGET_NATIVE)} |")
        L.append(f"| C host with native FMUs >= {TARGET_HOST_REALTIME:,.0f}x real time (Example "
                 f"3.6, 20 s) | {nat['host_rt']:,.0f}x ({nat['host_loop'] * 1e6:.0f} us; the whole "
                 f"process: {nat['host_rt_process']:,.0f}x, {nat['host_process'] * 1e3:.1f} ms) | "
                 f"{ok(nat['host_rt'] >= TARGET_HOST_REALTIME)} |")
    if pac is not None:
        L += packed_targets(pac)
    if sta is not None:
        L.append(f"| `delaycomp --help` within {TARGET_START:g}x of `python -c pass` (whole "
                 f"processes) | {sta['help_ratio']:.1f}x ({sta['help'] * 1e3:.0f} ms against "
                 f"{sta['python'] * 1e3:.0f} ms) | {ok(sta['help_ratio'] <= TARGET_START)} |")
    if spd is not None:
        L += speed_targets(spd)
    if eng is not None:
        L += ["", "## 1. Wall time per simulated second", "",
              "Each run about 2000 base steps (a whole number of periods, at most the scenario's "
              "stop time), setup included.", "",
              "| scenario | N | simulated s | fmu [ms/s] | inprocess [ms/s] | fmu / inprocess |",
              "|---|---|---|---|---|---|"]
        for r in eng:
            L.append(f"| {r['scenario']} | {r['N']} | {r['stop']:g} | {r['fmu'] * 1e3:.2f} | "
                     f"{r['inprocess'] * 1e3:.2f} | {r['ratio']:.1f} |")
    if mas is not None:
        L += ["", "## 2. The master's own share", "",
              "The master (with its recorder) stepping the FMUs, against a bare loop making the "
              "same fmpy calls in the same order (N = 100, setup excluded).", "",
              "| scenario | ticks | master [us/tick] | bare calls [us/tick] | ratio |",
              "|---|---|---|---|---|"]
        for r in mas:
            L.append(f"| {r['scenario']} | {r['ticks']} | {r['master'] * 1e6:.1f} | "
                     f"{r['bare'] * 1e6:.1f} | {r['ratio']:.2f} |")
    if pred is not None:
        L += ["", "## 3. Predictor cost per sample", "",
              "| predictor | per sample [us] | target [us] | closed vs numerical |",
              "|---|---|---|---|"]
        for r in pred:
            tgt = "" if r["target"] is None else f"{r['target'] * 1e6:g}"
            diff = f"{r['diff']:.1e}" if "diff" in r else ""
            L.append(f"| {r['what']} | {r['per'] * 1e6:.1f} | {tgt} | {diff} |")
    if acc is not None:
        L += ["", "## 4. Accuracy against cost", "",
              "Largest pointwise error against the reference trace (in-process engine, which "
              "equals the FMUs to the bit); `exact` loops are exact at every N, the "
              "continuous-input loops converge at first order in h.", "",
              "| case | kind | N | largest error | cost [ms] | observed order |",
              "|---|---|---|---|---|---|"]
        for r in acc:
            o = "" if r["order"] is None else f"{r['order']:.2f}"
            L.append(f"| {r['case']} | {r['kind']} | {r['N']} | {r['error']:.3e} | "
                     f"{r['cost'] * 1e3:.1f} | {o} |")
    if nat is not None:
        L += ["", "## 5. Native C FMUs", "",
              "Example 3.6 (20 s, N = 100, 2001 rows). Our master with the Python FMUs and with "
              "the native ones, timed alternately; the C host (`fmus/native/host/host.c`, run "
              "under `env -i`, no Python in the process) with the native FMUs: its stepping "
              "loop, and the whole process (loading, initialization, CSV output, exit).", "",
              "| run | wall time [ms] | faster than real time |", "|---|---|---|",
              f"| our master, Python FMUs | {nat['python'] * 1e3:.1f} | "
              f"{20.0 / nat['python']:,.0f}x |",
              f"| our master, native FMUs | {nat['native'] * 1e3:.1f} | "
              f"{20.0 / nat['native']:,.0f}x |",
              f"| C host, stepping loop | {nat['host_loop'] * 1e3:.3f} | {nat['host_rt']:,.0f}x |",
              f"| C host, whole process | {nat['host_process'] * 1e3:.1f} | "
              f"{nat['host_rt_process']:,.0f}x |"]
    if sta is not None:
        L += ["", "## 6. Start", "",
              "Whole processes, timed alternately (medians): what a user waits for before any "
              "work. `--help` and `list` import neither scipy nor matplotlib nor fmpy, "
              "nor numpy (tests/test_start.py).", "",
              "| command | wall time [ms] | against `python -c pass` |", "|---|---|---|",
              f"| `python -c pass` | {sta['python'] * 1e3:.0f} | 1x |",
              f"| `delaycomp --help` | {sta['help'] * 1e3:.0f} | {sta['help_ratio']:.1f}x |",
              f"| `delaycomp list` | {sta['list'] * 1e3:.0f} | {sta['list_ratio']:.1f}x |"]
    if imp is not None:
        L += ["", "## 7. Python FMUs: what instantiating one imports", "",
              "Each FMU instantiated in a fresh interpreter as pythonfmu's binary does it in a "
              "host (resources folder first on `sys.path`, the slave module imported, the class "
              "called): the time from the import to the instance (medians), the installed "
              "packages and scipy subpackages it loaded, and the bundled delaycomp modules. A "
              "host pays this once per process. `tests/test_start.py` holds each FMU to its "
              "list.", "",
              "| FMU | instantiation [ms] | packages | scipy | delaycomp modules | modules |",
              "|---|---|---|---|---|---|"]
        for r in imp:
            L.append(f"| {r['fmu']} | {r['seconds'] * 1e3:.0f} | {', '.join(r['packages'])} | "
                     f"{', '.join(r['scipy']) or '-'} | {', '.join(r['delaycomp'])} | "
                     f"{r['modules']} |")
    if "packed" in results:
        L += report_packed(pac)
    if "exact_grid" in results:
        L += report_exact_grid(results["exact_grid"])
    if spd is not None:
        L += report_speed(spd)
    if results.get("export") is not None:
        L += report_export(results["export"])
    if results.get("sweep_points") is not None:
        L += report_sweep_points(results["sweep_points"])
    L += ["", "![](docs/figures/benchmarks.png)", ""]
    notes = REPO / "bench" / "NOTES.md"
    if notes.exists():
        L += [notes.read_text(encoding="utf-8").rstrip(), ""]
    text = "\n".join(L)
    if args.sections is not None and Path(path).exists():
        text = merge_report(Path(path).read_text(encoding="utf-8"), text, args)
    Path(path).write_text(text, encoding="utf-8")


def plot(path, results) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    eng = [r for r in results["engines"] if r["N"] == 100]
    x = np.arange(len(eng))
    a1.bar(x - 0.2, [r["fmu"] * 1e3 for r in eng], 0.4, label="fmu")
    a1.bar(x + 0.2, [r["inprocess"] * 1e3 for r in eng], 0.4, label="inprocess")
    a1.set_xticks(x, [r["scenario"] for r in eng], rotation=30, ha="right", fontsize=8)
    a1.set_ylabel("wall time per simulated second [ms] (N = 100)")
    a1.set_yscale("log")
    a1.legend()
    a1.grid(True, axis="y", alpha=0.3)
    for cid in dict.fromkeys(r["case"] for r in results["accuracy"]):
        rows = [r for r in results["accuracy"] if r["case"] == cid]
        a2.loglog([r["cost"] * 1e3 for r in rows], [max(r["error"], 1e-17) for r in rows],
                  "o-", label=cid)
    a2.set_xlabel("cost of one run [ms] (in-process)")
    a2.set_ylabel("largest error against the reference")
    a2.legend(fontsize=7)
    a2.grid(True, alpha=0.3)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def compile_package() -> None:
    """Byte-compile the package (``delaycomp``, ``orchestrator``, ``fmus``) as ``pip
    install`` does, so the start-up rows time an installed package."""
    import compileall

    for folder in ("delaycomp", "orchestrator", "fmus"):
        compileall.compile_dir(REPO / folder, quiet=1)


def _sections(text: str) -> set[int]:
    try:
        picked = {int(x) for x in text.split(",") if x.strip()}
    except ValueError:
        picked = set()
    if not picked or not picked <= set(range(1, 13)):
        raise argparse.ArgumentTypeError(f"{text!r}: section numbers 1-12, comma-separated")
    return picked


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="one repeat of one scenario: checks the script, measures nothing")
    ap.add_argument("--out", type=Path, default=REPO / "BENCHMARKS.md")
    ap.add_argument("--plot", type=Path, default=REPO / "docs" / "figures" / "benchmarks.png")
    ap.add_argument("--sections", type=_sections, default=None, metavar="N[,N...]",
                    help="run only these sections (numbers 1-12, as in the report) and put "
                         "their rows and tables into the report already at --out, the other "
                         "numbers kept (the plot is redrawn only with sections 1 and 4)")
    args = ap.parse_args(argv)
    args.repeats = 1 if args.quick else 7
    names = ["example-3.6"] if args.quick else list(scenarios.SCENARIOS)
    Ns = (10,) if args.quick else (10, 100, 1000)
    run = set(args.sections or range(1, 13))
    results = {}
    compile_package()
    with tempfile.TemporaryDirectory(prefix="delaycomp-bench-") as tmp, single_threaded_blas():
        os.environ.setdefault("DELAYCOMP_CACHE_DIR", str(Path(tmp) / "cache"))
        fmu_dir = Path(tmp) / "fmus"
        if run & {1, 2}:
            print("building FMUs ...", flush=True)
            for name in names:
                sc = scenarios.get(name)
                for kind, config in (i.source.build_key() for i in sc.loop([]).instances):
                    fmu_path(kind, config, fmu_dir)
        if 1 in run:
            print("Example 3.6 against real time", flush=True)
            results["ex36"] = bench_example_3_6(args.repeats, fmu_dir)
            print("1. engines", flush=True)
            results["engines"] = bench_engines(names, Ns, args.repeats, fmu_dir)
        if 2 in run:
            print("2. master overhead", flush=True)
            results["master"] = bench_master(names, args.repeats, fmu_dir)
        if 3 in run:
            print("3. predictors", flush=True)
            results["predictors"] = bench_predictors(args.repeats)
        if 6 in run:
            print("6. start", flush=True)
            results["start"] = bench_start(args.repeats)
        if 8 in run:
            print("8. a packed loop against OMSimulator", flush=True)
            results["packed"] = bench_packed(args.repeats, Path(tmp),
                                             1 if args.quick else None)
        if 7 in run:
            print("7. Python FMUs", flush=True)
            results["fmu_imports"] = bench_fmu_imports(args.repeats, fmu_dir)
        if 5 in run:
            print("5. native C FMUs", flush=True)
            results["native"] = bench_native(args.repeats, fmu_dir, Path(tmp))
        if 9 in run:
            print("9. exact-grid steps", flush=True)
            results["exact_grid"] = bench_exact_grid(args.repeats, Path(tmp),
                                                     2000 if args.quick else 50_000)
        if 10 in run:
            print("10. native model controllers and loops", flush=True)
            results["speed"] = bench_speed(SPEED_CASES[:1] if args.quick else SPEED_CASES,
                                           args.repeats, fmu_dir, Path(tmp),
                                           2 if args.quick else 20)
        if 11 in run:
            print("11. exported controllers", flush=True)
            results["export"] = bench_export(20_000 if args.quick else 1_000_000, Path(tmp))
        if 12 in run:
            print("12. per-point sweep of a native model loop", flush=True)
            results["sweep_points"] = bench_sweep_points(args.repeats, Path(tmp),
                                                         2 if args.quick else 8,
                                                         1 if args.quick else None)
        if 4 in run:
            print("4. accuracy against cost", flush=True)
            cases = (["example-2.4/default"] if args.quick else
                     ["example-3.6/fig3", "example-3.8/default", "example-2.4/default",
                      "corollary-4.1/default"])
            results["accuracy"] = bench_accuracy(cases, (50, 100) if args.quick else
                                                 (50, 100, 200, 400),
                                                 max(1, args.repeats // 2))
    write_report(args.out, results, args)
    if "engines" in results and "accuracy" in results:
        plot(args.plot, results)
        print(f"wrote {args.out} and {args.plot}")
    else:
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    # leave as the delaycomp command does (delaycomp.cli.entry): the bench loads pythonfmu
    # FMUs in this process, and unloading them in the interpreter's teardown corrupts the
    # heap now and then ("corrupted double-linked list", SIGABRT) after the report is
    # written
    import atexit

    code = main()
    atexit._run_exitfuncs()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
