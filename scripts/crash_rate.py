"""One-off measurement: does a host survive a user model that raises? (README, "Reliability")

Runs, ``--runs`` times, a fresh Python process that co-simulates a model whose ``k`` raises
``SystemExit`` (or ``--raise KeyboardInterrupt``, ``RuntimeError``) at t = 0.5 through the
FMUs (fmpy), prints the run's message and leaves through normal interpreter exit (FMU
libraries unloaded by the interpreter's teardown). Counts the exit statuses: 3 means the
run failed cleanly with the reason; anything else (a signal, status 0 with no result) is a
crash. Usage::

    python scripts/crash_rate.py --runs 100
"""

from __future__ import annotations

import argparse
import collections
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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--raise", dest="exc", default="SystemExit")
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="delaycomp-crash-"))
    model = folder / "raising_model.py"
    model.write_text(MODEL.format(exc=args.exc), encoding="utf-8")
    statuses = collections.Counter()
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


if __name__ == "__main__":
    main()
