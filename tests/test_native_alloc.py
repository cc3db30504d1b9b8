"""Issue 33, item 1: the native FMUs allocate nothing while they step.

An ``LD_PRELOAD`` library (``tests/native_alloc/count_alloc.c``) counts every ``malloc``,
``calloc``, ``realloc`` (and the aligned variants) of the C host's process, its own and the
FMUs'; the host runs each native loop for 10^3 and for 10^5 base steps, on exact-grid steps
(``t_{k+1} - t_k`` of ``t_k = t0 + k h``) and on constant steps. What initialization
allocates (the instances, the model buffers, the host's own tables) is the same in all
four runs, so the four counts are equal exactly when no step allocates. The same again
from ``t0 = 1e5``, where an exact grid's steps differ from ``h`` by more than
``GRID_RTOL h`` and only the FMUs' rule for their own step (``same_step`` in
``fmus/native/native.c``) tells them apart from another step. glibc only
(``__libc_malloc``): Linux, as the rest of the C-host tests.
"""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are

from delaycomp.fmu.host import host_argv, unpack
from delaycomp.fmu.native import compiler
from delaycomp.fmu.twins import native_fmus
from delaycomp.paper import scenarios
from delaycomp.paper.scenarios import lti_loop

from .tiers import tiered

COUNTER = Path(__file__).parent / "native_alloc" / "count_alloc.c"

#: every native loop kind: LTI (scalar and MIMO), each nonlinear scenario (closed and
#: numerical predictors, continuous input and zero-order hold, padding)
LOOPS = {
    "example-3.6": lambda: _scenario("example-3.6", []),
    "mimo-n3-m2": lambda: stable_mimo_loop(),  # defined below
    "example-2.4": lambda: _scenario("example-2.4", []),
    "example-2.4-numerical": lambda: _scenario("example-2.4", ["predictor=numerical"]),
    "example-3.8-padded": lambda: _scenario("example-3.8", ["tau=0.5", "pad=true"]),
    "corollary-4.1": lambda: _scenario("corollary-4.1", []),
    "proposition-4.2": lambda: _scenario("proposition-4.2", []),
}


def stable_mimo_loop():
    """n = 3, m = 2, an unstable plant (an eigenvalue 0.045) under an LQR gain, ``T = 0.5``,
    ``r = 0.35`` (a fractional part of T), ``tau = 0.5``, ``N = 10``, compensated: stable
    over 10^5 base steps (the sampled closed loop's eigenvalues are below 0.77)."""
    rng = np.random.default_rng(7)
    A = rng.standard_normal((3, 3)) * 0.5
    B = rng.standard_normal((3, 2))
    K = -B.T @ solve_continuous_are(A, B, np.eye(3), np.eye(2))
    return lti_loop(A, B, K, T=0.5, r=0.35, tau=0.5, N=10, mode="compensated",
                    x0=(1.0, -0.5, 0.25), u0=(0.3, -0.2))


def _scenario(name, sets):
    sc = scenarios.get(name)
    return sc.make(sc.resolve(sets))


@pytest.fixture(scope="module")
def counter(tmp_path_factory, chost):
    tmp = tmp_path_factory.mktemp("alloc")
    lib = tmp / "count_alloc.so"
    subprocess.run([*compiler(), "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-shared",
                    "-fPIC", "-o", str(lib), str(COUNTER)], check=True)
    return lib, chost


def _count(counter, loop, dirs, steps, exact, start, tmp_path) -> dict[str, int]:
    lib, host = counter
    out = tmp_path / f"count-{steps}-{exact}-{start}.txt"
    stop = start + steps * loop.h
    proc = subprocess.run(["env", "-i", f"ALLOC_COUNT_FILE={out}", f"LD_PRELOAD={lib}",
                           *host_argv(host, loop, stop, dirs, exact_grid=exact, start=start)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert len(proc.stdout.splitlines()) == steps + 2  # the header, t0 .. t0 + steps h
    fields = dict(item.split("=") for item in out.read_text().split())
    return {k: int(v) for k, v in fields.items()}


@pytest.mark.parametrize("name", tiered(sorted(LOOPS), {"mimo-n3-m2", "example-3.8-padded"}))
@pytest.mark.parametrize("start", [0.0, 1e5], ids=["t0=0", "t0=1e5"])
def test_no_allocation_while_stepping(name, start, counter, tmp_path):
    """The four counts (10^3 and 10^5 steps, exact grid and constant steps) are equal, and
    the counter sees the FMUs' own allocations (each of the four instances is calloc'd by
    fmi2Instantiate, inside a dlopen'ed library)."""
    loop = LOOPS[name]()
    dirs = unpack(native_fmus(loop, tmp_path / "cache"), tmp_path / "fmus")
    counts = {(steps, exact): _count(counter, loop, dirs, steps, exact, start, tmp_path)
              for steps in (1000, 100_000) for exact in (False, True)}
    first = counts[(1000, False)]
    assert first["calloc"] >= 4 and first["total"] > 4, first
    for key, got in counts.items():
        assert got == first, (key, got, first)


#: a model whose flow is as fast as its input is large: w = 1 + stiff u^2 rad/s. With
#: u = 0 (u0) it is slow; with |u| up to 0.6 a sampling period of 0.1 s needs up to some
#: 3e4 DOP853 steps at tol 1e-10 (within the budget of 100 000 alone, not ten of them)
FAST = '''
import numpy as np
STATES = ("x1", "x2")
INPUTS = ("u",)
CONTROL = "zoh"
PARAMETERS = {"stiff": 3e5}

def f(x, u, p):
    w = 1.0 + p["stiff"] * u[0] * u[0]
    return np.array([w * x[1], -w * x[0]])

def k(x, p):
    return np.array([-0.5 * x[0]])
'''


def _drive_fast(comp, tau, ys, h):
    comp.setup(0.0, h * len(ys), {"T": 0.1, "N": 1, "r": 0.0, "tau": tau,
                                  "predictor": "numerical"})
    comp.initialize()
    out = []
    for i, y in enumerate(ys):
        comp.set_inputs(["y_x1", "y_x2"], list(y))
        out.append(comp.get_outputs(["u"])[0])
        comp.do_step(i * h, h)
    return out


def test_a_prediction_has_a_bounded_budget_and_is_refused_past_it(tmp_path):
    """Item 1's work bound (``MAX_ODE_STEPS`` of ``model_common.h``): a prediction may
    try at most 100 001 DOP853 steps over all the segments of its window. With a window
    of one period (tau = 0.1 s) every prediction fits; with ten periods (tau = 1 s) of
    the same inputs, segments that each fit add up past the budget, and the controller
    refuses the sample with the integrator's reason and the window's time, at once,
    instead of integrating on. The outputs read NaN from then on (the error state)."""
    from fmpy.fmi1 import FMICallException

    from delaycomp.fmu.native import build_native_fmu
    from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused

    model = tmp_path / "fast.py"
    model.write_text(FAST, encoding="utf-8")
    fmu = build_native_fmu("model_controller", tmp_path / "fmu", {"model": str(model)})
    rng = np.random.default_rng(3)
    ys = np.column_stack([rng.uniform(0.5, 1.0, 14), rng.uniform(-1.0, 1.0, 14)])
    comp = FmuComponent("c", fmu)
    try:
        short = _drive_fast(comp, 0.1, ys, 0.1)
    finally:
        comp.terminate()
    assert np.all(np.isfinite(short)) and len(set(short)) > 10
    comp = FmuComponent("c", fmu)
    try:
        with pytest.raises((FmuRefused, FMICallException)):
            _drive_fast(comp, 1.0, ys, 0.1)
        message = comp.messages[-1]
    finally:
        comp.terminate()
    # refused in a later segment of the window: the earlier ones, solved, spent the budget
    found = re.search(r"ODE solve failed (\S+) s into a window \(input .*\): larger nsteps "
                      r"is needed", message)
    assert found and float(found.group(1)) >= 0.3, message
