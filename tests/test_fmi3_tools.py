"""delaycomp's FMI 3.0 FMUs in others' tools (issue 28, item 4): fmusim, FMPy, OMSimulator.

**fmusim** (Reference-FMUs v0.0.39, the FMI standard's reference importer; found by
``delaycomp.verify.fmusim.locate``: ``DELAYCOMP_FMUSIM``, else ``../shared/tools/fmusim``;
missing, these tests fail with how to build it) runs each FMI 3.0 FMU alone, its arrays
given as start values (``--start-value A '0 1 0 ...'``) and its inputs from a CSV; our
master's ``FmuComponent`` drives the same FMU with the same inputs. What had to be allowed
for, and why the comparison is still exact:

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
  values are printed the same way (``_at_16_digits``) and then compared **exactly**
  (``np.array_equal``): a difference in the last bit of a double shows wherever it
  changes the 16th digit, anything larger always shows.

**The clocked controller** cannot be driven by fmusim v0.0.39: its clock ticks at ``t0``
(shift 0), and fmusim never sets an input clock at the start time (not in initialization
mode, not in the event iteration after ``fmi3ExitInitializationMode``; an input event at
the current time is never "next"), and it sets discrete (clocked) inputs in step mode
before each step that was no event. The FMU refuses both (its messages, asserted below):
what it is built to do for a host that cannot schedule its clock.

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
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from delaycomp import api
from delaycomp.fmu.native import build_native_fmu, build_native_model
from delaycomp.orchestrator.fmu import FmuComponent
from delaycomp.paper import models as paper_models
from delaycomp.verify import fmusim as fmusim_tool

from .roundoff import EPS
from .test_loopbuild import cli

pytestmark = pytest.mark.fmu

REPO = Path(__file__).resolve().parents[1]
MYLOOP = REPO / "docs" / "examples" / "myloop.toml"
EXAMPLE_3_8 = Path(paper_models.__file__).parent / "example_3_8.py"
H = 0.01  # the communication step of every run here (myloop's and example 3.8's T/N)


def _fmusim_cli() -> Path:
    """fmusim, or a failed test saying how to build it (never a skip)."""
    try:
        return fmusim_tool.locate()
    except fmusim_tool.FmusimNotInstalled as exc:
        pytest.fail(str(exc), pytrace=False)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> dict[str, Path]:
    """The FMI 3.0 FMUs: delay (n = 3), LTI plant and controller (n = 3, m = 2), the
    clocked controller, example 3.8's model plant and controller."""
    out = tmp_path_factory.mktemp("fmi3")
    built = {kind: build_native_fmu(kind, out, config, fmi=3) for kind, config in {
        "delay": {"n": 3}, "plant": {"n": 3, "m": 2}, "controller": {"n": 3, "m": 2}}.items()}
    built["clocked"] = build_native_fmu("controller", out / "clocked",
                                        {"n": 3, "m": 2, "clocked": True}, fmi=3)
    model = build_native_model(EXAMPLE_3_8, out / "model", fmi=3)
    built["model_plant"], built["model_controller"] = model[:2]
    return built


def _params(source, role: str) -> dict:
    """The parameters a loop gives ``role`` (our master's names: ``A[2,1]``, ...)."""
    return dict(api.load(source).parameters()[role])


def _as_arrays(params: dict) -> dict:
    """``A[1,1] .. A[3,3]`` (row-major, as a loop lists them) -> ``A: [9 values]``."""
    out: dict = {}
    for name, value in params.items():
        element = re.fullmatch(r"(\w+)\[[\d,]+\]", name)
        if element:
            out.setdefault(element.group(1), []).append(float(value))
        else:
            out[name] = value
    return out


def _literal(value) -> str:
    """A start value as fmusim reads it: 17 digits, an array's elements spaced."""
    if isinstance(value, list):
        return " ".join(repr(float(v)) for v in value)
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)


def _signals(names: list[str], steps: int) -> np.ndarray:
    """(steps + 1) x len(names) values, one row per communication point, held over the
    step that starts there: smooth, different per channel, none exactly representable."""
    k = np.arange(steps + 1)[:, None]
    j = np.arange(len(names))[None, :]
    return np.sin(0.37 * (j + 1) * k * H + 0.3 * j) + 0.1 * (j - 1) + k * H / 7


def _piecewise_rows(values: np.ndarray) -> list[tuple[float, np.ndarray]]:
    """The held signal as CSV rows: ``(t0, v0)``, then ``(t_k, v_{k-1}), (t_k, v_k)``."""
    rows = [(0.0, values[0])]
    for k in range(1, len(values)):
        rows += [(k * H, values[k - 1]), (k * H, values[k])]
    return rows


def _run_fmusim(fmu: Path, tmp: Path, starts: dict, names: list[str], values: np.ndarray,
                extra: tuple[str, ...] = (), clock: str | None = None
                ) -> tuple[list[str], np.ndarray, subprocess.CompletedProcess]:
    """fmusim's co-simulation of ``fmu`` alone over ``len(values) - 1`` steps of ``H``:
    the header and the numbers of its output CSV, and the process."""
    steps = len(values) - 1
    infile, outfile = tmp / f"{fmu.stem}_in.csv", tmp / f"{fmu.stem}_out.csv"
    with open(infile, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["time", *names] + ([clock] if clock else []))
        for t, v in _piecewise_rows(values):
            writer.writerow([repr(t), *(repr(float(x)) for x in v)] + (
                [int(round(t / H) % 20 == 0)] if clock else []))  # T = 20 H
    argv = [str(_fmusim_cli()), "--interface-type", "cs", "--stop-time", repr(steps * H),
            "--output-interval", repr(H), "--input-file", str(infile), "--output-file",
            str(outfile), *extra]
    for name, value in starts.items():
        argv += ["--start-value", name, _literal(value)]
    proc = subprocess.run([*argv, str(fmu)], capture_output=True, text=True, timeout=120)
    with open(outfile, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], np.array(rows[1:], dtype=float).reshape(len(rows) - 1, len(rows[0])), proc


def _ours(fmu: Path, params: dict, names: list[str], values: np.ndarray,
          outputs: list[str], fmusim_steps: bool = True) -> np.ndarray:
    """Our master's ``FmuComponent`` making fmusim's calls: the inputs of ``t0`` in
    initialization mode, the outputs at ``t0``; per step the inputs of ``t_k``, the step
    from ``t_k = k H`` to ``t_{k+1}`` (by ``t_{k+1} - t_k`` as fmusim steps, or by ``H`` as
    our master steps), the outputs at ``t_{k+1}``. Rows ``[t, outputs...]``."""
    steps = len(values) - 1
    comp = FmuComponent("ours", fmu)
    comp.setup(0.0, steps * H, params)
    write, read = comp.writer(names), comp.reader(outputs)
    write(list(values[0]))
    comp.initialize()
    rows = [[0.0, *read()]]
    for k in range(steps):
        write(list(values[k]))
        comp.do_step(k * H, (k + 1) * H - k * H if fmusim_steps else H)
        rows.append([(k + 1) * H, *read()])
    comp.terminate()
    return np.array(rows)


def _at_16_digits(values: np.ndarray) -> np.ndarray:
    """Each double as fmusim writes it (``%.16g``) and reads back."""
    return np.vectorize(lambda v: float(f"{v:.16g}"))(values)


def _assert_same(got: np.ndarray, want: np.ndarray, what: str) -> None:
    assert got.shape == want.shape, f"{what}: shape {got.shape} against {want.shape}"
    diff = np.abs(got - want)
    assert np.array_equal(got, want), (
        f"{what}: {int(np.count_nonzero(diff))} values differ, at most {diff.max():.3g} "
        f"(relative {np.max(diff / np.maximum(np.abs(want), 1e-300)):.3g})")


# -- the locator ------------------------------------------------------------------------------
def test_fmusim_is_found_or_named_with_how_to_build_it(monkeypatch, tmp_path):
    assert _fmusim_cli().name == "fmusim"
    monkeypatch.setenv(fmusim_tool.ENV, str(tmp_path))
    with pytest.raises(fmusim_tool.FmusimNotInstalled) as info:
        fmusim_tool.locate()
    message = str(info.value)
    assert message.startswith(f"fmusim not found: {fmusim_tool.ENV}={tmp_path} holds no "
                              "executable bin/fmusim: build it from modelica/Reference-FMUs "
                              "v0.0.39")
    assert "build.sh" in message and "\n" not in message


# -- fmusim runs each FMU alone -----------------------------------------------------------
CASES = {
    # kind: (loop, role, inputs, outputs, steps)
    "plant": (MYLOOP, "plant", ["u1", "u2"], ["x1", "x2", "x3"], 300),
    "delay": (MYLOOP, "meas_delay", ["u1", "u2", "u3"], ["y1", "y2", "y3"], 150),
    "controller": (MYLOOP, "controller", ["y1", "y2", "y3"], ["u1", "u2"], 300),
    "model_plant": ("example-3.8", "plant", ["u"], ["x1", "x2"], 300),
    "model_controller": ("example-3.8", "controller", ["y_x1", "y_x2"], ["u"], 300),
}


def _case(fmus, kind: str, tmp: Path):
    """fmusim's and our driver's runs of one FMU: (fmusim's rows, ours, header, process)."""
    source, role, inputs, outputs, steps = CASES[kind]
    params = _params(source, role)
    values = _signals(inputs, steps)
    header, got, proc = _run_fmusim(fmus[kind], tmp, _as_arrays(params), inputs, values)
    ours = _ours(fmus[kind], params, inputs, values, outputs)
    return got, ours, header, proc


@pytest.mark.parametrize("kind", list(CASES))
def test_fmusim_runs_each_fmu_alone_as_our_master_does(fmus, kind, tmp_path):
    """The plant (A, B, x0 arrays; u piecewise constant), the delay (3 channels, 0.36 s =
    36 steps, u0 an array), the LTI controller (myloop's T, r, tau, A, B, K), example 3.8's
    model plant and controller (its loop's parameters): fmusim's CSV equals our outputs
    at 16 digits, time included, at every communication point."""
    got, ours, header, proc = _case(fmus, kind, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert header == ["time", *CASES[kind][3]]
    _assert_same(got, _at_16_digits(ours), f"fmusim against our master, {kind}")
    moving = np.ptp(ours[:, 1:], axis=0)
    assert np.all(moving > 1e-3), f"{kind}: an output that does not move: {moving}"
    # our master's own steps (H each): the same numbers where the FMU keys on its grid;
    # the model plant's exact step takes the step it is given, so it moves by the steps'
    # last bits: at most sum |h_k - H| times the largest rate, plus the rounding
    source, role, inputs, outputs, steps = CASES[kind]
    master = _ours(fmus[kind], _params(source, role), inputs, _signals(inputs, steps),
                   outputs, fmusim_steps=False)
    if kind != "model_plant":
        _assert_same(master, ours, f"steps t_(k+1) - t_k against H, {kind}")
        return
    slack = np.abs(np.diff(np.arange(steps + 1) * H) - H).sum()
    rate = np.abs(np.diff(ours[:, 1:], axis=0)).max(axis=0) / H
    bound = slack * rate + 4 * EPS * np.abs(ours[:, 1:]).max(axis=0)
    assert np.all(np.abs(master - ours)[:, 1:].max(axis=0) <= bound)
    assert not np.array_equal(master, ours)  # the difference this allows for is real


def test_the_delay_in_fmusim_is_the_input_36_steps_late(fmus, tmp_path):
    """What the delay run compares: y(t_k) = u(t_{k-36}), the history u0 before."""
    got, _, _, _ = _case(fmus, "delay", tmp_path)
    values = _signals(["u1", "u2", "u3"], 150)
    u0 = _as_arrays(_params(MYLOOP, "meas_delay"))["u0"]
    want = np.vstack([np.tile(u0, (36, 1)), values[:-36]])
    _assert_same(got[:, 1:], _at_16_digits(want), "delay")


# -- the clocked controller ---------------------------------------------------------------
@pytest.mark.parametrize("empty_between_ticks, message", [
    (False, "[Error] fmi3SetFloat64: y1 is not allowed in step mode: it is clocked by sample "
            "(set it in event mode, at the clock's tick)"),
    (True, "[Error] fmi3DoStep from t = 0.0 is not allowed: sample ticks there (t0 + 0 T) "
           "and did not (enter event mode, set the inputs, fmi3SetClock, "
           "fmi3UpdateDiscreteStates, fmi3EnterStepMode)"),
])
def test_fmusim_cannot_tick_the_clocked_controller_at_t0(fmus, tmp_path, empty_between_ticks,
                                                         message):
    """``--event-mode-used`` and a clock column ``sample`` (1 at each t0 + i T). fmusim
    sets the CSV's y in step mode before the first step (the row at t0 is no event for
    it), which the FMU refuses; with y only in the tick rows (cells empty between, so
    nothing is set in step mode) the first step comes without the tick at t0 (fmusim sets
    no clock in initialization mode nor after fmi3ExitInitializationMode), which the FMU
    refuses too. Exit status 3 (Error) and one row, t0, where u is still its start value
    0 (no tick has sampled y)."""
    params = _as_arrays(_params(MYLOOP, "controller"))
    values = _signals(["y1", "y2", "y3"], 40)
    if empty_between_ticks:  # a first row without values, then the ticks' rows only
        infile = tmp_path / "in.csv"
        lines = ["time,y1,y2,y3,sample", "0.0,,,,0"]
        for k in range(41):
            cells = ",".join(repr(float(v)) for v in values[k]) if k % 20 == 0 else ",,"
            lines.append(f"{k * H!r},{cells},{int(k % 20 == 0)}")
        infile.write_text("\n".join(lines) + "\n")
        argv = [str(_fmusim_cli()), "--interface-type", "cs", "--event-mode-used",
                "--stop-time", "0.4", "--output-interval", repr(H), "--input-file",
                str(infile), "--output-file", str(tmp_path / "out.csv")]
        for name, value in params.items():
            argv += ["--start-value", name, _literal(value)]
        proc = subprocess.run([*argv, str(fmus["clocked"])], capture_output=True, text=True,
                              timeout=120)
        rows = np.loadtxt(tmp_path / "out.csv", delimiter=",", skiprows=1, ndmin=2)
    else:
        _, rows, proc = _run_fmusim(fmus["clocked"], tmp_path, params, ["y1", "y2", "y3"],
                                    values, extra=("--event-mode-used",), clock="sample")
    assert proc.returncode == 3
    assert proc.stdout.strip().splitlines() == [message]
    assert rows.tolist() == [[0.0, 0.0, 0.0]]


# -- FMPy --------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["delay", "controller"])
def test_fmpy_simulate_fmu_agrees_with_our_master_and_fmusim(fmus, kind, tmp_path):
    """``fmpy.simulate_fmu`` (FMI 3.0 co-simulation) with the inputs as a structured numpy
    array (the same held rows as fmusim's CSV): our driver's doubles exactly, fmusim's
    CSV at 16 digits."""
    from fmpy import simulate_fmu

    source, role, inputs, outputs, steps = CASES[kind]
    params = _params(source, role)
    values = _signals(inputs, steps)
    signal = np.array([(t, *v) for t, v in _piecewise_rows(values)],
                      dtype=[("time", float)] + [(n, float) for n in inputs])
    res = simulate_fmu(str(fmus[kind]), fmi_type="CoSimulation", start_time=0.0,
                       stop_time=steps * H, output_interval=H, input=signal,
                       start_values=_as_arrays(params), output=outputs)
    got = np.column_stack([res["time"], *(res[n] for n in outputs)])
    ours = _ours(fmus[kind], params, inputs, values, outputs)
    _assert_same(got, ours, f"fmpy against our master, {kind}")
    fmusim_rows, _, _, proc = _case(fmus, kind, tmp_path)
    assert proc.returncode == 0, proc.stdout
    _assert_same(fmusim_rows, _at_16_digits(got), f"fmusim against fmpy, {kind}")


def test_fmpy_simulate_fmu_cannot_tick_the_clocked_controller(fmus):
    """fmpy 0.3.32's input signals know no Clock variable (a ``sample`` column: KeyError
    'Clock' while it reads them); without it, it sets the clocked y in step mode, which the
    FMU refuses, as in fmusim."""
    from fmpy import simulate_fmu
    from fmpy.fmi1 import FMICallException

    rows = [(k * H, *v, float(k % 20 == 0))
            for k, v in enumerate(_signals(["y1", "y2", "y3"], 40))]
    signal = np.array(rows, dtype=[(n, float) for n in ("time", "y1", "y2", "y3", "sample")])
    run = dict(fmi_type="CoSimulation", stop_time=0.4, output_interval=H, use_event_mode=True,
               start_values=_as_arrays(_params(MYLOOP, "controller")))
    with pytest.raises(KeyError, match="'Clock'"):
        simulate_fmu(str(fmus["clocked"]), input=signal, **run)
    messages: list[bytes] = []
    with pytest.raises(FMICallException, match="fmi3SetFloat64 failed with status 3"):
        simulate_fmu(str(fmus["clocked"]), input=signal[["time", "y1", "y2", "y3"]],
                     logger=lambda *args: messages.append(args[-1]), **run)
    assert messages[-1].decode() == (
        "fmi3SetFloat64: y1 is not allowed in step mode: it is clocked by sample (set it in "
        "event mode, at the clock's tick)")


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


def _oms_cli(oms, tmp: Path, *args: str) -> subprocess.CompletedProcess:
    if oms.cli is None:
        pytest.skip("this OMSimulator install has no command line")
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
