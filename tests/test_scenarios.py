"""The paper's remaining examples co-simulated with the FMUs: references and claims."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from delaycomp.errors import ParameterError
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper import scenarios
from delaycomp.paper.models import corollary_4_1, unicycle
from delaycomp.system import loopfile
from delaycomp.verify.check import CASES

from .conftest import REPO

pytestmark = pytest.mark.fmu

# case id -> (scenario, --set assignments, reference case), from the one registry of
# reference cases (Example 3.6 has its own tests)
ZOH_CASES = {f"{c.scenario}-{c.case}": (c.scenario, list(c.sets), c.case)
             for c in CASES if c.kind == "exact" and c.scenario != "example-3.6"}
CONTINUOUS_CASES = {f"{c.scenario}-{c.case}": (c.scenario, list(c.sets), c.case)
                    for c in CASES if c.kind == "first-order"}


def reference(scenario, case):
    with open(REPO / "reference" / scenario / f"{case}_ref.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], np.array(rows[1:], dtype=float)


def simulate(fmu_dir, scenario, sets, stop):
    sc = scenarios.get(scenario)
    res = run_loop(sc.make(sc.resolve(sets)), stop, fmu_dir)
    assert res.success, res.message
    return res


@pytest.mark.parametrize("case", sorted(ZOH_CASES))
def test_zoh_scenario_matches_reference(fmu_dir, case):
    """Zero-order hold: plant steps, predictors and reference are all exact flows, so the
    only difference is round-off (measured <= 6e-14); 1e-9 (1 + |ref|) has ample room and
    still catches any timing or formula error (those are O(1e-2) or larger)."""
    scenario, sets, ref_case = ZOH_CASES[case]
    header, ref = reference(scenario, ref_case)
    res = simulate(fmu_dir, scenario, sets, ref[-1, 0])
    assert header == ["time", *res.names]
    np.testing.assert_allclose(res.times, ref[:, 0], rtol=0, atol=1e-12)
    err = np.abs(res.data - ref[:, 1:])
    assert np.all(err <= 1e-9 * (1 + np.abs(ref[:, 1:]))), f"largest error {err.max():.2e}"


@pytest.mark.parametrize("case", sorted(CONTINUOUS_CASES))
def test_continuous_scenario_converges_to_the_ideal_law_at_order_one(fmu_dir, case):
    """The reference is the paper's continuous-input loop; the FMUs realise it with the
    control held over each base step h (FMI 2.0 holds inputs), an O(h) perturbation. So the
    error must be small and halve when h halves (measured ratios 2.00-2.01)."""
    scenario, sets, ref_case = CONTINUOUS_CASES[case]
    header, ref = reference(scenario, ref_case)
    errors = []
    for N in (100, 200):
        res = simulate(fmu_dir, scenario, [*sets, f"N={N}"], ref[-1, 0])
        assert header == ["time", *res.names]
        errors.append(np.abs(res.data[:: N // 100] - ref[:, 1:]).max())
    assert errors[0] < 0.02 * np.abs(ref[:, 1:]).max()
    assert 1.8 < errors[0] / errors[1] < 2.2


# scenario, --set, time from which the state is zero: (j + l + ceil(r/T)) T, j the
# dead-beat order without delay. u0 != 0 makes the initial function inconsistent with the
# input history, so the first prediction is inexact and the bound is reached exactly.
DEADBEAT = {
    "example-3.8": ("example-3.8", ["u0=0.3"], 2 + 0 + 1),
    "example-3.8-delayed": ("example-3.8", ["u0=0.3", "tau=1", "r=1.5"], 2 + 1 + 2),
    "example-3.8-padded": ("example-3.8", ["u0=0.3", "tau=0.5", "pad=1"], 2 + 1 + 1),
    "corollary-3.7": ("corollary-3.7", ["u0=0.3"], 3 + 1 + 1),
    "corollary-3.7-n5": ("corollary-3.7", ["n=5", "u0=0.3", "r=2.2", "tau=0", "N=20"],
                         5 + 0 + 3),
    "proposition-4.2": ("proposition-4.2", ["u0=0.3,-0.2"], 3 + 1 + 1),
    "proposition-4.2-r2.5": ("proposition-4.2", ["u0=0.3,-0.2", "r=2.5", "tau=0"],
                             3 + 0 + 3),
}


@pytest.mark.parametrize("case", sorted(DEADBEAT))
def test_deadbeat_from_the_predicted_time(fmu_dir, case):
    scenario, sets, periods = DEADBEAT[case]
    sc = scenarios.get(scenario)
    p = sc.resolve(sets)
    res = simulate(fmu_dir, scenario, sets, (periods + 3) * p["T"])
    n = len(res.names) - (2 if scenario == "proposition-4.2" else 1)
    x = np.abs(res.data[:, :n]).max(axis=1)
    k = periods * p["N"]
    assert x[k:].max() < 1e-9
    assert x[k - 1] > 1e-6  # and not earlier


def test_example_2_4_converges_for_both_samplings(fmu_dir):
    for sets, bound in (([], 1e-9), (["T=2"], 1e-8)):
        res = simulate(fmu_dir, "example-2.4", sets, 30.0)
        assert np.abs(res.data[-1, :3]).max() < bound


def test_example_2_4_printed_law_is_selectable_and_differs(fmu_dir):
    corrected = simulate(fmu_dir, "example-2.4", [], 5.0)
    printed = simulate(fmu_dir, "example-2.4", ["law=printed"], 5.0)
    assert np.abs(corrected.data - printed.data).max() > 1e-3


def test_proposition_4_2_printed_law_is_not_deadbeat(fmu_dir):
    res = simulate(fmu_dir, "proposition-4.2", ["law=printed"], 10.0)
    assert np.abs(res.data[-1, :3]).max() > 1e-3  # corrected: < 1e-9 from 5T


def test_corollary_4_1_lyapunov_function_decreases(fmu_dir):
    """After the first exact prediction the plant obeys the nominal loop (up to O(h)):
    Pomet's V(t, x) decreases; the norm decays like t^(-1/2)."""
    res = simulate(fmu_dir, "corollary-4.1", [], 100.0)
    times, states = res.times, res.data[:, :3]
    V = np.array([corollary_4_1.lyapunov(t, *unicycle.chained(s))
                  for t, s in zip(times, states)])
    after = times >= 0.5 + 0.3 + 0.5  # T + tau, plus a period
    stride = 20  # 0.1 s: monotone up to the O(h) hold effect
    assert np.all(np.diff(V[after][::stride]) < 1e-6)
    norms = np.linalg.norm(states, axis=1)
    assert norms[-1] < 0.2 and norms[-1] < norms[times.searchsorted(25.0)] * 0.6


@pytest.mark.parametrize("scenario,sets,stop", [
    ("example-3.8", [], 6.0),
    ("example-2.4", [], 3.0),
])
def test_numerical_predictor_agrees_with_the_closed_form(fmu_dir, scenario, sets, stop):
    closed = simulate(fmu_dir, scenario, sets, stop)
    numerical = simulate(fmu_dir, scenario, [*sets, "predictor=numerical"], stop)
    # ODE tolerance 1e-10 per window, a few dozen windows: 1e-7 is the stated budget
    np.testing.assert_allclose(numerical.data, closed.data, rtol=1e-7, atol=1e-7)


def test_zoh_scenario_refuses_tau_off_the_period():
    with pytest.raises(scenarios.ParameterError,
                       match=r"pad = true .* accepts it, delaying the output to the next "
                             r"multiple, 1 "):
        scenarios.get("example-3.8").resolve(["tau=0.5"])


@pytest.mark.parametrize("scenario,sets,message", [
    ("example-3.8", ["x0=1,2,3"], "x0 has 3 values: must have 2"),
    ("proposition-4.2", ["u0=1"], "u0 has 1 values: must have 2"),
    ("corollary-3.7", ["n=0"], "n = '0' is not allowed"),
    ("example-2.4", ["law=other"], "law = 'other' is not allowed"),
    ("example-3.8", ["p=cube"], "p = 'cube' is not allowed"),
    ("example-2.4", ["r=0.3001"], "must be a multiple of the base step"),
])
def test_scenario_parameters_are_checked(scenario, sets, message):
    with pytest.raises(scenarios.ParameterError, match=message):
        scenarios.get(scenario).resolve(sets)





GRIDS = {  # sets, then one point's assignments per row (a grid in product order)
    "example-3.6": (["mode=uncompensated"], [("k=1", "r=0"), ("k=1", "r=0.5"),
                                              ("k=2.5", "r=0.98")]),
    "example-2.4": (["tau=0.2"], [("r=0",), ("r=0.37",)]),
    "example-3.8": (["p=sin"], [("r=0.5", "T=0.5"), ("r=1", "T=1")]),
    "corollary-3.7": ([], [("n=2",), ("n=4",), ("n=3", "x0=1,2,3")]),
    "corollary-4.1": ([], [("tau=0",), ("tau=0.4",)]),
    "proposition-4.2": (["law=printed"], [("x0=1,0,0.5",), ("x0=-2,1,0",)]),
}


@pytest.mark.parametrize("name", sorted(GRIDS))
def test_resolve_grid_is_resolve_point_by_point(name):
    """A grid resolved at once (each distinct assignment parsed once) equals each point
    resolved on its own; a cross-parameter default (corollary-3.7's x0 follows n) is
    filled in per point."""
    sc = scenarios.get(name)
    sets, grid = GRIDS[name]
    assert sc.resolve_grid(sets, grid) == [sc.resolve([*sets, *pt]) for pt in grid]


@pytest.mark.parametrize("sets,point", [
    ([], ("r=0.305",)), (["k=x"], ("r=0",)), ([], ("speed=3",)), ([], ("tau=0.5",)),
    (["T=0"], ()),
])
def test_resolve_grid_refuses_what_resolve_refuses(sets, point):
    sc = scenarios.get("example-3.6")
    with pytest.raises(ParameterError):
        sc.resolve([*sets, *point])
    assert sc.resolve_grid(sets, [("k=1",), point, ("k=2",)]) is None


@pytest.mark.parametrize("name", sorted(scenarios.SCENARIOS))
def test_a_scenario_is_its_shipped_loop_file_with_short_names(name):
    """Issue 26, item 2: a scenario is its loop file read by the loop-file reader; its
    parameters are aliases of the file's keys, their defaults the file's values."""
    from delaycomp.system.loopfile import LoopFile

    sc = scenarios.get(name)
    file = LoopFile(scenarios.loop_file(name))
    assert repr(sc.loop([])) == repr(file.loop([]))
    assert (sc.title, sc.default_stop_time) == (file.title, file.default_stop_time)
    for p in sc.params:
        if p.key is not None and p.from_file is None and p.name not in ("r_true", "tau_true",
                                                                        "pad"):
            section, _, key = p.key.rpartition(".")
            value = (file.data[section] if section else file.data)[key]
            assert p.default == value, (name, p.name)


# bad values of parameters that stand for one loop-file key each
_BAD = {"T": ["0", "-1", "inf", "x", "true"], "N": ["0", "2.5", "x", "-3"],
        "r": ["-0.1", "0.3001", "nan"], "tau": ["-1", "0.5", "x"], "r_true": ["-1", "0.0001"],
        "mode": ["fast", "1"], "predictor": ["guess"], "law": ["other", "1"], "p": ["cube"],
        "x0": ["1,x", "1,2,3,4,5"], "u0": ["inf", "1,2,3"]}


@pytest.mark.parametrize("name", sorted(scenarios.SCENARIOS))
def test_a_scenario_refuses_what_its_loop_file_refuses(name):
    """One rule, not two (issue 26, item 2): each value a scenario parameter refuses, the
    loop file refuses at the key it stands for, and the other way round."""
    from delaycomp.system.loopfile import LoopFile

    sc = scenarios.get(name)
    file = LoopFile(scenarios.loop_file(name))
    tried = 0
    for p in sc.params:
        if p.name not in _BAD or p.to_file not in (None, scenarios._listed):
            continue
        for text in _BAD[p.name]:
            refusals = []
            for source, assignment in ((sc, f"{p.name}={text}"), (file, f"{p.key}={text}")):
                try:
                    source.loop([assignment])
                    refusals.append(False)
                except ParameterError:
                    refusals.append(True)
            assert refusals[0] == refusals[1], (name, p.name, text, refusals)
            tried += refusals[0]
    assert tried >= 10  # refused by both


@pytest.mark.parametrize("name", sorted(scenarios.SCENARIOS))
def test_a_models_own_parameters_state_the_models_choices(name):
    """``delaycomp list`` prints a model parameter's choices without importing the model
    (no scipy at start, tests/test_start.py): the words it prints are the model's."""
    sc = scenarios.get(name)
    for p in sc.params:
        if p.key is not None and p.key not in loopfile.KEYS:
            choices = sc.model.choices[p.key.partition(".")[2]]
            assert p.allowed == " or ".join(choices), (name, p.name)
            assert p.default in choices
