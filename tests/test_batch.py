"""The batch engine against the per-point engine: trajectories, metrics, sweeps, chunking.

The per-point in-process engine is the reference (it equals the FMU run to the bit,
tests/test_engines.py). Tolerances:

- trajectories are compared relative to the run's scale so far (``assert_close``);
- exact LTI loops: the batch does the per-point engine's arithmetic per point; for scalar
  plants in the same order (bit-equal), for n > 1 the matrix products are summed in
  another order than BLAS, a few ulp a step (measured at most 1.6e-14 on these grids):
  1e-12 relative (the issue's bound);
- model loops: the batch predictor composes the exact step over the window where the
  per-point closed forms evaluate the same exact flow in one expression; both are exact,
  so they differ by round-off; 1e-9 relative to ``max(1, |x|)`` is the ODE tolerance
  (``DEFAULT_TOL`` = 1e-10) with room for 3000 steps;
- ``rho`` is a least-squares rate (closed form here, ``np.polyfit`` per point): equal to
  the same relative bound; ``final_norm`` and ``peak_norm`` to it relative to the run's
  peak (a dead-beat residual is round-off of that scale, its last digits the BLAS
  kernel's). Where both runs reach dead-beat (``|x| < 1e-9`` to the end) the tail holds
  round-off (1e-15 to 1e-45) and ``rho`` is the rate of that noise (measured
  7e-6 against 6e-6): there the two must agree on ``stable`` and the dead-beat time, and
  ``rho`` only where the noise is the same (else both below 1).
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from delaycomp.maths.model import load_model
from delaycomp.orchestrator import native_core
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper import scenarios
from delaycomp.paper.models import path
from delaycomp.studies import batch, sweep, sweep_batch
from delaycomp.studies.axes import parse_grid
from delaycomp.studies.sweep import SweepOptions

from .roundoff import SAME_ARITHMETIC_ULPS, assert_columns_close, assert_same_values

LTI_REL = 1e-12
MODEL_REL = 1e-9


def assert_same(b: dict, s: dict, rel: float) -> None:
    """Batch metrics ``b`` equal the per-point ``s`` (see the module docstring)."""
    assert b["stable"] == s["stable"]
    assert b["deadbeat_time"] == s["deadbeat_time"]
    for key in ("final_norm", "peak_norm"):
        # the trajectories agree to rel * (the run's scale so far) (assert_close), and a
        # norm moves by no more than its vector: | |x| - |y| | <= |x - y|. So the bound is
        # rel * max(1, peak): a dead-beat residual (1e-12 where the peak is 3) is round-off
        # of the run's own scale, and its last digits depend on the BLAS kernel
        assert b[key] == pytest.approx(s[key], rel=rel, abs=rel * max(1.0, s["peak_norm"])), key
    if s["deadbeat_time"] is not None:
        # the rate of round-off noise: the same verdict (stable, above) is what it carries
        assert b["rho"] == pytest.approx(s["rho"], rel=rel) or max(b["rho"], s["rho"]) < 1
    elif math.isinf(s["rho"]):
        assert math.isinf(b["rho"])
    else:
        assert b["rho"] == pytest.approx(s["rho"], rel=rel)


def assert_close(x: np.ndarray, ref: np.ndarray, rel: float) -> None:
    """``|x(t) - ref(t)| <= rel * max(1, the largest |ref| up to t)`` at every tick: the scale
    of the run so far (a dead-beat state near zero carries the round-off of the larger
    values it came from; the per-point engine's own round-off is of that size too)."""
    err = np.linalg.norm(x - ref, axis=1)
    scale = np.maximum(1.0, np.maximum.accumulate(np.linalg.norm(ref, axis=1)))
    assert np.all(err <= rel * scale), float(np.max(err / scale))


def per_point(sc, p: dict, stop: float):
    loop = sc.make(p)
    res = run_loop(loop, stop, engine="inprocess")
    n = sum(1 for port in loop.recorded if port.instance == "plant")
    return res, sweep.result_metrics(loop, res), n


# -- LTI: trajectories and metrics ---------------------------------------------------------

LTI_GRIDS = {
    "example-3.6": [dict(k=k, r=r, mode=mode) for k in (0.5, 2.0, 3.0)
                    for r in (0.0, 0.37, 0.98) for mode in ("compensated", "uncompensated")]
    + [dict(r=0.3, r_true=0.45, tau_true=0.2, u0=0.4), dict(r=0.3, tau=1.6, T=0.8, N=40),
       dict(r=1.7, tau=1.0, mode="uncompensated")],
    "corollary-3.7": [dict(r=r, tau=tau, mode=mode) for r in (0.0, 0.5, 1.5)
                      for tau in (0.0, 1.0) for mode in ("compensated", "uncompensated")]
    + [dict(n=2, r=0.25), dict(n=4, x0="1,2,3,4", tau=2.0)],
}


def lti_ingredients(sc, ps):
    """The batch ingredients of resolved points (loose arrays, for ``simulate_lti``), as
    the sweep takes them from the loops."""
    pts = [sweep_batch.lti_point(sc.make(p)) for p in ps]
    arr = {key: np.array([p[key] for p in pts]) for key in pts[0] if key != "mode"}
    arr["mode"] = [p["mode"] for p in pts]
    return arr


@pytest.mark.parametrize("name", list(LTI_GRIDS))
def test_lti_batch_equals_per_point(name):
    """Per-point matrices, delays, periods and N (two groups) in one batch."""
    sc = scenarios.get(name)
    ps = [sc.resolve({k: str(v) for k, v in point.items()}) for point in LTI_GRIDS[name]]
    by_n: dict[int, list[int]] = {}
    for i, p in enumerate(ps):
        by_n.setdefault(len(np.ravel(p["x0"])), []).append(i)
    stop = 12.0
    for idx in by_n.values():
        res = batch.simulate_lti(**lti_ingredients(sc, [ps[i] for i in idx]), stop=stop,
                                 record=True)
        for j, i in enumerate(idx):
            ref, metrics, n = per_point(sc, ps[i], stop)
            assert_close(res.states[j, :len(ref.data)], ref.data[:, :n], LTI_REL)
            assert_close(res.inputs[j, :len(ref.data)], ref.data[:, n:], LTI_REL)
            assert_same(res.rows()[j], metrics, LTI_REL)


def test_scalar_lti_trajectory_is_the_per_point_one():
    """n = m = 1: the same operations in the same order as the plant slave, so the same
    trajectory to the last bits (measured bit-equal: scalar products use no BLAS kernel),
    where n > 1 is held to LTI_REL."""
    sc = scenarios.get("example-3.6")
    ps = [sc.resolve({"k": "2.5", "r": "0.41", "mode": "uncompensated"})]
    res = batch.simulate_lti(**lti_ingredients(sc, ps), stop=20.0, record=True)
    ref, _, _ = per_point(sc, ps[0], 20.0)
    assert_columns_close(res.states[0, :, 0], ref.data[:, 0], SAME_ARITHMETIC_ULPS, "x")


# -- model loops -----------------------------------------------------------------------------

MODEL_GRIDS = {
    "example-2.4": (8.0, [{}, dict(r=0.1, tau=0.2), dict(x0="2,-1,1", r=0.55, tau=0.35),
                          dict(T=0.4, r=0.2, tau=0.6)]),
    "example-3.8": (8.0, [{}, dict(r=1.5, tau=1.0), dict(x0="2,1", r=0.25),
                          dict(T=0.5, r=0.75)]),
    "proposition-4.2": (8.0, [{}, dict(r=0.3), dict(x0="-2,1,3", r=1.25, tau=2.0),
                              dict(T=0.5, r=0.1, tau=0.5)]),
    "corollary-4.1": (6.0, [{}, dict(r=0.1, tau=0.2), dict(x0="0.5,-1,2", r=0.35)]),
}


@pytest.mark.parametrize("name", list(MODEL_GRIDS))
def test_model_batch_equals_per_point(name):
    stop, grid = MODEL_GRIDS[name]
    sc = scenarios.get(name)
    ps = [sc.resolve({k: str(v) for k, v in point.items()}) for point in grid]
    model = load_model(sc.make(ps[0]).by_role("plant").source.model)
    assert batch.batchable(model) is None
    params = model.params(**{k: ps[0][k] for k in ("law", "p") if k in ps[0]})
    res = batch.simulate_model(
        model, params, np.array([p["T"] for p in ps]), ps[0]["N"],
        np.array([p["r"] for p in ps]), np.array([p["tau"] for p in ps]),
        np.array([p["x0"] for p in ps]), np.array([p["u0"] for p in ps]), stop,
        record=True)
    for j, p in enumerate(ps):
        ref, metrics, n = per_point(sc, p, stop)
        assert_close(res.states[j, :len(ref.data)], ref.data[:, :n], MODEL_REL)
        assert_close(res.inputs[j, :len(ref.data)], ref.data[:, n:], MODEL_REL)
        assert_same(res.rows()[j], metrics, MODEL_REL)


def test_padding_and_both_laws_of_proposition_4_2():
    """Remark 3.3(b) padding (tau not a multiple of T) and the printed law, as sweeps."""
    for sets in (["pad=1"], ["law=printed"]):
        axes = [parse_grid("tau=0.3:0.9:3" if sets == ["pad=1"] else "r=0.2:0.6:3")]
        b = sweep.run_sweep("proposition-4.2", axes, sets, SweepOptions(stop=6.0, engine="batch"))
        s = sweep.run_sweep("proposition-4.2", axes, sets,
                            SweepOptions(stop=6.0, engine="inprocess"))
        for x, y in zip(b, s):
            assert_same(x, y, MODEL_REL)


# -- failures --------------------------------------------------------------------------------

def test_failures_end_the_record_as_the_per_point_engine_does():
    """A control that overflows (refused: tick not recorded) and a plant state that does
    (the run ends after the last finite tick): rho = inf and the same recorded norms."""
    axes = [parse_grid("k=1e150:1e300:2")]
    b = sweep.run_sweep("example-3.6", axes, ["mode=uncompensated"],
                        SweepOptions(stop=5.0, engine="batch"))
    with np.errstate(over="ignore"):  # the per-point metric squares states of 1e200
        s = sweep.run_sweep("example-3.6", axes, ["mode=uncompensated"],
                            SweepOptions(stop=5.0, engine="inprocess"))
    assert all(math.isinf(row["rho"]) for row in s)
    # the loop diverged: unstable, with the reason (in each engine's words)
    assert all(row["stable"] == 0 and "diverged" in row["failed"] for row in b + s)
    for x, y in zip(b, s):
        assert {**x, "failed": ""} == {**y, "failed": ""}


def test_finite_time_escape_of_the_printed_law():
    """Example 2.4 with the printed (2.18) escapes in finite time (errata item 1)."""
    axes = [parse_grid("r=0:0.2:2")]
    sets = ["law=printed", "x0=-1.295,2.307,-4.261", "tau=0"]
    b = sweep.run_sweep("example-2.4", axes, sets, SweepOptions(stop=2.0, engine="batch"))
    s = sweep.run_sweep("example-2.4", axes, sets, SweepOptions(stop=2.0, engine="inprocess"))
    assert any(math.isinf(row["rho"]) for row in s)
    for x, y in zip(b, s):
        assert_same(x, y, MODEL_REL)


# -- the sweep: every scenario, chunking, processes, Dask, fallback ---------------------

SWEEPS = {
    "example-3.6": (["mode=uncompensated"], ["k=0.5:3:4", "r=0:0.9:4"], 10.0),
    "corollary-3.7": (["mode=compensated"], ["r=0:1:3", "tau=0:1:2"], 8.0),
    "example-2.4": ([], ["r=0:0.4:3"], 6.0),
    "example-3.8": (["p=sin"], ["r=0:1:3"], 6.0),
    "proposition-4.2": ([], ["r=0:1:3"], 6.0),
    "corollary-4.1": ([], ["tau=0:0.4:3"], 5.0),
}


@pytest.mark.parametrize("name", list(SWEEPS))
def test_sweep_batch_equals_inprocess(name):
    sets, grids, stop = SWEEPS[name]
    axes = [parse_grid(g) for g in grids]
    notes: list[str] = []
    b = sweep.run_sweep(name, axes, sets, SweepOptions(stop=stop, engine="batch"), notes=notes)
    s = sweep.run_sweep(name, axes, sets, SweepOptions(stop=stop, engine="inprocess"))
    assert any(f"{len(b)} of {len(b)} points" in note for note in notes), notes
    rel = LTI_REL if name in LTI_GRIDS else MODEL_REL  # the LTI scenarios
    for x, y in zip(b, s):
        assert {k: x[k] for k in x if k in y and k not in sweep.METRICS} == \
            {k: y[k] for k in y if k not in sweep.METRICS}
        assert_same(x, y, rel)


def test_chunks_processes_and_dask_give_the_same_rows():
    from distributed import LocalCluster

    axes = [parse_grid("k=0.5:3:3"), parse_grid("r=0:0.9:4")]
    def rows(**options):
        return sweep.run_sweep("example-3.6", axes, ["mode=uncompensated"],
                               SweepOptions(stop=6.0, engine="batch", **options))

    whole = rows()
    chunked = rows(chunk=5)
    procs = rows(chunk=4, workers=2)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        dask_rows = rows(chunk=3, scheduler=cluster.scheduler_address)
    # chunks of other sizes, other processes: the same arithmetic, to the last bits
    for name, rows in (("chunked", chunked), ("processes", procs), ("dask", dask_rows)):
        assert_same_values(rows, whole, SAME_ARITHMETIC_ULPS, name)


def test_numerical_predictor_falls_back_and_says_so():
    axes = [parse_grid("r=0.1:0.3:2")]
    notes: list[str] = []
    rows = sweep.run_sweep("example-3.8", axes, ["predictor=numerical"],
                           SweepOptions(stop=4.0, engine="batch"), notes=notes)
    # on the fmu engine where the loop's native FMUs and the native core are here, else
    # in-process: that engine's rows (a dead-beat loop's rho is a ratio of round-off, so
    # the native FMUs' rows are not held to the slaves' here: test_oneface.py does that)
    engine = "fmu" if native_core.core_status() is None else "inprocess"
    assert any(f"per-point engine ({engine}): 2 points" in n and "predictor=numerical" in n
               for n in notes), notes
    assert_same_values(rows, sweep.run_sweep("example-3.8", axes, ["predictor=numerical"],
                                             SweepOptions(stop=4.0, engine=engine)),
                       SAME_ARITHMETIC_ULPS, "rows")


def test_a_model_without_batch_is_not_batchable(tmp_path):
    src = path("example_3_8").read_text(encoding="utf-8").replace("BATCH = True", "")
    f = tmp_path / "plain.py"
    f.write_text(src, encoding="utf-8")
    assert "does not declare BATCH = True" in batch.batchable(load_model(f))
    with pytest.raises(batch.BatchError, match="BATCH"):
        batch.simulate_model(load_model(f), {}, 1.0, 10, 0.5, 0.0, [1.0, 0.0], [0.0], 2.0)


@pytest.mark.parametrize("kwargs,match", [
    (dict(r=0.305), "r = 0.305"),
    (dict(tau=0.5), r"tau = 0.5 is not allowed: zero-order hold needs a multiple l\*T"),
    (dict(mode="sideways"), "mode = 'sideways'"),
    (dict(T=-1.0), "T is not allowed"),
])
def test_bad_ingredients_are_refused_in_one_line(kwargs, match):
    args = dict(A=[[1.0]], B=[[1.0]], K=[[-2.0]], T=1.0, N=100, r=0.3, tau=0.0, x0=[1.0],
                u0=[0.0], mode="compensated", stop=2.0)
    args.update(kwargs)
    with pytest.raises(batch.BatchError, match=match) as info:
        batch.simulate_lti(**args)
    assert "\n" not in str(info.value)


def test_zero_and_the_rate_rule_are_written_once():
    """The per-point metric and the batch engine read one ``ZERO`` and one tail rule
    (``delaycomp.studies.metrics``); no other study module defines its own."""
    import re

    from delaycomp.studies import metrics

    assert batch.ZERO is metrics.ZERO and sweep.ZERO is metrics.ZERO
    folder = Path(metrics.__file__).parent
    for module in folder.rglob("*.py"):  # the batch engine's package included
        if module == Path(metrics.__file__):
            continue
        text = module.read_text()
        assert not re.search(r"^ZERO\s*=", text, re.M), module.name
        assert not re.search(r"//\s*5\b", text), module.name


def cli(*args):
    from delaycomp.child import module_argv

    return subprocess.run([*module_argv("delaycomp.cli"), *args], capture_output=True,
                          text=True, timeout=600)


def test_cli_sweep_defaults_to_batch_and_says_so(tmp_path):
    out = tmp_path / "map.csv"
    proc = cli("sweep", "example-3.6", "--grid", "k=1:3:3", "--grid", "r=0:0.5:3",
               "--stop-time", "5", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "batch engine (numpy, cpu): 9 of 9 points in 1 chunk" in proc.stdout
    assert out.read_text().splitlines()[0] == "k,r,rho,stable,final_norm,peak_norm," \
                                              "deadbeat_time,failed"


def test_cli_array_backend_without_its_library_is_a_usage_error(tmp_path):
    try:
        batch.get_backend("cupy")
    except batch.BatchError:
        usable = False
    else:  # a machine with CuPy and a GPU: the sweep runs there
        usable = True
    proc = cli("sweep", "example-3.6", "--grid", "k=1:3:3", "--array-backend", "cupy",
               "--stop-time", "5", "--out", str(tmp_path / "x.csv"))
    if usable:
        assert proc.returncode == 0, proc.stderr
        return
    assert proc.returncode == 2
    assert "--array-backend" in proc.stderr and "cupy" in proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr


# -- the exact critical delays over a map ------------------------------------------------

def test_critical_curve_is_the_lifted_models_critical_delay():
    """k = 2, T = 1: r_c = 0.203267055 (docs/reference/sweeps.md, critical-delay --grid; (3.20));
    k = 2.5 is unstable at r = 0 (2.5 > 1 + 2/(e - 1)) and a band of delays stabilizes it: two
    crossings around the band the simulated map shows."""
    from delaycomp.studies.critical import critical_curve

    sc = scenarios.get("example-3.6")
    r_axis = np.linspace(0, 0.98, 50)
    rows = critical_curve(sc, ["mode=uncompensated"], ["k", "r"], [[2.0, 2.5], r_axis])
    at2 = rows[rows[:, 0] == 2.0][:, 1]
    assert at2.tolist() == pytest.approx([0.203267055], abs=1e-8)
    at25 = rows[rows[:, 0] == 2.5][:, 1]
    assert len(at25) == 2 and 0 < at25[0] < at25[1] < 0.2
    b = sweep.run_sweep("example-3.6", [parse_grid("r=0:0.2:21")], ["k=2.5", "mode=uncompensated"],
                        SweepOptions(engine="batch"))
    inside = [row["stable"] for row in b if at25[0] + 0.01 < row["r"] < at25[1] - 0.01]
    outside = [row["stable"] for row in b if row["r"] < at25[0] - 0.01
               or row["r"] > at25[1] + 0.01]
    assert inside and all(inside) and outside and not any(outside)
    assert critical_curve(sc, ["mode=compensated"], ["k", "r"], [[2.0], r_axis]) is None
    assert critical_curve(sc, ["mode=uncompensated"], ["k", "T"], [[2.0], [1.0]]) is None


def test_map_plot_carries_the_critical_delays(tmp_path):
    png = tmp_path / "map.png"
    proc = cli("sweep", "example-3.6", "--grid", "k=1.5:2.5:5", "--grid", "r=0:0.5:6",
               "--set", "mode=uncompensated", "--stop-time", "10",
               "--out", str(tmp_path / "m.csv"), "--plot", str(png))
    assert proc.returncode == 0, proc.stderr
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_loop_file_sweeps_on_the_batch_engine():
    """A loop file (the shipped example-3.6.toml) runs batched, as its scenario does."""
    from delaycomp.paper.scenarios import loop_file

    axes = [parse_grid("r=0:0.9:4")]
    notes: list[str] = []
    b = sweep.run_sweep(str(loop_file("example-3.6")), axes, [],
                        SweepOptions(stop=8.0, engine="batch"), notes=notes)
    s = sweep.run_sweep(str(loop_file("example-3.6")), axes, [],
                        SweepOptions(stop=8.0, engine="inprocess"))
    assert any("4 of 4 points" in n for n in notes), notes
    for x, y in zip(b, s):
        assert_same(x, y, LTI_REL)


# -- grid points without their loops ------------------------------------------------------

MIMO_LOOP = """
T = 0.5
N = 10
r = 0.3
tau = 0.5
[plant]
A = [[0.0, 1.0], [-1.0, 0.2]]
B = [[0.0], [1.0]]
x0 = [1.0, -0.5]
state = "q"
input = "f"
[controller]
K = [[-0.5, -1.2]]
u0 = [0.25]
"""


def _lti_sources(tmp_path):
    from delaycomp.paper.scenarios import loop_file

    mimo = tmp_path / "mimo.toml"
    mimo.write_text(MIMO_LOOP, encoding="utf-8")
    return {
        "example-3.6": ["k=1.5", "r=0.4", "mode=uncompensated", "r_true=0.45"],
        "corollary-3.7": ["n=4", "r=0.3", "tau=1", "tau_true=1.2", "x0=1,2,3,4"],
        str(loop_file("example-3.6")): ["r=0.25", "controller.mode=uncompensated",
                                        "tau_true=0.1"],
        str(mimo): ["r_true=0.4", "controller.u0=[0.5]"],
    }


def test_a_grid_points_design_is_its_loops_design(tmp_path):
    """What a batch sweep reads of an LTI point without building its loop
    (``Scenario.design``, ``LoopFile.design``) is what it reads of the loop."""
    from delaycomp.system import LtiDesign

    for source, sets in _lti_sources(tmp_path).items():
        sc = scenarios.open_source(source)
        p = sc.resolve(sets)
        point, loop = sc.design(p), sc.make(p)
        assert point.timing == loop.timing, source
        # both read the same parsed numbers (and the same call of the gain's function): no
        # arithmetic lies between them, so they are equal, not only close
        for f in dataclasses.fields(LtiDesign):
            a, b = getattr(point.lti, f.name), getattr(loop.lti, f.name)
            assert np.array_equal(a, b) and type(a) is type(b), (source, f.name)
        a, b = sweep_batch.lti_point(point), sweep_batch.lti_point(loop)
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a), source
    assert scenarios.get("example-2.4").design(scenarios.get("example-2.4").resolve()) is None


@pytest.mark.parametrize("sets", [
    ["r=0.305"], ["tau=0.5"], ["N=0"], ["controller.K=2"], ["controller.K=1,2"],
    ["controller.u0=1,2"], ["plant.state=1x"], ["controller.allow_unstable=2"],
    ["plant.x0=[true]"], ["r_true=-1"], ["controller.mode=sideways"], ["speed=3"],
])
def test_a_loop_files_design_refuses_what_its_loop_refuses(sets):
    from delaycomp.errors import ParameterError
    from delaycomp.paper.scenarios import loop_file

    lf = scenarios.open_source(loop_file("example-3.6"))
    try:
        data = lf.resolve(sets)
    except ParameterError:
        return  # refused before either is built
    with pytest.raises(ParameterError) as built:
        lf.make(data)
    with pytest.raises(ParameterError) as designed:
        lf.design(data)
    assert str(designed.value) == str(built.value)
    good = lf.resolve(["r=0.2"])
    assert lf.designs([good, data]) is None and lf.designs([data, good]) is None
    assert lf.designs([good, good]) is not None


def test_a_loop_files_designs_are_its_designs_one_by_one(tmp_path):
    """``LoopFile.designs`` (lists shared by the points parsed once, the checks vectorized)
    stacks what ``LoopFile.design`` gives point by point."""
    mimo = tmp_path / "mimo.toml"
    mimo.write_text(MIMO_LOOP, encoding="utf-8")
    lf = scenarios.open_source(str(mimo))
    datas = [lf.resolve([f"r={r}", f"r_true={rt}", f"T={T}", "controller.u0=[0.5]"])
             for r in (0.0, 0.3) for rt in (0.1, 0.45) for T in (0.5, 0.25)]
    many = lf.designs(datas)
    one = [lf.design(d) for d in datas]
    assert len(many) == len(one) == 8
    # stacked copies of the same parsed numbers (no arithmetic between them): equal
    for name in ("A", "B", "K", "x0", "u0", "r", "tau", "mode"):
        assert np.array_equal(getattr(many, name),
                              np.array([getattr(p.lti, name) for p in one])), name
    assert many.r_true.tolist() == [p.lti.r_true for p in one]
    assert many.timings() == {p.timing for p in one}


def test_a_batch_sweep_of_a_loop_file_names_a_bad_point(tmp_path):
    """Every point is validated before any runs, on the design path too."""
    from delaycomp.errors import ParameterError

    mimo = tmp_path / "mimo.toml"
    mimo.write_text(MIMO_LOOP, encoding="utf-8")
    with pytest.raises(ParameterError, match=r"grid point T=0\.3: .*tau = 0\.5"):
        sweep.run_sweep(str(mimo), [parse_grid("T=0.5:0.3:2")], [],
                        SweepOptions(stop=3.0, engine="batch"))


def _design_args(k: float, r: float, **changes) -> dict:
    args = dict(A=[[0.0, 1.0], [0.5, 0.0]], B=[[0.0], [1.0]], K=[[-k, -1.5]], T=0.5, N=10,
                r=r, tau=0.5, mode="compensated", x0=[1.0, 0.0], u0=[0.25], r_true=None,
                tau_true=0.6)
    args.update(changes)
    return args


def test_designs_of_many_points_are_their_designs_one_by_one():
    """The vectorized validation (``lti_designs``) gives what ``lti_design`` gives point by
    point, stacked (the true delays filled in with the assumed ones)."""
    from delaycomp.system import lti_design, lti_designs

    args = [_design_args(k, r, mode=mode) for k in (0.5, 1.0, 2.5) for r in (0.0, 0.35)
            for mode in ("compensated", "uncompensated")]
    batch_ = lti_designs(args)
    one = [lti_design(**a) for a in args]
    assert len(batch_) == len(args)
    # stacked copies of the same numbers (no arithmetic between them): equal
    for name in ("A", "B", "K", "x0", "u0", "r", "tau", "mode"):
        assert np.array_equal(getattr(batch_, name),
                              np.array([getattr(p.lti, name) for p in one])), name
    assert batch_.r_true.tolist() == [p.lti.r for p in one]
    assert batch_.tau_true.tolist() == [0.6] * len(one)
    assert batch_.timings() == {p.timing for p in one}


@pytest.mark.parametrize("changes", [
    dict(r=0.305), dict(r=-0.1), dict(tau_true=math.nan), dict(r_true=0.33), dict(T=0.0),
    dict(T=math.inf), dict(N=0), dict(N=10.0), dict(K=[[1.0, 2.0, 3.0]]),
    dict(A=[[0.0, math.inf], [0.5, 0.0]]), dict(x0=[1.0]), dict(u0=[0.0, 1.0]),
    dict(mode="sideways"), dict(mode=["compensated"]), dict(A=[[0.0, 1.0]]), dict(B=[[1.0]]),
    dict(A=[[[0.0]]]), dict(K="x"), dict(T="1"), dict(r=None), dict(tau="0.5"),
], ids=lambda c: ",".join(f"{k}={v}" for k, v in c.items()))
def test_designs_of_many_points_accept_no_point_that_one_by_one_refuses(changes):
    """One bad point anywhere in the grid: the batch is refused (``None``: validate one by
    one), and ``lti_design`` names what is wrong with that point."""
    from delaycomp.errors import ParameterError
    from delaycomp.system import lti_design, lti_designs

    good = [_design_args(k, 0.3) for k in (0.5, 1.0, 2.0)]
    bad = {**_design_args(1.5, 0.3), **changes}
    for at in range(len(good) + 1):
        assert lti_designs([*good[:at], bad, *good[at:]]) is None
    with pytest.raises(ParameterError):
        lti_design(**bad)


def test_the_engine_takes_the_validated_designs():
    """``run_lti`` takes the ``LtiBatch`` a sweep validates (``lti_designs``): the numbers
    of the loose-array ``simulate_lti`` to the bit (the same arithmetic), and a chunk of it
    (``take``) gives its points' numbers."""
    from delaycomp.system import lti_designs

    args = [_design_args(k, r, mode=mode, N=N) for k in (0.5, 2.5) for r in (0.0, 0.35)
            for mode in ("compensated", "uncompensated") for N in (10, 20)]
    design = lti_designs(args)
    res = batch.run_lti(design, 6.0, record=True)
    loose = batch.simulate_lti(design.A, design.B, design.K, design.T, design.N, design.r,
                               design.tau, design.x0, design.u0, list(design.mode), 6.0,
                               design.r_true, design.tau_true, record=True)
    for name in ("rho", "final_norm", "peak_norm", "deadbeat_time", "states", "inputs"):
        assert np.array_equal(getattr(res, name), getattr(loose, name), equal_nan=True), name
    part = batch.run_lti(batch.take(design, slice(3, 7)), 6.0)
    assert part.rows() == res.rows()[3:7]
    with pytest.raises(batch.BatchError, match="mode = 'sideways'"):
        batch.run_lti(dataclasses.replace(design, mode=np.array(["sideways"] * len(design),
                                                                 dtype=object)), 6.0)


def test_the_model_engine_takes_its_points_as_one_object():
    """``run_model`` takes the per-point timing as a ``ModelBatch``; ``simulate_model``
    gathers its loose arguments into one (the true delays filled in)."""
    model = load_model(path("example_3_8"))
    pts = batch.ModelBatch(T=np.array([1.0, 0.5, 1.0]), N=np.array([20, 20, 10]),
                           r=np.array([0.5, 0.25, 0.3]), tau=np.array([0.0, 0.5, 1.0]),
                           r_true=np.array([0.5, 0.25, 0.3]), tau_true=np.array([0.0, 0.5, 1.0]),
                           x0=np.array([[1.0, -1.0], [2.0, 1.0], [0.5, 0.5]]),
                           u0=np.zeros((3, 1)))
    res = batch.run_model(model, model.params(), pts, 6.0, record=True)
    loose = batch.simulate_model(model, model.params(), pts.T, pts.N, pts.r, pts.tau, pts.x0,
                                 [0.0], 6.0, record=True)
    assert len(pts) == 3 and res.rows() == loose.rows()
    assert np.array_equal(res.states, loose.states, equal_nan=True)
    assert batch.run_model(model, model.params(), batch.take(pts, [1]), 6.0).rows() == \
        res.rows()[1:2]


def test_a_batch_sweep_over_the_dimension_runs_each_shape_as_its_own_group():
    """Corollary 3.7 swept over ``n``: the points do not stack (one by one, one group per
    shape) and equal the per-point engine."""
    axes = [parse_grid("n=2:4:3"), parse_grid("r=0:0.5:2")]
    notes: list[str] = []
    b = sweep.run_sweep("corollary-3.7", axes, [],
                        SweepOptions(stop=4.0, engine="batch"), notes=notes)
    s = sweep.run_sweep("corollary-3.7", axes, [], SweepOptions(stop=4.0, engine="inprocess"))
    assert any("6 of 6 points in 3 chunks" in n for n in notes), notes
    for x, y in zip(b, s):
        assert_same(x, y, LTI_REL)


def test_a_bulk_batch_sweep_names_a_bad_grid_point():
    from delaycomp.errors import ParameterError

    with pytest.raises(ParameterError, match=r"grid point k=1, r=0\.105: .*multiple of the"):
        sweep.run_sweep("example-3.6", [parse_grid("k=1:2:2"), parse_grid("r=0.1:0.11:3")], [],
                        SweepOptions(stop=2.0, engine="batch"))


def test_api_sweep_defaults_to_the_batch_engine_and_equals_per_point():
    from delaycomp import api
    from delaycomp.paper.scenarios import loop_file

    notes: list[str] = []
    grid = {"r": [0.0, 0.3, 0.6], "r_true": [0.3, 0.7]}
    b = api.sweep(loop_file("example-3.6"), grid, stop_time=6.0, notes=notes, chunk=4)
    s = api.sweep(loop_file("example-3.6"), grid, stop_time=6.0, engine="inprocess")
    assert notes == ["batch engine (numpy, cpu): 6 of 6 points in 2 chunks"]
    assert [(x["r"], x["r_true"]) for x in b] == [(r, t) for r in grid["r"]
                                                  for t in grid["r_true"]]
    for x, y in zip(b, s):
        assert_same(x, y, LTI_REL)


@pytest.mark.parametrize("engine", ["batch", "inprocess", "fmu"])
def test_a_stop_time_off_some_points_grid_names_the_point(engine):
    """T = 1.5, N = 50 has h = 0.03, and 20 s is not a whole number of it: refused before
    anything runs (no FMU is built), naming the point, whatever the engine."""
    from delaycomp.errors import ParameterError

    axes = [parse_grid("T=0.5:1.5:3"), parse_grid("N=50:100:2")]
    with pytest.raises(ParameterError, match=r"^grid point T=1\.5, N=50: --stop-time 20\.0 "
                                             r"is not allowed: .* h = T/N = 0\.03$"):
        sweep.run_sweep("example-3.6", axes, ["r=0.3"], SweepOptions(stop=20.0, engine=engine))
