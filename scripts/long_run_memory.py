"""One-off measurement: memory over a long co-simulation (docs/explanation/reliability.md).

Runs a scenario for many base steps through the FMUs and the master, recording one row in
``--every`` ticks, and prints the process's resident set size (VmRSS) and the length of
every hidden buffer at checkpoints. Usage::

    python scripts/long_run_memory.py example-3.6 --ticks 1000000 --every 1000
    python scripts/long_run_memory.py corollary-4.1 --set predictor=numerical
    python scripts/long_run_memory.py --user-model --ticks 1000000

``--user-model`` runs a model file written here with ``f`` and ``k`` only (no ``step``,
no closed-form ``predictor``): the plant steps and the predictor are ODE solves.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from delaycomp.orchestrator.simulate import make_master, parameters_of
from delaycomp.paper import scenarios


def rss_kib() -> int:
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS")


def buffer_lengths(master) -> dict:
    out = {}
    for name, state in master.get_state()["components"].items():
        hidden = json.loads(state)["hidden"]
        for key, value in _lists(hidden):
            out[f"{name}.{key}"] = len(value)
    return out


def _lists(obj, prefix=""):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _lists(v, f"{prefix}{k}." if isinstance(v, dict) else f"{prefix}{k}")
    elif isinstance(obj, list) and obj and isinstance(obj[0], list):
        yield prefix, obj


#: a user model with neither ``step`` nor ``predictor``: x' = -x + x^3 / 10 + u, k = -x
USER_MODEL = '''"""Memory measurement: a model whose plant and predictor are ODE solves."""
import numpy as np
STATES = ("x",)
INPUTS = ("u",)
CONTROL = "zoh"
def f(x, u, p):
    return np.array([-x[0] + x[0] ** 3 / 10 + u[0]])
def k(x, p):
    return np.array([-x[0]])
'''


def user_spec(folder: Path):
    model = folder / "memory_user_model.py"
    model.write_text(USER_MODEL, encoding="utf-8")
    return scenarios.model_loop(model, T=0.1, r=0.05, tau=0.1, N=10, x0=[1.0], u0=[0.0],
                                predictor="numerical")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario", nargs="?")
    ap.add_argument("--user-model", action="store_true")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--ticks", type=int, default=1_000_000)
    ap.add_argument("--every", type=int, default=1000)
    ap.add_argument("--checkpoints", type=int, default=10)
    args = ap.parse_args()
    if args.user_model:
        spec = user_spec(Path(tempfile.mkdtemp(prefix="delaycomp-memory-")))
    else:
        sc = scenarios.get(args.scenario)
        spec = sc.make(sc.resolve(args.set))
    stop = args.ticks * spec.T / spec.N
    master, rec = make_master(spec, every=args.every)
    started = time.perf_counter()
    try:
        master.setup(stop, parameters_of(spec))
        master.initialize()
        print(f"start: rss {rss_kib()} KiB, buffers {buffer_lengths(master)}", flush=True)
        for c in range(1, args.checkpoints + 1):
            master.run_until(args.ticks * c // args.checkpoints)
            print(f"tick {master.k}: rss {rss_kib()} KiB, rows {len(rec.rows)}, "
                  f"{time.perf_counter() - started:.0f} s", flush=True)
        print(f"end: buffers {buffer_lengths(master)}; last row {rec.times[-1]} "
              f"{rec.rows[-1]}", flush=True)
    finally:
        master.terminate()


if __name__ == "__main__":
    main()
