"""A plant FMU that talks as a Modelica tool's export does (issue 25, item 4): its
information shown with ``-v`` only, its warnings always, each line prefixed by the
instance; the inputs the loop does not drive named once, with their start values, as a
note; ``--set plant.parameters.NAME=VALUE`` for the FMU's own (dotted) names.

The plant is the C test FMU ``Drive`` (``tests/cfmu``, README "Drive"): an info line at
initialization and eight lines of solver statistics at ``fmi2Terminate`` whatever
``loggingOn`` says, a warning when the tolerance is above 1e-3, extra inputs ``load.tau``
(Real, start 0) and ``brake.engaged`` (Boolean, start false).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from delaycomp.cli import main
from tests.cfmu.build import build_drive

pytestmark = pytest.mark.fmu

LOOP = """
T = 0.2
N = 20
r = 0.2
tau = 0.4
stop_time = 1
[plant]
fmu = "Drive.fmu"
states = ["sensor.phi", "sensor.w"]
inputs = ["motor.tau"]
x0 = [0, 0]
parameters = { "fixed.phi0" = 0 }
[controller]
A = [[0, 1], [1, -0.2]]
B = [[0], [-1]]
K = [[3, 2.5]]
u0 = [1]
"""
NOTE = ("note: plant inputs not driven by the loop keep their start values: load.tau = 0, "
        "brake.engaged = false")


@pytest.fixture(scope="module")
def loop_file(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("quiet")
    build_drive(out)
    (out / "drive.toml").write_text(LOOP, encoding="utf-8")
    return out / "drive.toml"


def _err(capsys, *argv) -> list[str]:
    assert main(list(argv)) == 0
    return capsys.readouterr().err.splitlines()


def test_info_only_with_v_and_the_free_inputs_once(loop_file, tmp_path, capsys):
    err = _err(capsys, "run", str(loop_file), "--out", str(tmp_path / "a.csv"), "--python")
    assert err == [NOTE], err  # the FMU's nine info lines are not shown
    err = _err(capsys, "run", str(loop_file), "--out", str(tmp_path / "b.csv"), "-v",
               "--python")
    assert err.count(NOTE) == 1
    assert "plant: Integration started at T = 0 with tolerance 0.0001 (Heun-Euler 2(1))" \
        in err, err
    shown = [line for line in err if line.startswith("plant: ")]
    assert len(shown) == 9 and any("Tolerance used" in line for line in shown), err
    err = _err(capsys, "run", str(loop_file), "--out", str(tmp_path / "c.csv"), "-q")
    assert err == []


def test_warnings_always_with_the_instance_name(loop_file, tmp_path, capsys):
    warning = ("plant: warning: tolerance 0.01 is larger than 1e-3: the results may be "
               "inaccurate")
    for quiet in ([], ["-q"]):
        err = _err(capsys, "run", str(loop_file), "--set", "plant.tolerance=0.01",
                   "--out", str(tmp_path / "w.csv"), "--python", *quiet)
        assert warning in err and not any("Tolerance used" in line for line in err), err


def test_result_keeps_every_message_with_its_status(loop_file):
    from delaycomp.orchestrator.simulate import run_loop
    from delaycomp.system.loopfile import read_loop

    res = run_loop(read_loop(loop_file, ["plant.tolerance=0.01"]), 0.4)
    statuses = {status for _, status, _ in res.logged}
    assert statuses == {"ok", "warning"} and {name for name, _, _ in res.logged} == {"plant"}
    assert [f"{n}: {t}" for n, _, t in res.logged] == [
        note for note in res.notes if note.startswith("plant: ")]


def test_export_loop_and_sweep_say_it_once_as_a_note(loop_file, tmp_path, capsys):
    err = _err(capsys, "export-loop", str(loop_file), "--out", str(tmp_path / "l.fmu"),
               "--python")
    # fmu-manipulation-toolbox's "Input 'Port plant.fmu/load.tau' is not connected" error
    # is the note now
    assert err.count(NOTE) == 1 and not any("not connected" in line for line in err), err
    err = _err(capsys, "sweep", str(loop_file), "--grid", "r=0.2:0.4:2", "--stop-time", "0.4",
               "--out", str(tmp_path / "s.csv"))
    assert err.count(NOTE) == 1, err


@pytest.mark.parametrize("name", ["damper.d", '"damper.d"', "'damper.d'"])
def test_set_a_parameter_by_its_fmu_name(loop_file, tmp_path, name, capsys):
    base, moved = tmp_path / "base.csv", tmp_path / "moved.csv"
    assert main(["run", str(loop_file), "--out", str(base), "-q", "--python"]) == 0
    assert main(["run", str(loop_file), "--out", str(moved), "-q", "--python",
                 "--set", f"plant.parameters.{name}=5"]) == 0
    a = np.loadtxt(base, delimiter=",", skiprows=1)
    b = np.loadtxt(moved, delimiter=",", skiprows=1)
    # the damping (0.2 by default) changes the motion, not the start
    assert np.array_equal(a[0], b[0]) and np.abs(a[-1, 1:3] - b[-1, 1:3]).max() > 1e-2
    # the file's other keys stay (a table of parameters merged, not replaced)
    from delaycomp.system.loopfile import LoopFile

    data = LoopFile(loop_file).resolve([f"plant.parameters.{name}=0.3",
                                        'plant.parameters."fixed.phi0"=0.5'])
    assert data["plant"]["parameters"] == {"fixed.phi0": 0.5, "damper.d": 0.3}
    assert LoopFile(loop_file).data["plant"]["parameters"] == {"fixed.phi0": 0}


@pytest.mark.parametrize("assignment, message", [
    ("plant.parameters.nope=1", "plant.parameters: 'nope' is not a settable parameter of "
                                "Drive.fmu: allowed are spring.c, damper.d"),
    ('plant.parameters."fixed.phi0=1', "the variable name \"fixed.phi0 is not allowed: "
                                       "must be one name, in one pair of quotes or none"),
    ("plant.parameters.body.J=0", None),
])
def test_bad_parameter_sets_are_one_line_exit_2(loop_file, assignment, message, capsys):
    assert main(["run", str(loop_file), "--set", assignment, "-q"]) == (2 if message else 1)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    if message:
        assert message in err[0], err
    else:  # refused by the FMU itself at initialization: a failed run naming it
        assert "body.J" in err[0], err


def test_columns_name_what_the_plant_receives_by_its_own_input_names(loop_file, tmp_path):
    """The CSV keeps its columns (the outputs measured, the controller's ``u``) and adds
    what the plant receives, named by the FMU's own input (``plant.motor.tau``): the
    controller's output tau = 0.4 s earlier (u0 = 1 before), exactly (the input delay is a
    shift on the grid). The column travels through the SSP (dc:Record name=) and back."""
    from delaycomp.formats import ssp
    from delaycomp.orchestrator.simulate import run_loop
    from delaycomp.system.loopfile import read_loop

    out = tmp_path / "cols.csv"
    assert main(["run", str(loop_file), "--out", str(out), "-q"]) == 0
    data = np.genfromtxt(out, delimiter=",", names=True, deletechars="")
    assert list(data.dtype.names) == ["time", "plant.sensor.phi", "plant.sensor.w",
                                      "controller.u", "plant.motor.tau"]
    shift = 40  # tau / h = 0.4 / 0.01 base steps
    received, sent = data["plant.motor.tau"], data["controller.u"]
    assert np.array_equal(received[shift:], sent[:-shift])
    assert np.all(received[:shift] == 1.0) and np.max(np.abs(sent)) > 0.1
    loop = read_loop(loop_file)
    path = ssp.pack(loop, ssp.SystemInfo("drive", "Drive", 1.0), tmp_path / "cols.ssp")
    with ssp.Archive(path) as archive:
        back = archive.system.spec
        assert back.columns == loop.columns
        res = run_loop(back, 1.0, fmus=archive.fmus())
    assert res.names == loop.columns and np.array_equal(res.data[:, -1], received)


def test_a_label_must_name_a_recorded_port_and_a_new_column(loop_file):
    """``Loop.labels`` is checked when the loop is built: a label of a port that is not
    recorded, or one that repeats another column, is refused naming it."""
    from delaycomp.errors import ParameterError
    from delaycomp.system import Port
    from delaycomp.system.loopfile import read_loop

    loop = read_loop(loop_file)
    with pytest.raises(ParameterError, match=r"label 'x' names meas_delay\.y, which is not "
                                             r"recorded"):
        loop.replace(labels=((Port("meas_delay", "y"), "x"),))
    with pytest.raises(ParameterError, match=r"two recorded columns are named "
                                             r"'plant\.sensor\.phi'"):
        loop.replace(labels=((Port("input_delay", "y"), "plant.sensor.phi"),))
