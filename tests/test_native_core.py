"""The native stepping core (``delaycomp.orchestrator.native_core``, C in
``fmus/native/host/stepping.c``): a loop of native FMUs stepped from C gives the Python
master's rows bit for bit (the same binaries, called with the same arguments in the same
order), through every path of a run: decimation, blocks, failures, progress, the CSV."""

from __future__ import annotations

import numpy as np
import pytest

from delaycomp import api
from delaycomp.errors import ParameterError
from delaycomp.fmu.twins import native_fmus
from delaycomp.maths.channel import Channel
from delaycomp.orchestrator import native_core
from delaycomp.orchestrator.simulate import run_loop

pytestmark = pytest.mark.skipif(native_core.core_status() is not None,
                                reason=f"{native_core.core_status()}")

#: each scenario to a stop time of a few sampling periods: every kind of native FMU (LTI
#: plant and controller, the model files' plants and controllers of both families, the
#: delays), ZOH and continuous input
SCENARIOS = {"example-3.6": 4.0, "example-2.4": 2.0, "example-3.8": 3.0,
             "corollary-3.7": 3.0, "corollary-4.1": 2.0, "proposition-4.2": 2.0}


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the bit (a -0.0 is not 0.0; the shapes agree)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def both(loop, stop: float, fmus=None, **options):
    """The run by the core and by the Python master, on the same native FMUs."""
    fmus = native_fmus(loop) if fmus is None else fmus
    core = run_loop(loop, stop, fmus=fmus, stepping="native-core", **options)
    python = run_loop(loop, stop, fmus=fmus, stepping="python", **options)
    assert core.stepped_by == "native-core" and python.stepped_by == "python"
    return core, python


def assert_same_run(core, python) -> None:
    assert core.names == python.names
    assert same_bits(core.times, python.times)
    assert same_bits(core.data, python.data)
    assert (core.success, core.message, core.failed_by, core.row_count) == \
        (python.success, python.message, python.failed_by, python.row_count)
    assert core.logged == python.logged


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_the_core_steps_each_scenario_as_the_python_master_bit_for_bit(scenario):
    core, python = both(api.load(scenario), SCENARIOS[scenario])
    assert len(core.times) > 100
    assert_same_run(core, python)


def test_a_users_loop_with_network_channels_and_vectors_bit_for_bit():
    """A user's LTI loop (two states), both delays network channels (jitter, loss, a
    seed): the channel FMU's draws and the controller's vectors, as the master steps
    them."""
    net = Channel(distribution="uniform", jitter=0.05, loss_model="bernoulli", loss=0.2,
                  seed=11)
    loop = api.lti([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[-1.0, -1.6]], T=0.5,
                   r=0.2, tau=0.5, N=10, x0=[1.0, 0.0], meas_channel=net,
                   input_channel=Channel(delay=0.5, distribution="exponential", jitter=0.1,
                                         max_delay=1.0, seed=3))
    core, python = both(loop, 6.0)
    assert_same_run(core, python)


def test_fmi3_native_fmus_bit_for_bit():
    loop = api.load("example-3.6")
    fmus = native_fmus(loop, fmi=3)
    core, python = both(loop, 3.0, fmus=fmus)
    assert_same_run(core, python)
    # and the FMI 2.0 FMUs give the same rows (as the Python master holds them)
    two = run_loop(loop, 3.0, fmus=native_fmus(loop), stepping="native-core")
    assert same_bits(two.data, core.data)


def test_decimated_rows_the_final_tick_and_small_blocks(monkeypatch):
    """A row every 7 ticks and the stop tick (not a multiple of 7), the rows coming back
    in blocks of 5 (the core's buffer full, again and again): the recorder's rows."""
    monkeypatch.setattr(native_core, "_MAX_BLOCK", 5)
    loop = api.load("example-3.6")
    core, python = both(loop, 2.0, every=7)
    assert len(core.times) == 201 // 7 + 2  # ticks 0, 7, ..., 196 and 200
    assert core.times[-1] == 2.0
    assert_same_run(core, python)


@pytest.mark.parametrize("sets,failed_by", [
    # the controller's output overflows: its fmi2GetReal refuses, in the propagation
    ({"k": -1e200, "mode": "uncompensated"}, "controller"),
    # the plant's state overflows: its fmi2DoStep refuses, in the step
    ({"x0": 1e307, "k": -0.5, "mode": "uncompensated"}, "plant"),
])
def test_a_loop_that_breaks_down_fails_at_the_same_tick_with_the_same_message(sets,
                                                                             failed_by):
    """Both runs stop at the same tick, with the same message, the same component blamed
    and the same rows before it."""
    core, python = both(api.load("example-3.6", sets), 20.0)
    assert not core.success and "must be finite" in core.message, core.message
    assert core.failed_by == failed_by and 50 < core.row_count < 2000
    assert_same_run(core, python)


def test_progress_is_heard_about_every_percent_up_to_the_last_tick():
    heard: list[int] = []
    loop = api.load("example-3.6")
    res = run_loop(loop, 20.0, fmus=native_fmus(loop), stepping="native-core",
                   progress=heard.append)
    assert res.stepped_by == "native-core"
    assert heard == sorted(heard) and heard[-1] == 2000
    assert 90 <= len(heard) <= 101


def test_without_keep_the_result_holds_the_last_row_and_the_sink_every_row():
    rows: list = []
    loop = api.load("example-3.6")
    fmus = native_fmus(loop)
    kept = run_loop(loop, 3.0, fmus=fmus, stepping="python")
    res = run_loop(loop, 3.0, fmus=fmus, stepping="native-core", keep=False,
                   sink=lambda t, row: rows.append((t, *row)))
    assert res.row_count == 301 and len(res.times) == 1
    assert same_bits(res.data, kept.data[-1:])
    assert same_bits(np.array(rows), np.column_stack([kept.times, kept.data]))


def test_the_csv_is_the_python_masters_byte_for_byte(tmp_path):
    from delaycomp.formats.outputs import CsvStream

    loop = api.load("example-2.4")
    fmus = native_fmus(loop)
    for stepping in ("native-core", "python"):
        stream = CsvStream(tmp_path / f"{stepping}.csv", loop.columns)
        run_loop(loop, 2.0, fmus=fmus, stepping=stepping, sink=stream, keep=False)
        stream.finish(True)
    # the text is the contract here (repr of every value, the same rows): compared whole
    core_text = (tmp_path / "native-core.csv").read_text(encoding="utf-8")
    assert core_text == (tmp_path / "python.csv").read_text(encoding="utf-8")


def test_auto_steps_native_loops_with_the_core_and_says_why_not_otherwise():
    loop = api.load("example-3.6")
    assert api.run(loop, 1.0).stepped_by == "native-core"
    res = api.run(loop, 1.0, fmus="python")
    assert res.stepped_by == "python" and res.stepping_note == "plant is a Python FMU"
    assert api.run(loop, 1.0, engine="inprocess").stepped_by == "python"


def test_clocked_fmi3_controllers_run_in_the_python_master():
    loop = api.load("example-3.6")
    res = api.run(loop, 1.0, fmi=3, clocked=True)
    assert res.stepped_by == "python" and "clocked" in res.stepping_note


@pytest.mark.parametrize("options,words", [
    ({"fmus": "python"}, "plant is a Python FMU"),
    ({"engine": "inprocess"}, "with the inprocess engine"),
    ({"stepping": "fast"}, "must be one of auto, native-core, python"),
])
def test_asking_for_the_core_where_it_cannot_step_is_refused(options, words):
    options = {"stepping": "native-core", **options}
    with pytest.raises(ParameterError, match=words):
        api.run("example-3.6", 1.0, **options)


def test_the_command_line_refuses_before_any_work_and_says_which_stepped(tmp_path, capsys):
    from delaycomp.cli import main

    out = tmp_path / "o.csv"
    out.write_text("an older result\n")
    assert main(["run", "example-3.6", "--stop-time", "1", "--python", "--stepping",
                 "native-core", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == ("delaycomp: error: --stepping native-core is not allowed for "
                           "this run: plant is a Python FMU")
    assert out.read_text() == "an older result\n"  # nothing touched
    assert main(["run", "example-3.6", "--stop-time", "1", "-v", "--out", str(out)]) == 0
    assert "example-3.6: stepped by the native core" in capsys.readouterr().err
    assert main(["run", "example-3.6", "--stop-time", "1", "-v", "--stepping", "python",
                 "--out", str(out)]) == 0
    assert "example-3.6: stepped by the Python master\n" in capsys.readouterr().err


def test_a_plant_fmu_of_another_tool_runs_in_the_python_master(tmp_path):
    """Another tool's FMU (C, run in a child process with a watchdog) is not the core's:
    the Python master steps the loop and says why; asked for, the core is refused."""
    from tests.cfmu.build import build_oscillator
    from tests.test_messages import PLANT_LOOP  # the oscillator's loop, to t = 100000

    build_oscillator(tmp_path, "Oscillator.fmu")
    path = tmp_path / "loop.toml"
    path.write_text(PLANT_LOOP, encoding="utf-8")
    res = api.run(path, 2.0)
    assert res.stepped_by == "python"
    assert res.stepping_note == ("plant is an FMU in a child process (another tool's), not "
                                 "a native FMU of this process")
    assert native_core.why_not_files(api.load(path), None) == (
        "plant is an FMU file of another tool (it runs in a child process)")
    with pytest.raises(ParameterError, match="plant is an FMU in a child process"):
        api.run(path, stepping="native-core")


def test_the_core_compiles_as_strict_c99(tmp_path):
    """``stepping.c`` is C99, pedantic, every warning an error, with this machine's
    system compiler (the core's own build uses the native FMUs' compiler, Zig's where it
    is here): its function pointers are cast between function pointer types only."""
    import subprocess

    from delaycomp.fmu.host import CORE_SOURCE
    from delaycomp.fmu.toolchain import system_compiler

    subprocess.run([*system_compiler(), "-std=c99", "-pedantic", "-Wall", "-Wextra",
                    "-Werror", "-O2", "-fPIC", "-shared", str(CORE_SOURCE), "-o",
                    str(tmp_path / "core.so"), "-lm"], check=True)
