"""The controller alone in someone else's loop (issue 24, item 4).

A user's loop file names a plant FMU written elsewhere (the C test plant of
``tests/cfmu``, RK4 inside, exported by no delaycomp code). ``delaycomp build LOOP.toml
--only controller`` gives the controller, ``--only delays`` the two delays; a system is
then put together from those files as an SSP (the controller with no parameter set: its
start values are the loop's), and OMSimulator's command line (the plain archive, under
``env -i``: no Python), libcosim and Ecos (the Jacobi variant the wiring sheet points to)
run it.
Each equals our own run of the whole loop (``delaycomp run LOOP.toml``).

Bounds: the same plant binary and the same controller maths (the native controller
against the Python one of ``delaycomp run``, which differ by round-off: 1e-12 of each
signal's peak holds with room); OMSimulator's CSV has 12 significant digits, so 1e-11 of
the peak there.
"""

from __future__ import annotations

import dataclasses
import subprocess
from pathlib import Path

import numpy as np
import pytest

from delaycomp.orchestrator.simulate import run_loop
from delaycomp.system.loop import FmuFile
from delaycomp.system.loopfile import read_loop
from tests.cfmu.build import build_oscillator

from .test_loopbuild import cli, write_loop
from .test_plant_fmu import LOOP, STOP

pytestmark = pytest.mark.fmu


@pytest.fixture(scope="module")
def users_loop(tmp_path_factory):
    """The loop file, its whole-loop run, and the controller and delays built from it."""
    folder = tmp_path_factory.mktemp("alone")
    build_oscillator(folder)
    loop_file = write_loop(folder, LOOP, "osc")
    for only in ("controller", "delays"):
        proc = cli("build", loop_file, "--out", folder / "fmus", "--only", only)
        assert proc.returncode == 0, proc.stderr
    loop = read_loop(loop_file)
    whole = run_loop(loop, STOP)
    assert whole.success, whole.message
    return folder, loop, whole


def _assembled(folder: Path, loop):
    """The loop as a user puts it together: their plant FMU, our controller and delays as
    files; the controller with no parameter set (its start values)."""
    files = {role: folder / "fmus" / f"osc_{role}.fmu"
             for role in ("meas_delay", "controller", "input_delay")}
    return loop.with_instances(
        dataclasses.replace(i, source=FmuFile(files[i.role]),
                            parameters={} if i.role == "controller" else dict(i.parameters))
        if i.role in files else i for i in loop.instances)


def _close(got_names, got, whole, rel):
    cols = [got_names.index(n) for n in whole.names]
    peak = np.max(np.abs(whole.data), axis=0)
    err = np.abs(got[:, cols] - whole.data)
    assert np.all(err <= rel * peak), (err.max(axis=0), peak)


def test_the_assembled_loop_runs_in_our_master_as_the_whole_loop(users_loop):
    folder, loop, whole = users_loop
    res = run_loop(_assembled(folder, loop), STOP)
    assert res.success, res.message
    _close(res.names, res.data, whole, 1e-12)


def test_omsimulators_command_line_runs_the_users_ssp(oms, users_loop, tmp_path):
    from delaycomp.formats.ssp import loop_system, pack

    folder, loop, whole = users_loop
    archive = pack(*loop_system(_assembled(folder, loop)), tmp_path / "users.ssp")
    result = tmp_path / "run" / "result.csv"
    result.parent.mkdir()
    proc = subprocess.run(["env", "-i", str(oms.cli), f"--stopTime={STOP!r}",
                           f"--resultFile={result}", str(archive)],
                          cwd=result.parent, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "error" not in (proc.stdout + proc.stderr).lower(), \
        proc.stdout[-2000:]
    import csv

    with open(result, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh, skipinitialspace=True))
    header, table = rows[0], np.array(rows[1:], dtype=float)
    table = table[np.append(table[1:, 0] != table[:-1, 0], True)]  # each time's last row
    names = [next((n for n in whole.names if h.endswith("." + n)), h) for h in header]
    assert table.shape[0] == whole.data.shape[0]
    np.testing.assert_allclose(table[:, 0], whole.times, rtol=0, atol=1e-9)
    _close(names, table, whole, 1e-11)


@pytest.mark.parametrize("master", ["libcosim", "ecos"])
def test_jacobi_masters_run_the_users_ssp_jacobi_variant(master, users_loop, tmp_path):
    """libcosim and Ecos step every FMU, then exchange: the Jacobi variant (the
    controller's ``held_sample``, the measurement delay shorter by h) gives the loop."""
    from delaycomp.verify.thirdparty import pack_jacobi, run_ssp

    folder, loop, whole = users_loop
    archive = pack_jacobi(_assembled(folder, loop), tmp_path / "users-jacobi.ssp")
    res = run_ssp(master, archive, STOP)
    assert res.success, res.message
    assert res.data.shape[0] == whole.data.shape[0]
    _close(res.names, res.data, whole, 1e-12)


def test_the_fmpy_example_wires_the_controller_in_a_host_of_your_own(tmp_path):
    """``docs/examples/controller_alone.py``: the cart's FMUs from ``delaycomp build``,
    stepped by a plain fmpy loop that sets no parameter, reach at t = 2.5 (before the
    dead-beat law has brought the cart to rest at 4 s) the state of ``delaycomp run``
    (printed to 12 digits)."""
    import shutil
    import sys

    from delaycomp.fmu.twins import native_fmus

    examples = Path(__file__).resolve().parent.parent / "docs" / "examples"
    for name in ("cart.toml", "cart.py", "controller_alone.py"):
        shutil.copy(examples / name, tmp_path / name)
    proc = cli("build", tmp_path / "cart.toml", "--out", tmp_path / "fmus")
    assert proc.returncode == 0, proc.stderr
    ran = subprocess.run([sys.executable, str(tmp_path / "controller_alone.py"),
                          str(tmp_path / "fmus"), "2.5"], capture_output=True, text=True,
                         timeout=300)
    assert ran.returncode == 0, ran.stderr
    printed = dict(item.split(" = ") for item in ran.stdout.strip().split(", "))
    loop = read_loop(tmp_path / "cart.toml")
    ours = run_loop(loop, 2.5, fmus=native_fmus(loop))
    assert ours.success, ours.message
    peak = np.max(np.abs(ours.data), axis=0)
    assert np.all(np.abs(ours.data[-1, :2]) > 1e-3 * peak[:2])  # still moving: a real check
    for j, name in enumerate(ours.names):
        if name.startswith("plant."):
            got = float(printed[name.removeprefix("plant.")])
            assert abs(got - ours.data[-1, j]) <= 1e-11 * peak[j], (name, got)
    assert set(printed) == {n.removeprefix("plant.") for n in ours.names
                            if n.startswith("plant.")}
