"""One-off measurement: memory over a long co-simulation (README, "Reliability").

Runs a scenario for many base steps through the FMUs and the master, recording one row in
``--every`` ticks, and prints the process's resident set size (VmRSS) and the length of
every hidden buffer at checkpoints. Usage::

    python scripts/long_run_memory.py example-3.6 --ticks 1000000 --every 1000
"""

from __future__ import annotations

import argparse
import json
import time

from delaycomp import scenarios
from delaycomp.simulate import make_master, parameters_of


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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--ticks", type=int, default=1_000_000)
    ap.add_argument("--every", type=int, default=1000)
    ap.add_argument("--checkpoints", type=int, default=10)
    args = ap.parse_args()
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
