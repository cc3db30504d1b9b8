"""A broken plant never gives a successful run (issue 30, item 1).

A plant whose outputs become NaN or infinite, at any tick and the last one included,
stops the run in our master (every engine: the FMUs, in-process, a foreign SSP, the
container's loop), naming the output and the time; the masters of others that we drive
(libcosim, Ecos, OMSimulator) and fmpy on the container are held to the same rule on their
results. Before the fix a NaN at the stop time ran to exit 0 with a complete-looking CSV.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from delaycomp.orchestrator.master import Master, Recorder, SimulationError
from delaycomp.orchestrator.simulate import Result

from .test_master import Mock, gain, loop


def broken_plant(bad: float, from_tick: int) -> Mock:
    """A plant (no feedthrough) whose output is 1 until ``from_tick`` steps are done,
    then ``bad``."""
    return Mock("plant", False, lambda m: bad if len(m.calls) >= from_tick else 1.0)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("from_tick", [1, 4, 10])  # 10: the last tick of run_until(10)
def test_the_master_stops_where_an_output_is_not_finite(bad, from_tick):
    master = Master([broken_plant(bad, from_tick), gain("g", -1.0)], loop("plant", "g"),
                    T=1.0, N=10)
    rec = Recorder(master, [("plant", "out")])
    master.add_observer(rec)
    master.setup(1.0, {})
    master.initialize()
    with pytest.raises(SimulationError) as info:
        master.run_until(10)
    t = from_tick * 0.1
    assert str(info.value) == (f"plant failed at t = {t:.12g}: its output out = {bad!r} is "
                               "not allowed: must be finite")
    assert len(rec.rows) == from_tick  # ticks 0 .. from_tick - 1, none of them broken
    assert all(math.isfinite(row[0]) for row in rec.rows)


def test_a_broken_initial_output_is_refused_at_initialization():
    master = Master([broken_plant(math.nan, 0), gain("g", -1.0)], loop("plant", "g"),
                    T=1.0, N=10)
    master.setup(1.0, {})
    with pytest.raises(SimulationError, match=r"^plant failed at t = 0: its output out = "):
        master.initialize()


def test_the_source_is_blamed_not_the_component_that_refuses_its_input():
    """A delay (here a gain) that refuses a NaN input would name itself; the master names
    the output that broke."""
    def refuse(m, names, values):
        if not math.isfinite(values[0]):
            m.last_message = f"input in = {values[0]!r} is not allowed: must be finite"
            raise ValueError(m.last_message)
        m.u = values[0]

    g = gain("g", -1.0)
    g.set_inputs = lambda names, values: refuse(g, names, values)
    master = Master([broken_plant(math.nan, 3), g], loop("plant", "g"), T=1.0, N=10)
    master.setup(1.0, {})
    master.initialize()
    with pytest.raises(SimulationError, match=r"^plant failed at t = 0\.3: its output out "):
        master.run_until(10)


def test_finite_outputs_whose_sum_overflows_run_on():
    """The master checks one sum per tick; a sum that overflows over finite outputs
    (1e308 + 1e308) is looked at output by output and passes."""
    big = Mock("plant", False, lambda m: 1e308)
    master = Master([big, gain("g", 1.0)], loop("plant", "g"), T=1.0, N=10)
    master.setup(1.0, {})
    master.initialize()
    master.run_until(10)
    assert master.k == 10


def test_a_result_of_another_master_is_checked_the_same_way():
    times = np.arange(5) * 0.5
    data = np.column_stack([np.ones(5), np.ones(5)])
    data[3, 1] = -np.inf
    res = Result(["plant.x", "controller.u"], times, data).checked_finite("libcosim")
    assert not res.success and len(res.times) == 3
    assert res.message == ("libcosim: controller.u = -inf at t = 1.5 is not allowed: must be "
                           "finite")
    good = Result(["plant.x"], times, np.ones((5, 1)))
    assert good.checked_finite("ecos") is good


# -- end to end: a C plant FMU of "another tool" that breaks down ------------------------

LOOP = """
T = 0.5
N = 10
r = 0.3
tau = 0.5
stop_time = 2.0
[plant]
fmu = "Broken.fmu"
states = ["position", "velocity"]
inputs = ["force"]
x0 = [1.0, 0.0]
[controller]
A = [[0, 1], [1, -0.2]]
B = [[0], [1]]
K = [[-3.0, -2.5]]
"""


def _cli(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "delaycomp", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.fmu
@pytest.mark.parametrize("broken_after", [1.0, 2.0])  # 2.0: the stop time, the last row
def test_run_fails_on_a_plant_fmu_that_breaks_down(tmp_path, broken_after):
    from tests.cfmu.build import build_oscillator

    build_oscillator(tmp_path, "Broken.fmu", broken_after=broken_after)
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    proc = _cli("run", "loop.toml", "--out", "out.csv", cwd=tmp_path)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith(
        f"delaycomp: error: plant failed at t = {broken_after:g}: its output position = nan "
        "is not allowed: must be finite")
    assert not (tmp_path / "out.csv").exists()
    rows = (tmp_path / "out.csv.partial").read_text().splitlines()
    assert len(rows) == 1 + round(broken_after / 0.05)  # the header, then t < broken_after
    assert "nan" not in "".join(rows).lower()
    # the same loop packed as an SSP and run in our master from the archive
    proc = _cli("ssp", "loop.toml", "--out", "loop.ssp", "--python", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = _cli("run", "loop.ssp", cwd=tmp_path)
    assert proc.returncode == 1 and "its output position = nan" in proc.stderr, proc.stderr


# -- sweeps: a broken plant's point is failed, never "unstable" ----------------------------

def _sweep_rows(path: Path) -> list[dict]:
    import csv

    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.fmu
@pytest.mark.parametrize("broken_after", [1.0, 2.0])  # 2.0: the stop time, the last row
def test_a_sweep_marks_a_broken_plant_failed_not_unstable(tmp_path, broken_after):
    """Before the fix each point read ``stable = 0``, ``rho = inf`` and the command exited 0."""
    from tests.cfmu.build import build_oscillator

    build_oscillator(tmp_path, "Broken.fmu", broken_after=broken_after)
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    proc = _cli("sweep", "loop.toml", "--grid", "r=0.2:0.3:2", "--workers", "1",
                "--out", "map.csv", cwd=tmp_path)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert ", 0 stable, 2 failed; wrote map.csv" in proc.stdout
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("delaycomp: error: 2 of 2 points failed (column failed of map.csv)")
    rows = _sweep_rows(tmp_path / "map.csv")
    assert [r["r"] for r in rows] == ["0.2", "0.3"]
    for row in rows:
        assert row["rho"] == "" and row["stable"] == "" and row["deadbeat_time"] == ""
        assert row["failed"].startswith(f"plant failed at t = {broken_after:g}: its output "
                                        "position = nan is not allowed: must be finite")
        assert math.isfinite(float(row["peak_norm"]))  # the metrics of the rows before it


@pytest.mark.fmu
def test_a_sweep_of_a_healthy_plant_fmu_has_no_failures(tmp_path):
    """The same loop with the plant intact: every point completes, ``failed`` is empty."""
    from tests.cfmu.build import build_oscillator

    build_oscillator(tmp_path, "Broken.fmu")
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    proc = _cli("sweep", "loop.toml", "--grid", "r=0.2:0.3:2", "--workers", "1",
                "--out", "map.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert " failed" not in proc.stdout
    rows = _sweep_rows(tmp_path / "map.csv")
    assert all(r["failed"] == "" and r["stable"] in ("0", "1") and r["rho"] for r in rows)


@pytest.mark.parametrize("engine", ["batch", "inprocess"])
def test_a_sweep_calls_a_diverging_loop_unstable_with_its_reason(tmp_path, engine):
    """Our own plant refuses a state that overflowed (the loop diverged): unstable,
    ``rho = inf``, the reason in ``failed``, exit 0 (a result, not a failure)."""
    proc = _cli("sweep", "example-3.6", "--set", "mode=uncompensated", "--grid",
                "k=1e150:1e300:2", "--stop-time", "5", "--engine", engine, "--workers", "1",
                "--out", "map.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert ", 0 stable; wrote map.csv" in proc.stdout
    for row in _sweep_rows(tmp_path / "map.csv"):
        assert row["rho"] == "inf" and row["stable"] == "0"
        assert "is not finite" in row["failed"] or "must be finite" in row["failed"]
        assert "diverged" in row["failed"]


MODEL = '''
import math
import numpy as np
STATES = ("x",)
INPUTS = ("u",)
CONTROL = "zoh"
PARAMETERS = {}

def f(x, u, p):
    return np.array([x[0] + u[0]])

def step(x, u, h, p):
    if x[0] < 0.5:
        math.sqrt(-1.0)  # a bug in the model's own code: ValueError, math domain error
    e = math.exp(h)
    return np.array([e * x[0] + (e - 1.0) * u[0]])

def k(x, p):
    return np.array([-2.0 * x[0]])
'''

MODEL_LOOP = """
T = 0.5
N = 5
r = 0.1
tau = 0.0
stop_time = 5.0
[plant]
model = "buggy.py"
x0 = [1.0]
[controller]
predictor = "numerical"
"""


def test_an_exception_in_a_models_step_is_a_failure_not_a_divergence(tmp_path):
    """A ValueError raised by a model's own ``step`` was reported as "the plant diverged"
    (and a sweep called the point unstable); it is a failure of the model, named."""
    from delaycomp import api

    (tmp_path / "buggy.py").write_text(MODEL, encoding="utf-8")
    (tmp_path / "loop.toml").write_text(MODEL_LOOP, encoding="utf-8")
    from delaycomp.errors import SimulationFailed

    with pytest.raises(SimulationFailed) as info:
        api.run(api.load(tmp_path / "loop.toml"), engine="inprocess")
    message = str(info.value)
    assert "the model's step raised ValueError: math domain error" in message
    assert "diverged" not in message
    rows = api.sweep(tmp_path / "loop.toml", {"r": [0.1, 0.2]}, engine="inprocess")
    assert all(row["stable"] is None and row["rho"] is None for row in rows)
    assert all("math domain error" in row["failed"] for row in rows)
