"""One-off measurement: does a host survive a user model that raises?
(docs/explanation/reliability.md)

Runs, ``--runs`` times, a fresh Python process that co-simulates a model whose ``k`` raises
``SystemExit`` (or ``--raise KeyboardInterrupt``, ``RuntimeError``) at t = 0.5 through the
FMUs (fmpy), prints the run's message and leaves through normal interpreter exit (FMU
libraries unloaded by the interpreter's teardown). Counts the exit statuses: 3 means the
run failed cleanly with the reason; anything else (a signal, status 0 with no result) is a
crash. Usage::

    python scripts/crash_rate.py --runs 100

With ``--fmi-sequences`` it counts instead the exits of fresh plain-fmpy hosts that run FMI
call sequences, legal and illegal, on the Python FMUs of the default loop (plant, delay,
controller, built from these sources unless ``--fmu-dir`` names a folder of them) and leave
through normal interpreter exit (``scripts/fmi_sequence_child.py``; issue 30, item 10:
the teardown heap corruption). ``--runs`` runs per sequence; a crash is any exit but 0
with ``DONE`` printed::

    python scripts/crash_rate.py --fmi-sequences --runs 300
"""

from __future__ import annotations

import argparse
import collections
import concurrent.futures
import subprocess
import sys
import tempfile
from pathlib import Path

MODEL = '''"""k raises {exc} at t >= 0.5: a misbehaving user model."""
import numpy as np
STATES = ("x",)
INPUTS = ("u",)
CONTROL = "zoh"
def f(x, u, p):
    return np.array([-x[0] + u[0]])
def step(x, u, h, p):
    return np.array([np.exp(-h) * x[0] + (1 - np.exp(-h)) * u[0]])
def k(x, p):
    if abs(x[0]) < 0.7:
        raise {exc}("k gave up")
    return np.array([-0.1 * x[0]])
'''

CHILD = '''
import sys
from delaycomp.paper.scenarios import model_loop
from delaycomp.orchestrator.simulate import run_loop
spec = model_loop(sys.argv[1], T=0.1, r=0.0, tau=0.0, N=1, x0=[1.0], u0=[0.0])
result = run_loop(spec, 2.0, sys.argv[2])
print(result.message)
sys.exit(3 if not result.success and "k gave up" in result.message else 4)
'''


def raising_model(args: argparse.Namespace) -> None:
    """Count the exits of hosts whose user model raises ``args.exc`` (module docstring)."""
    folder = Path(tempfile.mkdtemp(prefix="delaycomp-crash-"))
    model = folder / "raising_model.py"
    model.write_text(MODEL.format(exc=args.exc), encoding="utf-8")
    statuses: collections.Counter[int] = collections.Counter()
    last = ""
    for i in range(args.runs):
        proc = subprocess.run([sys.executable, "-c", CHILD, str(model), str(folder / "fmus")],
                              capture_output=True, text=True, timeout=300)
        statuses[proc.returncode] += 1
        last = proc.stdout.strip() or proc.stderr.strip()[-300:]
        if proc.returncode != 3:
            print(f"run {i}: status {proc.returncode}: {proc.stderr.strip()[-300:]}",
                  flush=True)
    print(f"{args.exc}: {args.runs} runs, exit statuses {dict(statuses)}; "
          f"crashes (not 3): {args.runs - statuses[3]}; last message: {last}")


SEQUENCE_CHILD = Path(__file__).resolve().parent / "fmi_sequence_child.py"


def run_sequence(sequence: str, fmus: list[str]) -> tuple[int, str]:
    """One fresh host running ``sequence`` on ``fmus``: its exit status (-1: it exited 0
    without ``DONE``) and the end of its stderr."""
    proc = subprocess.run([sys.executable, str(SEQUENCE_CHILD), sequence, *fmus],
                          capture_output=True, text=True, timeout=300)
    status = proc.returncode
    if status == 0 and f"DONE {sequence}" not in proc.stdout:
        status = -1
    return status, proc.stderr.strip()[-300:]


def default_fmus(fmu_dir: str | None) -> list[str]:
    """The plant, delay and controller FMUs in ``fmu_dir``, else built from these sources
    into a new temporary folder."""
    if fmu_dir is None:
        from delaycomp.fmu.build import build_all

        return [str(p) for p in build_all(Path(tempfile.mkdtemp(prefix="delaycomp-heap-")))]
    names = ("DelaycompPlantLTI.fmu", "DelaycompDelay.fmu", "DelaycompControllerLTI.fmu")
    return [str(Path(fmu_dir) / n) for n in names]


def fmi_sequences(args: argparse.Namespace) -> None:
    """Count, per call sequence, the crashed exits of ``args.runs`` fresh hosts."""
    sys.path.insert(0, str(SEQUENCE_CHILD.parent))
    from fmi_sequence_child import SEQUENCES

    fmus = default_fmus(args.fmu_dir)
    total: collections.Counter[str] = collections.Counter()
    with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
        for sequence in args.sequence or list(SEQUENCES):
            results = list(pool.map(run_sequence, [sequence] * args.runs,
                                    [fmus] * args.runs))
            statuses = collections.Counter(status for status, _ in results)
            crashes = args.runs - statuses[0]
            total.update(runs=args.runs, crashes=crashes)
            example = next((err.splitlines()[-1] for status, err in results
                            if status != 0 and err), "")
            print(f"{sequence}: {crashes} crashes of {args.runs} runs, exit statuses "
                  f"{dict(statuses)} {example}".rstrip(), flush=True)
    print(f"all sequences: {total['crashes']} crashes of {total['runs']} runs")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--raise", dest="exc", default="SystemExit")
    ap.add_argument("--fmi-sequences", action="store_true",
                    help="count the exits of hosts running FMI call sequences instead")
    ap.add_argument("--sequence", action="append",
                    help="with --fmi-sequences: this sequence only (repeatable)")
    ap.add_argument("--fmu-dir", help="with --fmi-sequences: the FMUs to run")
    ap.add_argument("--jobs", type=int, default=1, help="hosts running at once")
    args = ap.parse_args()
    if args.fmi_sequences:
        fmi_sequences(args)
    else:
        raising_model(args)


if __name__ == "__main__":
    main()
