"""The C host (``fmus/native/host/host.c``) closing a loop over network channels (issue 29):
the native channel FMU in the place of either delay, with the plain native controller (the
channel's ``stamp`` output left unconnected) or the native time-stamp controller
(``stamp -> stamp``), wired by the variables' names where the counts differ.

The README's loop of one's own (``docs/examples/myloop.toml``, n = 3, m = 2) over the
network of ``tests/test_loop_stamps.py``: the measurement through a channel with uniform
jitter 2 T and 30 % of the packets lost, the commands through a jittered channel behind a
play-out buffer. The host's CSV is compared with delaycomp's own master (fmpy) running the
same native FMU binaries.

Why bit for bit: both processes call the same shared libraries with the same values in the
same order (each FMU's outputs read, the next one's inputs set, Gauss-Seidel along the
chain; then every FMU steps), and the native FMUs do their own arithmetic in C (no BLAS,
nothing that depends on the process). The two masters' times differ in the last bits (the
host's ``t0 + k h``, the master's ``t0 + i T + j h``: 1.8e-15 apart at most here), but every
FMU takes a step to its own integer grid (``delaycomp.maths.grid``), the channel draws
and delivers packets by step index, and its ``stamp`` is ``t0 + k h`` computed inside it: no
time the masters pass reaches the numbers. Measured: equal, 0 difference, in every case.
"""

from __future__ import annotations

import copy
import subprocess
from pathlib import Path

import numpy as np
import pytest
import tomllib

from delaycomp.fmu.host import host_argv, unpack
from delaycomp.fmu.twins import native_fmus
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.system.loopfile import build

from .conftest import machine_blas_settings
from .external import need

REPO = Path(__file__).resolve().parents[1]
MYLOOP = tomllib.loads((REPO / "docs" / "examples" / "myloop.toml").read_text("utf-8"))
#: a measurement channel with jitter 2 T (T = 0.2) and 30 % loss; commands through a
#: jittered channel behind a play-out buffer (tests/test_loop_stamps.py's network)
MEAS = {"distribution": "uniform", "jitter": 0.4, "loss_model": "bernoulli", "loss": 0.3,
        "seed": 7}
INPUT = {"distribution": "uniform", "delay": 0.2, "jitter": 0.2, "policy": "playout",
         "seed": 3}
#: id -> (stamps, [meas_delay] table or None, [input_delay] table or None)
LOOPS = {
    "stamps-both-channels": (True, MEAS, INPUT),
    "plain-both-channels": (False, MEAS, INPUT),
    "plain-measurement-channel": (False, MEAS, None),
    "plain-input-channel": (False, None, INPUT),
}
HEADER = "time,plant.x1,plant.x2,plant.x3,controller.u1,controller.u2"


def _loop(stamps, meas, inp, **plant):
    data = copy.deepcopy(MYLOOP)
    data["controller"]["stamps"] = stamps
    for table, value in (("meas_delay", meas), ("input_delay", inp)):
        if value is not None:
            data[table] = dict(value)
    data["plant"].update(plant)
    return build(data, REPO / "docs" / "examples", name="myloop")


@pytest.fixture(scope="module")
def native_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("native-channel")


def _host_rows(argv, timeout=120):
    proc = subprocess.run(["env", "-i", *machine_blas_settings(), *argv],
                          capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == HEADER
    return np.array([line.split(",") for line in lines[1:]], dtype=float)


@pytest.mark.parametrize("case", list(LOOPS))
def test_c_host_over_channels_equals_our_master(case, chost, native_dir, tmp_path):
    stamps, meas, inp = LOOPS[case]
    loop = _loop(stamps, meas, inp)
    kinds = {i.role: i.source.kind for i in loop.instances}
    assert kinds["meas_delay"] == ("channel" if meas else "delay")
    assert kinds["input_delay"] == ("channel" if inp else "delay")
    assert kinds["controller"] == ("stamped_controller" if stamps else "controller")
    stop = MYLOOP["stop_time"]
    fmus = native_fmus(loop, native_dir)
    rows = _host_rows(host_argv(chost, loop, stop, unpack(fmus, tmp_path)))
    ours = run_loop(loop, stop, fmus=fmus)
    assert ours.success, ours.message
    assert ours.names == HEADER.split(",")[1:]
    assert rows.shape == (len(ours.times), 6)
    assert np.abs(rows[:, 0] - ours.times).max() <= 4e-15  # t0 + k h against t0 + i T + j h
    assert np.array_equal(rows[:, 1:], ours.data)  # bit for bit: the module docstring


def test_the_host_wires_the_stamp(chost, native_dir, tmp_path):
    """The stamp reaches the time-stamp controller: with it the host's run differs from the
    plain controller's on the same network by far more than round-off (0.12 of the
    state in docs/howto/network.md), and both are finite."""
    runs = []
    for stamps in (True, False):
        loop = _loop(stamps, MEAS, INPUT)
        fmus = native_fmus(loop, native_dir)
        runs.append(_host_rows(host_argv(chost, loop, MYLOOP["stop_time"],
                                         unpack(fmus, tmp_path / str(stamps)))))
    assert np.all(np.isfinite(runs[0])) and np.all(np.isfinite(runs[1]))
    assert np.abs(runs[0][:, 1:4] - runs[1][:, 1:4]).max() > 1e-2


def _dirs(loop, native_dir, into):
    return unpack(native_fmus(loop, native_dir), into)


def _refusal(chost, dirs, stop="1"):
    argv = [str(chost), stop, "0.01",
            *(f"{n}={dirs[n]}" for n in ("plant", "meas_delay", "controller", "input_delay"))]
    return subprocess.run(argv, capture_output=True, text=True, timeout=60)


def test_a_controller_with_fewer_inputs_than_the_channel_is_refused(chost, native_dir,
                                                                     tmp_path):
    """A two-state loop's controller (inputs y1, y2) behind the three-state loop's
    measurement channel (outputs y1, y2, y3, stamp): y3 has nowhere to go; refused in one
    line naming the FMU and the variable, before any step."""
    net = _dirs(_loop(False, MEAS, INPUT), native_dir, tmp_path / "net")
    small = build({"T": 0.2, "N": 20, "r": 0.36, "tau": 0.4,
                   "plant": {"A": [[0, 1], [-1, 0]], "B": [[0, 0], [1, 0]], "x0": [1, 0]},
                   "controller": {"K": [[-1, -1], [-1, -1]]}}, REPO, name="small")
    net["controller"] = _dirs(small, native_dir, tmp_path / "small")["controller"]
    proc = _refusal(chost, net)
    assert proc.returncode == 1 and proc.stdout == ""
    assert proc.stderr == (
        "host: error: cannot connect meas_delay.y3: controller has no Real input y3, and "
        "meas_delay's 3 Real outputs (a stamp aside) cannot go in order to its 2 Real "
        "inputs\n")


def test_a_time_stamp_controller_behind_a_plain_delay_is_refused(chost, native_dir,
                                                                 tmp_path):
    """The time-stamp controller needs the stamp a channel gives: behind the delay FMU
    (outputs y1, y2, y3 only) its input ``stamp`` is refused, though the in-order rule
    could not tell (three outputs, four inputs: named first)."""
    stamped = _dirs(_loop(True, MEAS, INPUT), native_dir, tmp_path / "stamped")
    stamped["meas_delay"] = _dirs(_loop(False, None, None), native_dir,
                                  tmp_path / "plain")["meas_delay"]
    proc = _refusal(chost, stamped)
    assert proc.returncode == 1 and proc.stdout == ""
    assert proc.stderr == ("host: error: cannot connect controller.stamp: meas_delay has no "
                           "Real output stamp (the send time a network channel gives)\n")


def test_valgrind_finds_no_error_and_no_leak_in_the_host_over_channels(chost, native_dir,
                                                                       tmp_path):
    """The C host running the time-stamp loop over both channels (12 s, 1200 ticks) under
    valgrind: no invalid access, every heap block freed (as
    tests/test_native_model_controller.py does for the nonlinear loops)."""
    valgrind = need("valgrind")
    loop = _loop(True, MEAS, INPUT)
    dirs = _dirs(loop, native_dir, tmp_path)
    proc = subprocess.run([valgrind, "--error-exitcode=9", "--leak-check=full",
                           *host_argv(chost, loop, MYLOOP["stop_time"], dirs)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "All heap blocks were freed" in proc.stderr
    assert "ERROR SUMMARY: 0 errors" in proc.stderr
