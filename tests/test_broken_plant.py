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
