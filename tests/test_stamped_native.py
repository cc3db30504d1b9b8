"""The native twin of the time-stamp controller (issue 29, item 2):
``fmus/controller/controller_stamped.c`` against ``delaycomp_controller_stamped.py``.

Both FMUs are driven by our master's FMU driver (``FmuComponent``, fmpy underneath) with
the same samples: of varying age, repeated stamps (a lost packet: the last one shown
again), too old ones (older than ``age_max``), stamps before ``t0`` (the history),
``tau`` off the grid of ``T``, both modes, ``held_sample``.

Tolerance: the twins walk the same pieces (the same ``SNAP`` rule, the same double
arithmetic for the breakpoints) and differ only in each piece's flow: scipy's ``expm``
against ``linalg.c``'s Pade (each accurate to a few ulps of the augmented exponential's
norm; ``tests/test_native.py`` holds the two to ~1e-15 relative) and the order of the
sums of ``E x + G u``. An output composes at most ``L + tau / T + 2`` such pieces (here
``L = floor((0.6 + 0.25) / 0.1) + 2 = 10``: 13 pieces), each amplifying what came
before by at most ``||e^{A s}|| <= e^{||A|| T}`` (~1.5 here), and the controller's own
outputs come back through its history. So the difference is a few ulps times the pieces
times that growth: ~13 * 1.5^13 * 10 eps ~ 5e-12 of the outputs' peak as a generous
bound, 1e-11 allowed, as the LTI twin's tests do it, a bound far below any behavioural
difference (a sample taken or not, a piece shifted by one output: O(1e-2) here).
Measured: see the assertions' messages (``-s``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are

from delaycomp.fmu.cache import fmu_path
from delaycomp.fmu.native import native_fmu_path
from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused

pytestmark = pytest.mark.fmu

T, N = 0.1, 4
H = T / N
RTOL = 1e-11


@pytest.fixture(scope="module")
def fmus() -> dict[str, object]:
    """The Python FMU, its native twin (FMI 2.0 and 3.0), n = 3, m = 2, from the session's
    build caches."""
    config = {"n": 3, "m": 2}
    return {"python": fmu_path("stamped_controller", config),
            "native": native_fmu_path("stamped_controller", config),
            "fmi3": native_fmu_path("stamped_controller", config, fmi=3)}


def _plant():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(3, 3)) * 0.8 + 0.3 * np.eye(3)
    B = rng.normal(size=(3, 2))
    P = solve_continuous_are(A, B, np.eye(3), np.eye(2))
    return A, B, -(B.T @ P)


def _parameters(**extra) -> dict:
    A, B, K = _plant()
    params = {"T": T, "tau": 0.25, "age_max": 0.6, "u0[1]": 0.2, "u0[2]": -0.1}
    for label, M in (("A", A), ("B", B), ("K", K)):
        params.update({f"{label}[{i + 1},{j + 1}]": float(M[i, j])
                       for i in range(M.shape[0]) for j in range(M.shape[1])})
    return {**params, **extra}


def _samples(count: int, seed: int = 2, t0: float = 0.0) -> list[tuple[list[float], float]]:
    """At t_i: a sample and its stamp, 0 to 0.9 s old (older than age_max = 0.6 at times),
    every fifth the last one again (lost), the first ones stamped before t0."""
    rng = np.random.default_rng(seed)
    out: list[tuple[list[float], float]] = []
    for i in range(count):
        if i % 5 == 4:
            out.append(out[-1])
            continue
        age = 0.01 * int(rng.integers(0, 91))
        out.append((list(rng.normal(size=3)), t0 + i * T - age))
    return out


def _drive(fmu, params: dict, samples, t0: float = 0.0, state_at: int | None = None):
    """The outputs at each instant (the sample set there, or held with held_sample: set
    over the step before), and the state after ``state_at`` periods."""
    comp = FmuComponent("c", fmu)
    comp.setup(t0, t0 + 100.0, params)
    write = comp.writer(["y1", "y2", "y3", "stamp"])
    read = comp.reader(["u1", "u2"])
    write([*samples[0][0], samples[0][1]])
    comp.initialize()
    rows, state = [], None
    for k, (y, s) in enumerate(samples):
        write([*y, s])
        rows.append(read())
        if k == state_at:
            state = comp.get_state()
        for q in range(N):
            comp.do_step(t0 + k * T + q * H, H)
    comp.terminate()
    return np.array(rows), state


CASES = {
    "compensated": {},
    "uncompensated": {"mode": "uncompensated"},
    "held_sample": {"held_sample": True},
    "tau on the grid": {"tau": 0.2, "age_max": 0.35},
    "no delay, no age": {"tau": 0.0, "age_max": 0.0},
}


@pytest.mark.parametrize("case", list(CASES))
def test_native_equals_python(fmus, case):
    params = _parameters(**CASES[case])
    samples = _samples(60)
    want, _ = _drive(fmus["python"], params, samples)
    got, _ = _drive(fmus["native"], params, samples)
    peak = np.abs(want).max()
    worst = np.abs(got - want).max() / peak
    print(f"{case}: native - python = {worst:.2g} of the peak {peak:.3g}")
    assert worst <= RTOL


def test_native_equals_python_from_a_late_start(fmus):
    """From t0 = 1e3: the instants' and the breakpoints' arithmetic the same doubles."""
    params = _parameters()
    samples = _samples(40, seed=5, t0=1e3)
    want, _ = _drive(fmus["python"], params, samples, t0=1e3)
    got, _ = _drive(fmus["native"], params, samples, t0=1e3)
    assert np.abs(got - want).max() <= RTOL * np.abs(want).max()


def test_fmi3_is_fmi2_bit_for_bit(fmus):
    from fmpy.validation import validate_fmu

    for case in ("compensated", "held_sample"):
        params = _parameters(**CASES[case])
        samples = _samples(50, seed=9)
        two, _ = _drive(fmus["native"], params, samples)
        three, _ = _drive(fmus["fmi3"], params, samples)
        assert np.array_equal(three, two), case
    assert validate_fmu(str(fmus["fmi3"])) == []


@pytest.mark.parametrize("impl", ["native", "fmi3"])
def test_the_state_restores_the_run(fmus, impl):
    params = _parameters(held_sample=True)
    samples = _samples(30)
    whole, state = _drive(fmus[impl], params, samples, state_at=12)
    again = FmuComponent("again", fmus[impl])
    again.setup(0.0, 100.0, params)
    again.initialize()
    again.set_state(state)
    write, read = again.writer(["y1", "y2", "y3", "stamp"]), again.reader(["u1", "u2"])
    for q in range(N):
        again.do_step(12 * T + q * H, H)
    rows = []
    for k in range(13, 30):
        y, s = samples[k]
        write([*y, s])
        rows.append(read())
        for q in range(N):
            again.do_step(k * T + q * H, H)
    again.terminate()
    assert np.array_equal(np.array(rows), whole[13:])


def _refusal(fmu, params: dict, inputs: list[float], at: str) -> str:
    comp = FmuComponent("bad", fmu)
    comp.setup(0.0, 10.0, params)
    try:
        if at == "init":
            with pytest.raises(Exception):  # noqa: B017 - FmuRefused or FMICallException
                comp.initialize()
        else:
            comp.initialize()
            comp.writer(["y1", "y2", "y3", "stamp"])(inputs)
            with pytest.raises(Exception):  # noqa: B017
                if at == "output":
                    comp.reader(["u1", "u2"])()
                comp.do_step(0.0, H)
        return (comp.last_message or "").split("] ", 1)[-1]
    finally:
        comp.call_failed = True
        comp.terminate()


@pytest.mark.parametrize("bad, inputs, at", [
    ({"T": 0.0}, [], "init"),
    ({"T": math.nan}, [], "init"),
    ({"tau": -0.1}, [], "init"),
    ({"age_max": -1.0}, [], "init"),
    ({"mode": "x"}, [], "init"),
    ({"mode_index": 3}, [], "init"),
    ({"age_max": 1e9}, [], "init"),
    ({"A[2,3]": math.inf}, [], "init"),
    ({}, [1.0, 0.0, 0.0, 0.5], "output"),
    ({"mode": "uncompensated"}, [1.0, 0.0, 0.0, 0.5], "step"),
    ({}, [1.0, 0.0, 0.0, math.nan], "step"),
    ({}, [1.0, math.inf, 0.0, 0.0], "step"),
])
def test_the_same_refusals_with_the_same_messages(fmus, bad, inputs, at):
    params = _parameters(**bad)
    want = _refusal(fmus["python"], params, inputs, at)
    got = _refusal(fmus["native"], params, inputs, at)
    assert want and got == want


def test_a_crafted_native_state_is_refused_naming_the_field(fmus):
    from .native_state import decode, encode, layout_of

    params = _parameters()
    _, state = _drive(fmus["native"], params, _samples(10), state_at=5)
    layout = layout_of(fmus["native"])
    for field, value, message in (("stamp", 99.0, "stamp = 99.0: must be a finite time <="),
                                  ("z", math.nan, "z[1] = nan: must be a finite number"),
                                  ("next", 0, "z[0] = ")):
        snap, buf = decode(layout, state)
        if field == "z":
            snap.d.m.z[1] = value
        else:
            setattr(snap.d.m, field, value)
        fresh = FmuComponent("crafted", fmus["native"])
        fresh.setup(0.0, 100.0, params)
        fresh.initialize()
        try:
            with pytest.raises((FmuRefused, Exception)):
                fresh.set_state(encode(snap, buf))
            assert message in (fresh.last_message or ""), fresh.messages
        finally:
            fresh.terminate()


def test_the_estimate_never_aliases_the_sample():
    """A sample taken at the instant (no piece to walk) was returned as the estimate
    itself: the Python FMU's input array, which the next ``fmi2SetReal`` changed in place
    (found by the twin test above: the FMU off from its maths by O(1) from the next
    instant on). The estimate is a copy."""
    from delaycomp.maths.stamped import StampedController

    A, B, K = _plant()
    c = StampedController(A, B, K, T, 0.0, 0.0, "compensated", [0.0, 0.0])
    y = np.array([1.0, 2.0, 3.0])
    c.commit(c.propose(y, 0.0), y, 0.0)
    z = c.z.copy()
    y[:] = 99.0
    assert np.array_equal(c.z, z)
