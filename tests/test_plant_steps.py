"""The LTI plant FMUs (Python and native) on a host's exact grid (issue 34, item 5).

A host that keeps time exactly (``t_k = t0 + k h``, as the FMI guides ask) passes steps
``t_{k+1} - t_k`` that differ from ``h`` in the last bits. Both plant FMUs key their
discretization ``Ad(h), Bd(h)`` on their own grid (``delaycomp.maths.grid.same_step``): a
step within ``GRID_RTOL`` of the cached step is that step, another one is discretized and
becomes the key. What is checked, and why each tolerance:

- an exact grid gives the trajectory of constant steps ``h1 = t_1 - t_0`` (the first step
  of the grid, the key) bit for bit: the same cached matrices times the same states, in one
  process; from ``t0 = 0`` that is ``h`` itself (``0 + h`` is exact). Against constant
  steps ``h`` the run is the exact flow over ``k h1`` instead of ``k h``: a time shift
  ``k |h1 - h|``, so ``|x_k - x(k h)| <= k |h1 - h| max |x'|`` plus the round-off of the
  two recursions (below);
- a step within the tolerance (``h (1 + 1e-12)``, ``h (1 - 5e-10)``) gives bit for bit the
  result of the step ``h``: the cache is used (a recomputed ``Ad`` differs in its last
  bits, and so would the state);
- a step outside it (``h / 2``, ``h (1 + 1e-6)``, ``h (1 + 2e-9)``) is recomputed: the state
  is the exact flow over that step, to the flow's round-off (``1e3 max(1, ||A||_1) eps`` of
  the largest entry, as for the C flow against scipy in ``tests/test_native.py``), while the
  cached ``Ad(h)`` would be off by ``|step - h| |x'|``, ``1e-9 |x'|`` or more.

Round-off of a recursion ``x_{k+1} = Ad x_k + Bd u`` (``n + m`` products per entry): at
most ``gamma = (n + m) eps`` of ``|Ad| |x_k| + |Bd| |u|`` per step, carried by the
contracting ``Ad`` of the stable test plant; over ``K`` steps two runs are within
``2 K gamma`` of the peak (a worst case; measured a few eps).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from delaycomp.fmu.build import DEFAULT_CONFIG
from delaycomp.fmu.cache import fmu_path
from delaycomp.fmu.native import native_fmu_path
from delaycomp.maths.grid import same_step
from orchestrator.fmu import FmuComponent

from .roundoff import EPS

pytestmark = pytest.mark.fmu

N_STATES, N_INPUTS = 3, 2
RNG = np.random.default_rng(34)
#: a stable plant (eigenvalues in [-1.5, -0.5]) with couplings: A = V diag V^-1
_V = np.eye(N_STATES) + 0.3 * RNG.standard_normal((N_STATES, N_STATES))
A = _V @ np.diag([-0.5, -1.0, -1.5]) @ np.linalg.inv(_V)
B = RNG.standard_normal((N_STATES, N_INPUTS))
X0 = np.array([1.0, -0.5, 0.25])
U = np.array([0.3, -0.2])  # held throughout: the trajectory is the exact flow
H = 0.01
K = 2000
CONFIG = {**DEFAULT_CONFIG["plant"], "n": N_STATES, "m": N_INPUTS}
STATES = [f"x{i + 1}" for i in range(N_STATES)]
INPUTS = [f"u{j + 1}" for j in range(N_INPUTS)]


def _parameters() -> dict:
    p = {f"A[{i + 1},{j + 1}]": float(A[i, j]) for i in range(N_STATES)
         for j in range(N_STATES)}
    p.update({f"B[{i + 1},{j + 1}]": float(B[i, j]) for i in range(N_STATES)
              for j in range(N_INPUTS)})
    p.update({f"x0[{i + 1}]": float(X0[i]) for i in range(N_STATES)})
    return p


@pytest.fixture(scope="module", params=["python", "native"])
def plant_fmu(request, tmp_path_factory):
    out = tmp_path_factory.mktemp(f"plant-{request.param}")
    if request.param == "python":
        return fmu_path("plant", CONFIG, out)
    return native_fmu_path("plant", CONFIG, out)


def _run(path, t0: float, steps) -> np.ndarray:
    """The states x_0 .. x_len(steps) of the plant FMU stepped from ``t0`` by ``steps``."""
    comp = FmuComponent("plant", path)
    try:
        comp.setup(t0, t0 + 1e6, _parameters())
        comp.initialize()
        comp.set_inputs(INPUTS, list(U))
        xs = [comp.get_outputs(STATES)]
        t = t0
        for h in steps:
            comp.do_step(t, h)
            t += h
            xs.append(comp.get_outputs(STATES))
        return np.array(xs, dtype=float)
    finally:
        comp.terminate()


def _exact_grid_steps(t0: float, h: float, k: int) -> list[float]:
    """``t_{i+1} - t_i`` for ``t_i = t0 + i h`` (each time computed from i, as the FMI
    guides ask of an importer)."""
    return [(t0 + (i + 1) * h) - (t0 + i * h) for i in range(k)]


def _flow(x, h: float) -> np.ndarray:
    """The exact flow of ``x' = A x + B U`` over ``h`` (scipy's Van Loan exponential)."""
    n, m = N_STATES, N_INPUTS
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * h)
    return E[:n, :n] @ x + E[:n, n:] @ U


def test_exact_grid_steps_differ_from_h_but_are_on_the_grid():
    """The premise: the steps of an exact grid are not all ``h`` bit for bit, and are all
    ``h`` for ``same_step``: ``t_i`` is ``i h`` and ``t0 + i h`` rounded (each off by
    ``eps / 2`` of itself at most), and the difference rounded once more, so
    ``|t_{i+1} - t_i - h| <= (2 i + 3 + t0 / h) eps h``."""
    for t0 in (0.0, 0.3, 1000.0, 1e6):
        steps = _exact_grid_steps(t0, H, K)
        assert len(set(steps)) > 1
        # the round-off of the times near t: from t0 = 1e6 beyond GRID_RTOL H alone
        assert all(same_step(s, H, t0 + i * H) for i, s in enumerate(steps))
        assert all(same_step(s, H) for s in steps) == (t0 < 1e6)
        assert all(abs(s - H) <= (2 * i + 3 + t0 / H) * EPS * H for i, s in enumerate(steps))


@pytest.mark.parametrize("t0", [0.0, 0.3, 1000.0, 1e6])
def test_an_exact_grid_gives_the_trajectory_of_constant_steps(plant_fmu, t0):
    steps = _exact_grid_steps(t0, H, K)
    h1 = steps[0]
    grid = _run(plant_fmu, t0, steps)
    # the cache keyed on the first step serves every later one: the very same arithmetic
    assert np.array_equal(grid, _run(plant_fmu, t0, [h1] * K))
    if t0 == 0.0:
        assert h1 == H
    # against constant steps h: a time shift of k |h1 - h| (h1 - h is round-off of t_1)
    # plus the round-off of two recursions (module docstring)
    constant = _run(plant_fmu, t0, [H] * K)
    peak = np.max(np.abs(constant))
    slope = np.max(np.abs(constant @ A.T + B @ U))
    shift = K * abs(h1 - H) * slope
    assert abs(h1 - H) <= EPS * (t0 + H)
    assert np.max(np.abs(grid - constant)) <= shift + 2 * K * (N_STATES + N_INPUTS) * EPS * peak


@pytest.mark.parametrize("rel", [1e-12, -1e-12, 5e-10, -5e-10])
def test_a_step_within_the_tolerance_is_the_cached_step(plant_fmu, rel):
    """Bit for bit the result of the step h: a recomputed Ad(h (1 + rel)) would differ
    from Ad(h) by about rel h |A| relative, in the last bits of the state at least."""
    step = H * (1 + rel)
    assert step != H and same_step(step, H)
    want = _run(plant_fmu, 0.0, [H] * 5)
    got = _run(plant_fmu, 0.0, [H, step, H, step, step])
    assert np.array_equal(got, want)


@pytest.mark.parametrize("factor", [0.5, 1 + 1e-6, 1 + 2e-9, 1 - 2e-9])
def test_a_step_outside_the_tolerance_is_recomputed(plant_fmu, factor):
    """The state after a step ``h'`` not within GRID_RTOL of ``h`` is the exact flow over
    ``h'`` (and the next step ``h``, again another step for the key ``h'``, the flow over
    ``h``); the cached ``Ad(h)`` would miss by ``|h' - h| |x'|``, above the tolerance."""
    step = H * factor
    assert not same_step(step, H) and not same_step(H, step)
    got = _run(plant_fmu, 0.0, [H, H, step, H])
    flow_tol = 1e3 * max(1.0, np.linalg.norm(A, 1)) * EPS * np.max(np.abs(got))
    want_step = _flow(got[2], step)
    want_next = _flow(got[3], H)
    miss = abs(step - H) * np.max(np.abs(A @ got[2] + B @ U))  # what the cache would give
    assert miss > 10 * flow_tol
    assert np.max(np.abs(got[3] - want_step)) <= flow_tol
    assert np.max(np.abs(got[4] - want_next)) <= flow_tol
