"""delaycomp's FMI 3.0 FMUs in others' tools (issue 28, item 4): fmusim, FMPy, OMSimulator.

**fmusim** (Reference-FMUs v0.0.39, the FMI standard's reference importer) runs each FMI 3.0
FMU alone, its arrays given as start values (``--start-value A '0 1 0 ...'``) and its
inputs from a CSV; our master's ``FmuComponent`` drives the same FMU with the same inputs.
fmusim is in no package registry, so its runs are **recorded** (``reference/fmusim/``, by
``scripts/record_fmusim.py``: the FMU's build, the parameters, fmusim's options, the input
CSV, fmusim's output CSV or log) and every machine checks our master against the records;
where fmusim is found (``delaycomp.verify.fmusim.locate``: ``DELAYCOMP_FMUSIM``, else
``../shared/tools/fmusim``) it also runs again on the FMUs built here and must reproduce
the records and our master exactly; where it is not, those tests are skipped saying so (a
``DELAYCOMP_FMUSIM`` that names no fmusim fails them). What had to be allowed for, and why
the comparison is still exact:

- **When outputs are read.** fmusim records the outputs at ``t0`` after initialization
  (the inputs at ``t0`` set in initialization mode) and at each ``t_{k+1}`` right after
  ``fmi3DoStep``, *before* it sets the inputs of ``t_{k+1}``. Our driver (``_ours``) makes
  the same calls in the same order: the inputs of ``t0`` in initialization mode, then per
  step the inputs of ``t_k``, the step, the outputs. A direct-feedthrough output (the
  controllers' ``u``) therefore sees the same inputs in both; in a loop our master sets
  ``y(t_i)`` before it reads ``u_i`` (``docs/reference/fmi3.md``), which is a loop's
  matter, not the FMU's.
- **Input interpolation.** fmusim interpolates a continuous input linearly between CSV
  rows and sets inputs only at communication points. The CSV holds the piecewise-constant
  signal as it is: ``(t0, v0)``, then at each step edge ``(t_k, v_{k-1})`` and
  ``(t_k, v_k)``, the times written with 17 digits (``repr``), so they are the very
  doubles fmusim computes (``t0 + k h``). At ``t_k`` fmusim takes the row after the
  repeated time (without event mode) and ``v + (t - t_k) (...) = v + 0``: the value
  exactly. A repeated time is an "input event", at a regular point here: no extra step.
- **Step sizes.** fmusim steps ``t_{k+1} - t_k`` with ``t_k = t0 + k h``: ``h`` up to
  its last bits. Our driver passes the same steps, so every FMU gets the same calls. With
  our master's own steps (``h`` each) the LTI plant, the delay and both controllers give
  the same numbers bit for bit (they key their discretization and step counts on the
  grid, relative slack 1e-9); the model plant's exact ``step(x, u, h)`` takes the step it
  is given, so there it moves by round-off (measured 6.5 EPS of the state's peak; bound
  asserted: ``sum |h_k - h|`` times the largest rate, plus 4 EPS of the peak).
- **Digits.** fmusim writes ``%.16g``, which does not always round-trip a double; our
  values are printed the same way (``_at_16_digits``). fmusim run here on the FMUs built
  here is compared **exactly** (``np.array_equal``: a difference in the last bit of a
  double shows wherever it changes the 16th digit, anything larger always shows); the
  records, made on another machine, to ``RECORD_ULPS``.

**The clocked controller** cannot be driven by fmusim v0.0.39: its clock ticks at ``t0``
(shift 0), and fmusim never sets an input clock at the start time (not in initialization
mode, not in the event iteration after ``fmi3ExitInitializationMode``; an input event at
the current time is never "next"), and it sets discrete (clocked) inputs in step mode
before each step that was no event. The FMU refuses both (its messages, recorded and
asserted below): what it is built to do for a host that cannot schedule its clock.

**FMPy** (``fmpy.simulate_fmu``, FMI 3.0 co-simulation; its loop is fmusim's, in Python)
runs the delay and the controller alone from a structured numpy input: equal to our
driver's outputs bit for bit (``np.array_equal``: doubles in, doubles out) and so to
fmusim's at 16 digits. It cannot tick the clocked controller either (fmpy 0.3.32 has no
input of type Clock).

**OMSimulator** (v3.0.0-111; FMI 3.0 co-simulation is a prototype there): its Python API
cannot read an FMI 3.0 model description with structural parameters; its command line
reads and writes every array variable as one value (``nValues = 1``), which our FMUs
refuse for arrays of more than one element; an SSP of Example 3.6's four FMI 3.0 FMUs
(n = m = 1: one-element arrays) runs, equal to our master up to the first sampling
instant after ``t0``, where it reads the controller's ``u`` before it sets the
controller's ``y`` (the FMI 2.0 archive resolves that direct feedthrough and matches
throughout). The tests assert each of these, so that an OMSimulator that can is noticed.
Its CSV has 12 significant digits: 5e-12 of the signal's peak.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from delaycomp import api
from delaycomp.fmu.native import build_native_fmu
from delaycomp.orchestrator.fmu import FmuComponent
from delaycomp.verify import fmusim as fmusim_tool

from .external import Absent, need
from .roundoff import EPS, SAME_ARITHMETIC_ULPS, assert_columns_close
from .test_loopbuild import cli

pytestmark = pytest.mark.fmu

REPO = Path(__file__).resolve().parents[1]
RECORDS = REPO / "reference" / "fmusim"
_spec = importlib.util.spec_from_file_location("record_fmusim",
                                               REPO / "scripts" / "record_fmusim.py")
assert _spec is not None and _spec.loader is not None
recorder = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(recorder)
H = recorder.H  # the communication step of every case (myloop's and example 3.8's T/N)

#: the cases fmusim runs to the end (``<case>_out.csv`` holds the whole run)
RUNS = ["plant", "delay", "controller", "model_plant", "model_controller"]
#: the clocked controller's cases, which fmusim cannot run (exit 3 at t0)
CLOCKED = ["clocked_held", "clocked_ticks"]

#: A record made on another machine against our master here: the same FMU's arithmetic
#: (the same C, compiled and linked elsewhere: another libm may round ``exp`` otherwise),
#: at most ``SAME_ARITHMETIC_ULPS`` of a column's peak apart, then both printed to 16
#: digits (``%.16g``): each rounding at most half a unit of the 16th digit, 5e-16 of the
#: value, under 2.5 EPS of the peak. On the recording machine the two are equal.
RECORD_ULPS = SAME_ARITHMETIC_ULPS + 5


def _record(case: str) -> dict:
    """The JSON entry of a recorded case."""
    return json.loads((RECORDS / f"{case}.json").read_text())


def _held_inputs(case: str) -> np.ndarray:
    """The held input values of a recorded case, one row per communication point: the
    input CSV holds ``(t0, v0)`` then ``(t_k, v_{k-1}), (t_k, v_k)``, so rows 0, 2, 4, ...
    (whose times are exactly ``k H``, written with 17 digits)."""
    rec = _record(case)
    data = np.loadtxt(RECORDS / f"{case}_in.csv", delimiter=",", skiprows=1, ndmin=2)
    held = data[0::2, :1 + len(rec["inputs"])]  # without a clock column
    assert held.shape == (rec["steps"] + 1, 1 + len(rec["inputs"]))
    assert np.array_equal(held[:, 0], np.arange(rec["steps"] + 1) * rec["step"])
    # each step edge: the old values, then the new
    assert np.array_equal(data[1::2, 1:held.shape[1]], held[:-1, 1:])
    return held[:, 1:]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> dict[str, Path]:
    """The FMI 3.0 FMUs of the records, built here: delay (n = 3), LTI plant and
    controller (n = 3, m = 2), the clocked controller, example 3.8's model plant and
    controller."""
    out = tmp_path_factory.mktemp("fmi3")
    built = {case: recorder.build(_record(case)["fmu"], out) for case in RUNS}
    built["clocked"] = recorder.build(_record("clocked_held")["fmu"], out)
    assert built["clocked"] == recorder.build(_record("clocked_ticks")["fmu"], out)
    return built


@pytest.fixture(scope="module")
def fmusim_cli() -> Path:
    """fmusim, to run again; skipped saying so where it is not found and not asked for (a
    ``DELAYCOMP_FMUSIM`` that names no fmusim fails the test with how to build it)."""
    return need("fmusim", fmusim_tool.locate, (fmusim_tool.FmusimNotInstalled,),
                "running fmusim again (our master is checked against its records in "
                "reference/fmusim on every machine)")


def _ours(fmu: Path, params: dict, names: list[str], values: np.ndarray,
          outputs: list[str], fmusim_steps: bool = True, h: float = H) -> np.ndarray:
    """Our master's ``FmuComponent`` making fmusim's calls: the inputs of ``t0`` in
    initialization mode, the outputs at ``t0``; per step the inputs of ``t_k``, the step
    from ``t_k = k h`` to ``t_{k+1}`` (by ``t_{k+1} - t_k`` as fmusim steps, or by ``h`` as
    our master steps), the outputs at ``t_{k+1}``. Rows ``[t, outputs...]``."""
    steps = len(values) - 1
    comp = FmuComponent("ours", fmu)
    comp.setup(0.0, steps * h, params)
    write, read = comp.writer(names), comp.reader(outputs)
    write(list(values[0]))
    comp.initialize()
    rows = [[0.0, *read()]]
    for k in range(steps):
        write(list(values[k]))
        comp.do_step(k * h, (k + 1) * h - k * h if fmusim_steps else h)
        rows.append([(k + 1) * h, *read()])
    comp.terminate()
    return np.array(rows)


def _ours_as_recorded(fmus, case: str, fmusim_steps: bool = True) -> np.ndarray:
    """Our driver on the FMU built here, with a record's parameters and inputs."""
    rec = _record(case)
    return _ours(fmus[case], rec["parameters"], rec["inputs"], _held_inputs(case),
                 rec["outputs"], fmusim_steps, rec["step"])


def _at_16_digits(values: np.ndarray) -> np.ndarray:
    """Each double as fmusim writes it (``%.16g``) and reads back."""
    return np.vectorize(lambda v: float(f"{v:.16g}"))(values)


def _assert_same(got: np.ndarray, want: np.ndarray, what: str) -> None:
    assert got.shape == want.shape, f"{what}: shape {got.shape} against {want.shape}"
    diff = np.abs(got - want)
    assert np.array_equal(got, want), (
        f"{what}: {int(np.count_nonzero(diff))} values differ, at most {diff.max():.3g} "
        f"(relative {np.max(diff / np.maximum(np.abs(want), 1e-300)):.3g})")


def _recorded_output(case: str) -> tuple[list[str], np.ndarray]:
    return fmusim_tool.read_output(RECORDS / f"{case}_out.csv")


# -- the locator and the records --------------------------------------------------------------
def test_locate_names_the_folder_and_how_to_build_fmusim(monkeypatch, tmp_path):
    monkeypatch.setenv(fmusim_tool.ENV, str(tmp_path))
    with pytest.raises(fmusim_tool.FmusimNotInstalled) as info:
        fmusim_tool.locate()
    message = str(info.value)
    assert message.startswith(f"fmusim not found: {fmusim_tool.ENV}={tmp_path} holds no "
                              "executable bin/fmusim: build it from modelica/Reference-FMUs "
                              "v0.0.39")
    assert "build.py x86_64-linux" in message and "\n" not in message


@pytest.mark.parametrize("case", RUNS + CLOCKED)
def test_a_record_is_what_the_recorder_gives_fmusim(case):
    """Each record's options are its parameters as fmusim reads them (arrays spaced, 17
    digits), over its steps; its input CSV is the recorder's signal for its form."""
    rec = _record(case)
    spec, loop, role, inputs, outputs, steps, extra, form = recorder.CASES[case]
    assert (rec["fmu"], rec["loop"], rec["role"], rec["inputs"], rec["outputs"],
            rec["steps"], rec["step"]) == (spec, loop, role, inputs, outputs, steps, H)
    starts = [a for name, value in recorder.as_arrays(rec["parameters"]).items()
              for a in ("--start-value", name, recorder.literal(value))]
    assert rec["options"] == ["--interface-type", "cs", "--stop-time", repr(steps * H),
                              "--output-interval", repr(H), *extra, *starts]
    with open(RECORDS / f"{case}_in.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    want = recorder.input_rows(form, inputs, recorder.signals(len(inputs), steps))
    assert [r[0] for r in rows] == [r[0] for r in want] and rows[0] == want[0]
    got = np.array([[float(c) if c else np.nan for c in r[1:]] for r in rows[1:]])
    ref = np.array([[float(c) if c else np.nan for c in r[1:]] for r in want[1:]])
    assert_columns_close(got, ref, ulps=4, what=f"{case} inputs")  # sin of another libm


# -- fmusim's records against our master, on every machine ------------------------------------
@pytest.mark.parametrize("case", RUNS)
def test_our_master_reproduces_fmusims_recorded_run(fmus, case):
    """The plant (A, B, x0 arrays; u piecewise constant), the delay (3 channels, 0.36 s =
    36 steps, u0 an array), the LTI controller (myloop's T, r, tau, A, B, K), example 3.8's
    model plant and controller (its loop's parameters): fmusim's recorded CSV against our
    driver on the FMU built here, with the record's parameters and inputs, at every
    communication point, time included."""
    rec = _record(case)
    assert rec["returncode"] == 0 and rec["log"] == [], rec["log"]
    header, recorded = _recorded_output(case)
    assert header == ["time", *rec["outputs"]]
    ours = _ours_as_recorded(fmus, case)
    assert_columns_close(_at_16_digits(ours), recorded, ulps=RECORD_ULPS,
                         what=f"fmusim's record against our master, {case}")
    moving = np.ptp(ours[:, 1:], axis=0)
    assert np.all(moving > 1e-3), f"{case}: an output that does not move: {moving}"


@pytest.mark.parametrize("case", RUNS)
def test_our_masters_own_steps_give_what_fmusims_steps_give(fmus, case):
    """Our master's own steps (h each) against fmusim's ``t_{k+1} - t_k``: the same
    numbers where the FMU keys on its grid; the model plant's exact step takes the step it
    is given, so it moves by the steps' last bits: at most ``sum |h_k - h|`` times the
    largest rate, plus the rounding."""
    ours = _ours_as_recorded(fmus, case)
    master = _ours_as_recorded(fmus, case, fmusim_steps=False)
    if case != "model_plant":
        _assert_same(master, ours, f"steps t_(k+1) - t_k against h, {case}")
        return
    rec = _record(case)
    slack = np.abs(np.diff(np.arange(rec["steps"] + 1) * rec["step"]) - rec["step"]).sum()
    rate = np.abs(np.diff(ours[:, 1:], axis=0)).max(axis=0) / rec["step"]
    bound = slack * rate + 4 * EPS * np.abs(ours[:, 1:]).max(axis=0)
    assert np.all(np.abs(master - ours)[:, 1:].max(axis=0) <= bound)
    assert not np.array_equal(master, ours)  # the difference this allows for is real


def test_the_delay_in_fmusims_record_is_the_input_36_steps_late():
    """What the delay record holds: y(t_k) = u(t_{k-36}), the history u0 before (fmusim's
    numbers against the inputs it was given, at 16 digits: exactly)."""
    rec = _record("delay")
    _, got = _recorded_output("delay")
    values = _held_inputs("delay")
    u0 = recorder.as_arrays(rec["parameters"])["u0"]
    lag = round(rec["parameters"]["delay"] / rec["step"])
    assert lag == 36
    want = np.vstack([np.tile(u0, (lag, 1)), values[:-lag]])
    _assert_same(got[:, 1:], _at_16_digits(want), "delay")


# -- the clocked controller ---------------------------------------------------------------
CLOCKED_REFUSALS = {
    "clocked_held": ("fmi3SetFloat64: y1 is not allowed in step mode: it is clocked by "
                     "sample (set it in event mode, at the clock's tick)"),
    "clocked_ticks": ("fmi3DoStep from t = 0.0 is not allowed: sample ticks there (t0 + 0 T) "
                      "and did not (enter event mode, set the inputs, fmi3SetClock, "
                      "fmi3UpdateDiscreteStates, fmi3EnterStepMode)"),
}


@pytest.mark.parametrize("case", CLOCKED)
def test_fmusims_record_shows_it_cannot_tick_the_clocked_controller_at_t0(case):
    """``--event-mode-used`` and a clock column ``sample`` (1 at each t0 + i T). fmusim
    sets the CSV's y in step mode before the first step (the row at t0 is no event for
    it), which the FMU refuses (``clocked_held``); with y only in the tick rows (cells
    empty between, so nothing is set in step mode) the first step comes without the tick
    at t0 (fmusim sets no clock in initialization mode nor after
    fmi3ExitInitializationMode), which the FMU refuses too (``clocked_ticks``). Exit status
    3 (Error) and one row, t0, where u is still its start value 0 (no tick has sampled y).
    That the FMU built here still says so: the FMPy tests below."""
    rec = _record(case)
    assert rec["returncode"] == 3
    assert rec["log"] == [f"[Error] {CLOCKED_REFUSALS[case]}"]
    header, rows = _recorded_output(case)
    assert header == ["time", "u1", "u2"] and rows.tolist() == [[0.0, 0.0, 0.0]]


# -- fmusim again, where it is found ----------------------------------------------------------
@pytest.mark.parametrize("case", RUNS)
def test_fmusim_runs_each_fmu_built_here_as_recorded(fmusim_cli, fmus, case, tmp_path):
    """fmusim now, on the FMUs built here, with the record's options and input CSV: our
    driver's outputs exactly (at 16 digits), and the record to ``RECORD_ULPS``."""
    rec = _record(case)
    out = tmp_path / "out.csv"
    proc = fmusim_tool.simulate(fmus[case], rec["options"], RECORDS / f"{case}_in.csv", out,
                                cli=fmusim_cli)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    header, got = fmusim_tool.read_output(out)
    assert header == ["time", *rec["outputs"]]
    _assert_same(got, _at_16_digits(_ours_as_recorded(fmus, case)),
                 f"fmusim against our master, {case}")
    assert_columns_close(got, _recorded_output(case)[1], ulps=RECORD_ULPS,
                         what=f"fmusim against its record, {case}")


@pytest.mark.parametrize("case", CLOCKED)
def test_fmusim_still_cannot_tick_the_clocked_controller_built_here(fmusim_cli, fmus, case,
                                                                   tmp_path):
    rec = _record(case)
    out = tmp_path / "out.csv"
    proc = fmusim_tool.simulate(fmus["clocked"], rec["options"], RECORDS / f"{case}_in.csv",
                                out, cli=fmusim_cli)
    assert (proc.returncode, (proc.stdout + proc.stderr).strip().splitlines()) == (
        rec["returncode"], rec["log"])
    assert fmusim_tool.read_output(out)[1].tolist() == [[0.0, 0.0, 0.0]]


# -- FMPy --------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", ["delay", "controller"])
def test_fmpy_simulate_fmu_agrees_with_our_master_and_fmusims_record(fmus, case):
    """``fmpy.simulate_fmu`` (FMI 3.0 co-simulation) with the inputs as a structured numpy
    array (the rows of the record's input CSV): our driver's doubles exactly, fmusim's
    recorded CSV at 16 digits (to ``RECORD_ULPS``)."""
    from fmpy import simulate_fmu

    rec = _record(case)
    data = np.loadtxt(RECORDS / f"{case}_in.csv", delimiter=",", skiprows=1, ndmin=2)
    signal = np.array([tuple(row) for row in data],
                      dtype=[("time", float)] + [(n, float) for n in rec["inputs"]])
    res = simulate_fmu(str(fmus[case]), fmi_type="CoSimulation", start_time=0.0,
                       stop_time=rec["steps"] * rec["step"], output_interval=rec["step"],
                       input=signal, start_values=recorder.as_arrays(rec["parameters"]),
                       output=rec["outputs"])
    got = np.column_stack([res["time"], *(res[n] for n in rec["outputs"])])
    _assert_same(got, _ours_as_recorded(fmus, case), f"fmpy against our master, {case}")
    assert_columns_close(_at_16_digits(got), _recorded_output(case)[1], ulps=RECORD_ULPS,
                         what=f"fmusim's record against fmpy, {case}")


def test_fmpy_simulate_fmu_cannot_tick_the_clocked_controller(fmus):
    """fmpy 0.3.32's input signals know no Clock variable (a ``sample`` column: KeyError
    'Clock' while it reads them); without it, it sets the clocked y in step mode, which the
    FMU refuses as fmusim's record says (``clocked_held``); with no inputs at all it steps
    from t0 without the tick there, refused as in fmusim's ``clocked_ticks``."""
    from fmpy import simulate_fmu
    from fmpy.fmi1 import FMICallException

    rec = _record("clocked_held")
    h = rec["step"]
    rows = [(k * h, *v, float(k % recorder.TICK == 0))
            for k, v in enumerate(_held_inputs("clocked_held"))]
    signal = np.array(rows, dtype=[(n, float) for n in ("time", "y1", "y2", "y3", "sample")])
    run = dict(fmi_type="CoSimulation", stop_time=rec["steps"] * h, output_interval=h,
               use_event_mode=True, start_values=recorder.as_arrays(rec["parameters"]))
    with pytest.raises(KeyError, match="'Clock'"):
        simulate_fmu(str(fmus["clocked"]), input=signal, **run)
    messages: list[bytes] = []
    for case, given in (("clocked_held", signal[["time", "y1", "y2", "y3"]]),
                        ("clocked_ticks", None)):
        messages.clear()
        call = "fmi3SetFloat64" if case == "clocked_held" else "fmi3DoStep"
        with pytest.raises(FMICallException, match=f"{call} failed with status 3"):
            simulate_fmu(str(fmus["clocked"]), input=given,
                         logger=lambda *args: messages.append(args[-1]), **run)
        assert [f"[Error] {messages[-1].decode()}"] == _record(case)["log"]


# -- OMSimulator -------------------------------------------------------------------------------
def test_omsimulators_python_api_cannot_read_an_fmi3_model_description(oms, fmus, tmp_path):
    """OMSimulator's Python API parses the model description itself and knows no
    ``causality="structuralParameter"`` (every FMI 3.0 FMU with arrays has one)."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from OMSimulator import SSP; "
            "SSP().addResource(sys.argv[2])")
    proc = subprocess.run([sys.executable, "-c", code, str(oms.package_dir or tmp_path),
                           str(fmus["plant"])], capture_output=True, text=True, cwd=tmp_path,
                          timeout=120)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines()[-1] == "KeyError: 'structuralParameter'"


def _no_cli() -> None:
    raise Absent("this OMSimulator install has no command line")


def _oms_cli(oms, tmp: Path, *args: str) -> subprocess.CompletedProcess:
    if oms.cli is None:
        need("omsimulator", _no_cli, what="its command line")
    return subprocess.run(["env", "-i", str(oms.cli), *args], capture_output=True, text=True,
                          cwd=tmp, timeout=300)


def test_omsimulators_command_line_reads_an_array_as_one_value(oms, fmus, tmp_path):
    """The plant (n = 3, m = 2) alone in OMSimulator's command line: it asks for each
    array with nValues = 1, our FMU refuses (logged as an error), and OMSimulator still
    exits 0 with the arrays unread."""
    proc = _oms_cli(oms, tmp_path, "--mode=cs", "--stopTime=0.1", "--resultFile=out.csv",
                    str(fmus["plant"]))
    assert proc.returncode == 0
    errors = [ln.strip() for ln in (proc.stdout + proc.stderr).splitlines()
              if ln.startswith("error:")]
    assert errors == [
        f"error:   [fmi3logger] [fmi3Error] logStatusError: fmi3GetFloat64: nValues = 1 is "
        f"not allowed: must be {count} (the elements of the variables named)"
        for count in (9, 6, 3)]


def _fmi3_archive(fmi2_ssp: Path, out: Path, fmu_dir: Path) -> Path:
    """Example 3.6's archive with its three FMUs swapped for their FMI 3.0 builds (n = m =
    1) and the parameters renamed to the arrays (``A[1,1]`` -> ``A``): an SSP of four FMI
    3.0 FMUs (``ssp --fmi 3`` is issue 28, item 5)."""
    with zipfile.ZipFile(fmi2_ssp) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            name = info.filename
            if name.endswith(".fmu"):
                kind, config = {"DelaycompDelay.fmu": ("delay", {"n": 1}),
                        "DelaycompPlantLTI.fmu": ("plant", {"n": 1, "m": 1}),
                        "DelaycompControllerLTI.fmu": ("controller", {"n": 1, "m": 1})}[
                            Path(name).name]
                dst.write(build_native_fmu(kind, fmu_dir, config, fmi=3), name)
            elif name.endswith((".ssd", ".ssv")):
                text = src.read(name).decode("utf-8")
                dst.writestr(name, re.sub(r'name="(\w+)\[1(?:,1)?\]"', r'name="\1"', text))
            else:
                dst.writestr(info, src.read(name))
    return out


def _oms_columns(path: Path, ident: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Times and the columns ``plant.x``, ``plant.u``, ``controller.u`` of an OMSimulator
    CSV (one row per time: the first, before the exchange, as every other row)."""
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    header = [h.strip() for h in rows[0]]
    data = np.array(rows[1:], dtype=float)
    data = data[np.r_[True, data[1:, 0] != data[:-1, 0]]]  # the stop time comes twice
    return data[:, 0], {n: data[:, header.index(f"{ident}.{ident}.{n}")]
                        for n in ("plant.x", "plant.u", "controller.u")}


def test_omsimulator_runs_an_fmi3_loop_right_until_its_first_tick_after_t0(oms, tmp_path):
    """Example 3.6 (n = m = 1, one-element arrays) as an SSP of four FMI 3.0 FMUs in
    OMSimulator's command line (``--emitEvents=false``: one row per step, recorded before
    the step's exchange, so an input column shows the value set at the step before).

    The plant's state equals our master's FMI 3.0 run (12 digits) up to t = 1, the first
    sampling instant after t0. There the plant gets the controller's u as OMSimulator read
    it before setting the controller's y: computed from the measurement of t = 1 - h, not
    our master's u_1; from t = 1.01 on the runs part. The FMI 2.0 archive (the same loop,
    the FMI 2.0 twins) resolves that direct feedthrough and matches throughout."""
    stop, tick = 3.0, round(1.0 / H)  # example 3.6: T = 1
    fmi2 = tmp_path / "example_3_6.ssp"
    proc = cli("ssp", "example-3.6", "--native", "--out", fmi2)
    assert proc.returncode == 0, proc.stderr
    fmi3 = _fmi3_archive(fmi2, tmp_path / "example_3_6_fmi3.ssp", tmp_path / "fmus")
    ours = api.run("example-3.6", fmi=3, stop_time=stop, fmu_dir=tmp_path / "cache")
    x_ours = ours.data[:, ours.names.index("plant.x")]
    u_ours = ours.data[:, ours.names.index("controller.u")]
    runs = {}
    for label, archive in (("fmi2", fmi2), ("fmi3", fmi3)):
        result = tmp_path / f"{label}.csv"
        proc = _oms_cli(oms, tmp_path, "--emitEvents=false", f"--stopTime={stop!r}",
                        f"--resultFile={result.name}", str(archive))
        assert proc.returncode == 0 and "error:" not in proc.stdout + proc.stderr, (
            proc.stdout + proc.stderr)
        times, runs[label] = _oms_columns(result, "example_3_6")
        assert np.abs(times - ours.times).max() <= 5e-12 * stop
    tol_x, tol_u = 5e-12 * np.abs(x_ours).max(), 5e-12 * np.abs(u_ours).max()
    two, three = runs["fmi2"], runs["fmi3"]
    assert np.abs(two["plant.x"] - x_ours).max() <= tol_x
    assert np.abs(two["plant.u"][1:] - u_ours[:-1]).max() <= tol_u  # set a step before
    assert np.abs(three["plant.x"] - x_ours)[:tick + 1].max() <= tol_x
    assert np.abs(three["plant.u"][1:tick + 1] - u_ours[:tick]).max() <= tol_u
    # at t = 1: the u read before the controller's y was set (the one both record there)
    stale = three["controller.u"][tick]
    assert abs(two["controller.u"][tick] - stale) <= tol_u
    assert abs(stale - u_ours[tick]) > 1e-2 * np.abs(u_ours).max(), (
        "OMSimulator now resolves the controller's feedthrough at its ticks in FMI 3.0: "
        "compare the whole run and update docs/reference/fmi3.md")
    assert abs(three["plant.u"][tick + 1] - stale) <= tol_u
    assert abs(two["plant.u"][tick + 1] - u_ours[tick]) <= tol_u
    assert np.abs(three["plant.x"][tick + 1] - x_ours[tick + 1]) > 1e-4 * np.abs(x_ours).max()
