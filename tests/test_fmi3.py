"""FMI 3.0 native FMUs (issue 28, items 1 and 2).

``build --fmi 3`` compiles the same C models as the FMI 2.0 twins behind the FMI 3.0 layer
(``fmus/native/fmi3.c``): the matrices and vectors as arrays sized by structural
parameters, the other variables with their FMI 2.0 value references. Our master runs them
through fmpy's FMI 3.0 classes (``delaycomp.orchestrator.fmu``), alone or beside another
tool's FMI 2.0 plant.

Tolerances: the FMI 3.0 and FMI 2.0 loops run the same C maths on the same inputs in the
same order, so they are compared bit for bit (``np.array_equal``); fmpy's own simulation
of the plant alone against the exact flow ``expm(A t) x0``: 1e-13 of the state's size
(the Pade approximant of ``expm`` and ten products, a few ulps each).
"""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest

from delaycomp import api
from delaycomp.fmu.native import MODEL_KINDS, native_fmu_path
from delaycomp.fmu.toolchain import system_compiler
from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused
from delaycomp.paper import models as paper_models

from .test_loopbuild import cli, write_loop
from .tiers import tiered

pytestmark = pytest.mark.fmu

REPO = Path(__file__).resolve().parents[1]
MYLOOP = REPO / "docs" / "examples" / "myloop.toml"
EXAMPLE_3_8 = Path(paper_models.__file__).parent / "example_3_8.py"
DIMS = {"delay": {"n": 3}, "plant": {"n": 3, "m": 2}, "controller": {"n": 3, "m": 2}}


@pytest.fixture(scope="module")
def built() -> dict[tuple[str, int], Path]:
    """(kind, fmi) -> the FMU: delay (n = 3), LTI plant and controller (n = 3, m = 2) and
    example 3.8's model plant and controller, for FMI 2.0 and 3.0; from the session's
    native build cache, which the loops run here share."""
    out: dict[tuple[str, int], Path] = {}
    for fmi in (2, 3):
        for kind, config in DIMS.items():
            out[kind, fmi] = native_fmu_path(kind, config, fmi=fmi)
        for kind in MODEL_KINDS:
            out[kind, fmi] = native_fmu_path(kind, {"model": str(EXAMPLE_3_8)}, fmi=fmi)
    return out


def _root(fmu: Path) -> ET.Element:
    with zipfile.ZipFile(fmu) as zf:
        return ET.fromstring(zf.read("modelDescription.xml"))


# -- item 1: the FMUs ----------------------------------------------------------------------
@pytest.mark.parametrize("kind", [*DIMS, "model_plant", "model_controller"])
def test_each_fmi3_fmu_passes_fmpy_validate(built, kind):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(built[kind, 3])) == []
    assert _root(built[kind, 3]).get("fmiVersion") == "3.0"


def test_matrices_are_arrays_sized_by_structural_parameters(built):
    """The controller (n = 3, m = 2): A n x n, B n x m, K m x n, u0 m, each one Float64
    whose Dimensions name the UInt64 structural parameters n and m; its start values all
    its elements, row-major."""
    variables = {v.get("name"): v for v in _root(built["controller", 3]).find("ModelVariables")}
    n, m = variables["n"], variables["m"]
    for sp, value in ((n, "3"), (m, "2")):
        assert (sp.tag, sp.get("causality"), sp.get("variability"), sp.get("start")) == (
            "UInt64", "structuralParameter", "fixed", value)
    shapes = {"A": (n, n), "B": (n, m), "K": (m, n), "u0": (m,)}
    for name, dims in shapes.items():
        var = variables[name]
        assert var.tag == "Float64"
        assert [d.get("valueReference") for d in var.findall("Dimension")] == [
            d.get("valueReference") for d in dims]
        assert len(var.get("start").split()) == np.prod([int(d.get("start")) for d in dims])
    assert not [name for name in variables if "[" in name]  # no scalar element left
    assert [v.get("name") for v in variables.values() if v.get("causality") == "independent"
            ] == ["time"]


@pytest.mark.parametrize("kind", [*DIMS, "model_plant", "model_controller"])
def test_every_other_variable_keeps_its_fmi2_value_reference(built, kind):
    """Scalars (parameters, inputs, outputs) keep name and value reference; an array's
    value reference is its first element's; the outputs' dependencies are the same inputs."""
    two = {sv.get("name"): sv for sv in _root(built[kind, 2]).find("ModelVariables")}
    three = {v.get("name"): v for v in _root(built[kind, 3]).find("ModelVariables")}
    for name, sv in two.items():
        base = name.split("[")[0]
        if "[" in name:
            assert int(three[base].get("valueReference")) <= int(sv.get("valueReference"))
            if name.endswith("[1]") or name.endswith("[1,1]"):
                assert three[base].get("valueReference") == sv.get("valueReference")
        else:
            assert three[name].get("valueReference") == sv.get("valueReference"), name
            assert three[name].get("causality") == sv.get("causality")
    root2, root3 = _root(built[kind, 2]), _root(built[kind, 3])
    ordered = list(root2.find("ModelVariables"))
    deps2 = {ordered[int(u.get("index")) - 1].get("valueReference"):
             sorted(ordered[int(i) - 1].get("valueReference")
                    for i in (u.get("dependencies") or "").split())
             for u in root2.find("ModelStructure/Outputs")}
    deps3 = {u.get("valueReference"): sorted((u.get("dependencies") or "").split())
             for u in root3.find("ModelStructure").findall("Output")}
    assert deps3 == deps2


@pytest.mark.parametrize("kind", ["controller", "model_controller"])
def test_the_sources_compile_as_build_description_lists_them(built, kind, tmp_path):
    """``sources/buildDescription.xml`` lists the C files an importer compiles (C99,
    pedantic, every warning an error; the system compiler, as an importer's: clang 15 and
    later, Zig's among them, call the FMI 3.0 headers' own ``()`` callback types
    non-prototypes under -pedantic) into a library that exports the FMI 3.0 functions."""
    with zipfile.ZipFile(built[kind, 3]) as zf:
        zf.extractall(tmp_path)
    desc = ET.parse(tmp_path / "sources" / "buildDescription.xml").getroot()
    files = [f.get("name") for f in desc.iter("SourceFile")]
    assert "fmi3.c" in files and "fmi2.c" not in files
    assert sorted(files) == sorted(p.name for p in (tmp_path / "sources").glob("*.c"))
    lib = tmp_path / "lib.so"
    subprocess.run([*system_compiler(), "-std=c99", "-pedantic", "-Wall", "-Wextra",
                    "-Werror", "-O2", "-fPIC", "-shared", "-I", str(tmp_path / "sources"),
                    "-o", str(lib),
                    *(str(tmp_path / "sources" / f) for f in files), "-lm"], check=True)
    symbols = subprocess.run(["nm", "-D", "--defined-only", str(lib)], capture_output=True,
                             text=True, check=True).stdout
    for fn in ("fmi3InstantiateCoSimulation", "fmi3DoStep", "fmi3GetFloat64",
               "fmi3SerializeFMUState", "fmi3EnterConfigurationMode"):
        assert fn in symbols
    assert (tmp_path / "binaries" / "x86_64-linux").is_dir()
    assert not (tmp_path / "binaries" / "linux64").exists()


# -- item 2: our master runs them ---------------------------------------------------------
@pytest.mark.parametrize("source, sets", tiered([
    (str(MYLOOP), {}),  # a user's loop file, n = 3, m = 2
    ("example-3.8", {}),  # a model file's plant and controller, translated to C
    ("example-3.6", {"r": 0.3, "u0": 4}),
    ("corollary-3.7", {}),
], 2))
def test_an_fmi3_loop_equals_its_fmi2_twin_bit_for_bit(source, sets, tmp_path):
    two = api.run(source, sets=sets, fmus="native")
    three = api.run(source, sets=sets, fmi=3)
    assert three.names == two.names
    assert np.array_equal(three.times, two.times)
    assert np.array_equal(three.data, two.data)
    chosen, _ = api.choose_fmus(source if not sets else api.load(source, sets=sets),
                                fmi=3)
    assert {_root(p).get("fmiVersion") for p in chosen.values()} == {"3.0"}


def test_an_fmi3_controller_runs_beside_another_tools_fmi2_plant(tmp_path):
    """A plant FMU of another tool (FMI 2.0, C, RK4 inside: tests/cfmu) with delaycomp's
    delays and controller as FMI 3.0 FMUs: the run equals the one with their FMI 2.0 twins
    bit for bit (the same plant binary, the same C maths)."""
    from delaycomp.system.loop import FmuFile
    from tests.cfmu.build import build_oscillator

    from .test_plant_fmu import LOOP

    build_oscillator(tmp_path)
    loop = api.load(write_loop(tmp_path, LOOP, "osc"))
    three = api.run(loop, fmi=3)
    twins = {i.name: native_fmu_path(*i.source.build_key())
             for i in loop.instances if not isinstance(i.source, FmuFile)}
    two = api.run(loop, fmus=twins)
    assert np.array_equal(three.data, two.data) and three.names == two.names
    assert np.max(np.abs(three.data)) > 0.1  # a loop that moves
    chosen, _ = api.choose_fmus(loop, fmi=3)
    assert set(chosen) == {"meas_delay", "controller", "input_delay"}  # not the plant


def _controller(path: Path, name: str = "c") -> FmuComponent:
    comp = FmuComponent(name, path)
    comp.setup(0.0, 10.0, {
        "T": 0.2, "r": 0.36, "tau": 0.4,
        **{f"A[{i},{j}]": float(i == j + 1) - 0.1 * (i == j) for i in range(1, 4)
           for j in range(1, 4)},
        **{f"B[{i},{j}]": float(i == j + 1) for i in range(1, 4) for j in range(1, 3)},
        **{f"K[{j},{i}]": -0.5 * i - 0.1 * j for i in range(1, 4) for j in range(1, 3)},
        "u0[2]": 0.25})
    comp.initialize()
    return comp


def _steps(comp: FmuComponent, k0: int, count: int, h: float = 0.01) -> list[list[float]]:
    write, read = comp.writer(["y1", "y2", "y3"]), comp.reader(["u1", "u2"])
    out = []
    for k in range(k0, k0 + count):
        t = k * h
        write([np.sin(t), np.cos(3 * t), t / 10])
        out.append(read())
        comp.do_step(t, h)
    return out


def test_parameters_by_element_and_the_run_equal_fmi2(built):
    """The master sets ``A[2,1]`` etc. into the arrays; the controller's outputs over 200
    steps equal its FMI 2.0 twin's, fed the same inputs."""
    runs = []
    for fmi in (2, 3):
        comp = _controller(built["controller", fmi])
        runs.append(_steps(comp, 0, 200))
        comp.terminate()
    assert runs[0] == runs[1]
    assert runs[1][0][1] != 0.0  # u0[2] reached the history


def test_fmu_state_with_every_buffer_continues_bit_identically(built):
    """fmi3GetFMUState + fmi3SerializeFMUState mid-run; restored into the same instance
    and into another one, both continue as the first did."""
    comp = _controller(built["controller", 3])
    _steps(comp, 0, 57)
    state = comp.get_state()
    first = _steps(comp, 57, 80)
    comp.set_state(state)
    assert _steps(comp, 57, 80) == first
    other = _controller(built["controller", 3], "other")
    other.set_state(state)
    assert _steps(other, 57, 80) == first
    comp.terminate()
    other.terminate()


def _slave(path: Path, messages: list[str]):
    """fmpy's FMU3Slave of the FMU, instantiated; its messages appended to ``messages``."""
    from fmpy import extract, read_model_description
    from fmpy.fmi3 import FMU3Slave

    md = read_model_description(str(path))
    slave = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="t")
    slave.instantiate(logMessage=lambda env, status, cat, msg: messages.append(msg.decode()))
    return slave, {v.name: v.valueReference for v in md.modelVariables}


def test_structural_parameters_accept_their_value_and_refuse_another(built):
    from fmpy.fmi1 import FMICallException

    messages: list[str] = []
    slave, vr = _slave(built["controller", 3], messages)
    assert slave.getUInt64([vr["n"], vr["m"]]) == [3, 2]
    with pytest.raises(FMICallException):  # only in configuration mode
        slave.setUInt64([vr["n"]], [3])
    assert "n is a structural parameter: it can be set only in configuration mode" in (
        messages[-1])
    slave.enterConfigurationMode()
    slave.setUInt64([vr["n"], vr["m"]], [3, 2])
    with pytest.raises(FMICallException):  # in configuration mode, only those
        slave.setFloat64([vr["T"]], [0.5])
    assert messages[-1] == ("fmi3SetFloat64: T cannot be set in configuration mode (only the "
                            "structural parameters are)")
    with pytest.raises(FMICallException):
        slave.setUInt64([vr["m"]], [4])
    assert messages[-1] == ("fmi3SetUInt64: m = 4 is not allowed: this FMU is built for m = 2 "
                            "(its arrays' sizes are compiled in: build an FMU for m = 4)")
    slave.exitConfigurationMode()
    slave.enterInitializationMode()
    with pytest.raises(FMICallException):  # an array is set whole: 9 values for A
        slave.setFloat64([vr["A"]], [0.0] * 8)
    assert messages[-1] == ("fmi3SetFloat64: nValues = 8 is not allowed: must be 9 (the "
                            "elements of the variables named)")
    slave.setFloat64([vr["A"], vr["u0"]], [float(k) for k in range(11)])
    assert slave.getFloat64([vr["A"], vr["u0"]], nValues=11) == [float(k) for k in range(11)]
    with pytest.raises(FMICallException):  # a Float32 this FMU has none of
        slave.getFloat32([vr["T"]])
    assert "it is not a Float32 variable of this FMU" in messages[-1]
    slave.freeInstance()


def test_event_mode_and_scheduled_execution_are_refused_at_instantiation(built):
    """hasEventMode is false: a host that asks for event mode gets NULL and a message,
    not an instance that ignores its events."""
    from fmpy import extract, read_model_description
    from fmpy.fmi3 import FMU3Slave

    md = read_model_description(str(built["controller", 3]))
    slave = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(built["controller", 3])),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="t")
    messages: list[str] = []
    with pytest.raises(Exception, match="Failed to instantiate"):
        slave.instantiate(eventModeUsed=True, logMessage=lambda e, s, c, m: messages.append(
            m.decode()))
    assert messages == ["eventModeUsed = true is not allowed: this FMU has no event mode "
                        "(hasEventMode = false)"]


@pytest.mark.parametrize("kind", ["controller", "delay"])
def test_a_bad_parameter_is_refused_with_the_fmi2_twins_message(built, kind):
    """T < 0 (controller), a delay that is no multiple of the step (delay): fmi3Error at
    fmi3ExitInitializationMode, logged with the FMI 2.0 twin's words."""
    params = {"T": -1.0} if kind == "controller" else {"delay": 0.015}
    found = []
    for fmi in (2, 3):
        comp = FmuComponent(f"c{fmi}", built[kind, fmi])
        comp.setup(0.0, 1.0, params)
        with pytest.raises(Exception) as info:
            comp.initialize()
            comp.do_step(0.0, 0.01)  # the delay checks its step at the first one
        found.append(comp.last_message)
        assert isinstance(info.value, FmuRefused) or "status 3" in str(info.value)
        comp.terminate()
    assert found[0] and found[1] == found[0].replace("fmi2", "fmi3")


def test_fmpy_simulates_the_fmi3_plant_alone_exactly(built):
    """fmpy's own FMI 3.0 co-simulation of the plant (its arrays set by fmpy) gives the
    exact flow expm(A t) x0 at each output point."""
    from fmpy import simulate_fmu
    from scipy.linalg import expm

    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, -2.0, -3.0]])
    x0 = np.array([1.0, -0.5, 0.25])
    res = simulate_fmu(str(built["plant", 3]), fmi_type="CoSimulation", stop_time=2.0,
                       output_interval=0.1, start_values={"A": A.ravel().tolist(),
                                                          "x0": x0.tolist()},
                       output=["x1", "x2", "x3"])
    got = np.array([[row[k] for k in ("x1", "x2", "x3")] for row in res])
    want = np.array([expm(A * t) @ x0 for t in res["time"]])
    assert np.max(np.abs(got - want)) <= 1e-13 * np.max(np.abs(want))


# -- the command line ---------------------------------------------------------------------
def test_build_and_run_take_fmi_3(tmp_path):
    proc = cli("build", MYLOOP, "--fmi", "3", "--out", tmp_path)
    assert proc.returncode == 0, proc.stderr
    for role in ("plant", "meas_delay", "controller", "input_delay"):
        assert _root(tmp_path / f"myloop_{role}.fmu").get("fmiVersion") == "3.0"
    assert "FMI 3.0 co-simulation FMUs" in (tmp_path / "myloop_wiring.txt").read_text()
    proc = cli("run", MYLOOP, "--fmi", "3", "--out",
               tmp_path / "three.csv")
    assert proc.returncode == 0, proc.stderr
    proc = cli("run", MYLOOP, "--native", "--out",
               tmp_path / "two.csv")
    assert proc.returncode == 0, proc.stderr
    three, two = (np.loadtxt(tmp_path / f"{n}.csv", delimiter=",", skiprows=1)
                  for n in ("three", "two"))
    assert np.array_equal(three, two)  # the same C maths: the same numbers, bit for bit


@pytest.mark.parametrize("args, message", [
    (["--python"], "--fmi 3 is not allowed with --python: delaycomp's FMI 3.0 FMUs are the "
                   "native C ones"),
    (["--engine", "inprocess"], "--fmi 3 runs FMUs: --engine inprocess is not allowed with "
                                "it"),
])
def test_fmi_3_with_what_has_no_fmi3_fmus_is_one_line(args, message):
    proc = cli("run", "example-3.6", "--fmi", "3", *args)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"delaycomp: error: {message}"
    assert "Traceback" not in proc.stderr


def test_the_reference_pages_table_is_the_fmus(built):
    """``docs/reference/fmi3.md``'s table of arrays and structural parameters is what the
    FMUs declare (example 3.8 for a model's)."""
    import re

    page = (REPO / "docs" / "reference" / "fmi3.md").read_text(encoding="utf-8")
    rows = {m.group(1): (m.group(2), m.group(3)) for m in re.finditer(
        r"^\| `(Delaycomp\w+?)(?:_<model>)?` \| (.+?) \| (.+?) \|$", page, re.M)}
    idents = {"delay": "DelaycompDelay", "plant": "DelaycompPlantLTI",
              "controller": "DelaycompControllerLTI", "model_plant": "DelaycompPlant",
              "model_controller": "DelaycompController"}
    for kind, ident in idents.items():
        variables = list(_root(built[kind, 3]).find("ModelVariables"))
        by_vr = {v.get("valueReference"): v.get("name") for v in variables}
        arrays = ", ".join(
            f"`{v.get('name')}` ({' x '.join(by_vr[d.get('valueReference')] for d in dims)})"
            for v in variables if (dims := v.findall("Dimension")))
        structural = [v.get("name") for v in variables
                      if v.get("causality") == "structuralParameter"]
        assert rows[ident][0] == arrays, ident
        assert re.findall(r"`(\w+)`", rows[ident][1]) == structural, ident


# -- item 3: a controller on a clock -------------------------------------------------------
@pytest.fixture(scope="module")
def clocked() -> Path:
    """The clocked LTI controller, n = 3, m = 2 (from the session's native build cache)."""
    return native_fmu_path("controller", {**DIMS["controller"], "clocked": True}, fmi=3)


def test_the_clocked_controller_declares_its_clock(clocked):
    """An input Clock, its interval the parameter T (fixed), every input and output
    clocked by it; event mode; valid for fmpy."""
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(clocked)) == []
    root = _root(clocked)
    assert root.find("CoSimulation").get("hasEventMode") == "true"
    variables = {v.get("name"): v for v in root.find("ModelVariables")}
    clock = variables["sample"]
    assert (clock.tag, clock.get("causality"), clock.get("intervalVariability")) == (
        "Clock", "input", "fixed")
    ports = [v for v in variables.values() if v.get("causality") in ("input", "output")
             and v.tag != "Clock"]
    assert sorted(v.get("name") for v in ports) == ["u1", "u2", "y1", "y2", "y3"]
    assert {(v.get("clocks"), v.get("variability")) for v in ports} == {
        (clock.get("valueReference"), "discrete")}


@pytest.mark.parametrize("source, sets", [
    ("example-3.6", {"r": 0.3, "u0": 4}),
    ("corollary-3.7", {}),
    (str(MYLOOP), {}),
])
def test_the_clocked_controller_reproduces_the_unclocked_loop(source, sets, tmp_path):
    """Our master schedules its ticks (event mode, the inputs, fmi3SetClock,
    fmi3UpdateDiscreteStates, step mode at each t0 + i T): the loop equals the unclocked
    one bit for bit."""
    plain = api.run(source, sets=sets, fmi=3)
    ticked = api.run(source, sets=sets, fmi=3, clocked=True)
    assert ticked.names == plain.names
    assert np.array_equal(ticked.data, plain.data)
    chosen, _ = api.choose_fmus(source if not sets else api.load(source, sets=sets), fmi=3,
                                clocked=True)
    assert _root(chosen["controller"]).find("CoSimulation").get("hasEventMode") == "true"


def _event_slave(path: Path, messages: list[str], event_mode: bool = True):
    from fmpy import extract, read_model_description
    from fmpy.fmi3 import FMU3Slave

    md = read_model_description(str(path))
    slave = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="t")
    slave.instantiate(eventModeUsed=event_mode,
                      logMessage=lambda env, st, cat, msg: messages.append(msg.decode()))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave.enterInitializationMode(startTime=0.0)
    slave.setFloat64([vr["T"], vr["K"]], [0.2, *[-0.1] * 6])
    return slave, vr


def test_a_host_without_clocks_gets_a_refusal_not_a_wrong_loop(clocked):
    """No event mode asked for: no instance. A step from a tick instant whose tick did not
    come, a tick at another instant, a clocked input set in step mode: each refused with a
    message saying what the host must do."""
    from ctypes import c_double, c_int, c_uint

    from fmpy.fmi1 import FMICallException

    messages: list[str] = []
    with pytest.raises(Exception, match="Failed to instantiate"):
        _event_slave(clocked, messages, event_mode=False)
    assert messages[-1].startswith("eventModeUsed = false is not allowed: this controller "
                                   "samples at the ticks of its clock sample")
    slave, vr = _event_slave(clocked, messages)
    interval, qualifier = (c_double * 1)(), (c_int * 1)()
    slave.getIntervalDecimal((c_uint * 1)(vr["sample"]), interval, qualifier)
    assert (interval[0], qualifier[0]) == (0.2, 2)  # T, fmi3IntervalChanged
    slave.exitInitializationMode()  # event mode: the tick at t0 is due
    slave.enterStepMode()
    with pytest.raises(FMICallException):
        slave.doStep(0.0, 0.05)
    assert messages[-1] == (
        "fmi3DoStep from t = 0.0 is not allowed: sample ticks there (t0 + 0 T) and did not "
        "(enter event mode, set the inputs, fmi3SetClock, fmi3UpdateDiscreteStates, "
        "fmi3EnterStepMode)")
    slave.freeInstance()
    slave, vr = _event_slave(clocked, messages)
    slave.exitInitializationMode()
    slave.setFloat64([vr["y1"], vr["y2"], vr["y3"]], [1.0, 2.0, 3.0])
    slave.setClock([vr["sample"]], [True])
    slave.updateDiscreteStates()
    u = slave.getFloat64([vr["u1"], vr["u2"]])
    slave.enterStepMode()
    slave.doStep(0.0, 0.05)
    with pytest.raises(FMICallException):
        slave.setFloat64([vr["y1"]], [9.0])
    assert messages[-1] == ("fmi3SetFloat64: y1 is not allowed in step mode: it is clocked "
                            "by sample (set it in event mode, at the clock's tick)")
    assert slave.getFloat64([vr["u1"], vr["u2"]]) == u  # held between ticks
    slave.enterEventMode()
    with pytest.raises(FMICallException):
        slave.setClock([vr["sample"]], [True])
    assert messages[-1] == ("fmi3SetClock: sample ticking at t = 0.05 is not allowed: its "
                            "next tick is at t0 + 1 T = 0.2 (interval T = 0.2)")
    slave.freeInstance()


def test_a_clocked_run_restored_mid_period_continues_bit_identically(clocked, tmp_path):
    """The master's state (every component's, the clocked one's schedule and the inputs
    kept for its next tick with it) taken between ticks and restored: the run goes on as
    before."""
    from delaycomp.orchestrator.simulate import make_master

    loop = api.load(MYLOOP)
    fmus, _ = api.choose_fmus(loop, fmi=3, clocked=True)
    master, rec = make_master(loop, fmus=fmus)
    master.setup(loop.stop_time, loop.parameters())
    master.initialize()
    master.run_until(137)  # T = 20 base steps: 17 steps into a period
    state = master.get_state()
    master.run_until(400)
    first = np.array(rec.rows[-263:])
    master.set_state(state)
    master.run_until(400)
    assert np.array_equal(np.array(rec.rows[-263:]), first)
    master.terminate()


def test_clocked_asks_for_fmi_3_on_the_command_line(tmp_path):
    proc = cli("run", "example-3.6", "--clocked")
    assert proc.returncode == 2
    assert proc.stderr.strip() == ("delaycomp: error: --clocked is not allowed without --fmi "
                                   "3: the clocked controller is an FMI 3.0 FMU")
    proc = cli("build", MYLOOP, "--fmi", "3", "--clocked", "--only", "controller", "--out",
               tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert _root(tmp_path / "myloop_controller.fmu").find(
        "CoSimulation").get("hasEventMode") == "true"
    proc = cli("run", MYLOOP, "--fmi", "3", "--clocked")
    assert proc.returncode == 0, proc.stderr


# -- item 5: SSP archives of FMI 3.0 FMUs --------------------------------------------------
def _archive(tmp_path: Path, source: str, *flags: str) -> Path:
    out = tmp_path / f"{Path(source).stem}{''.join(flags).replace('-', '')}.ssp"
    proc = cli("ssp", source, "--fmi", "3", *flags, "--out", out)
    assert proc.returncode == 0, proc.stderr
    return out


@pytest.mark.parametrize("source", tiered([str(MYLOOP), "example-3.6", "corollary-3.7"]))
def test_an_fmi3_archive_is_ssp_1_0_and_runs_in_our_master_as_the_loop(source, tmp_path):
    """``ssp --fmi 3``: the SSD and parameter sets valid against the SSP 1.0 schemas, an
    FMI 3.0 FMU of its own per instance (its values as start values), the parameter sets
    without array elements (SSP 1.0 knows no arrays); our master runs the archive as the
    loop, bit for bit."""
    from delaycomp.formats import ssp

    out = _archive(tmp_path, source)
    with zipfile.ZipFile(out) as zf:
        zf.extractall(tmp_path / "x")
    folder = tmp_path / "x"
    for f in [folder / ssp.SSD_NAME, *sorted((folder / "resources").glob("*.ssv"))]:
        assert ssp.validate(f) == [], f
    fmus = sorted((folder / "resources").glob("*.fmu"))
    assert [f.stem for f in fmus] == ["controller", "input_delay", "meas_delay", "plant"]
    assert {_root(f).get("fmiVersion") for f in fmus} == {"3.0"}
    for ssv in (folder / "resources").glob("*.ssv"):
        assert "[" not in ssv.read_text(encoding="utf-8")
    with ssp.Archive(out) as archive:
        from delaycomp.orchestrator.simulate import run_loop

        got = run_loop(archive.system.spec, archive.system.info.stop_time,
                       fmus=archive.fmus())
    want = api.run(source, fmi=3)
    assert got.success and np.array_equal(got.data, want.data)


def test_a_clocked_archive_runs_in_our_master_as_the_loop(tmp_path):
    from delaycomp.formats import ssp
    from delaycomp.orchestrator.simulate import run_loop

    out = _archive(tmp_path, str(MYLOOP), "--clocked")
    with ssp.Archive(out) as archive:
        got = run_loop(archive.system.spec, archive.system.info.stop_time,
                       fmus=archive.fmus())
        assert _root(archive.fmu("controller")).find("CoSimulation").get(
            "hasEventMode") == "true"
    want = api.run(str(MYLOOP), fmi=3)
    assert got.success and np.array_equal(got.data, want.data)


def test_omsimulator_runs_the_jacobi_fmi3_archive_as_our_master(oms, tmp_path):
    """OMSimulator's command line runs an FMI 3.0 archive (its Python API cannot read
    FMI 3.0 FMUs: ``run --master omsimulator`` takes the command line for them). It does
    not order FMI 3.0 FMUs by their direct feedthrough (it reads their dependencies,
    value references, as FMI 2.0 indices): the Jacobi variant is the archive it runs
    exactly (12 significant digits in its CSV: 1e-11 of each value, as for FMI 2.0), the
    plain one is off by a visible amount, and the run says so in a note."""
    source = "example-3.6"
    from delaycomp.formats.ssp import Archive
    from delaycomp.orchestrator.simulate import run_loop
    from delaycomp.verify import omsimulator

    jacobi = _archive(tmp_path, source, "--jacobi")
    with Archive(jacobi) as a:
        ours = run_loop(a.system.spec, a.system.info.stop_time, fmus=a.fmus())
        stop = a.system.info.stop_time
    theirs = omsimulator.run_ssp(jacobi, stop)
    assert theirs.success, theirs.message
    assert np.all(np.abs(theirs.data - ours.data) <= 1e-11 * np.abs(ours.data) + 1e-12)
    assert theirs.notes == []
    plain = omsimulator.run_ssp(_archive(tmp_path, source), stop)
    assert plain.success and plain.notes == [omsimulator.JACOBI_FMI3_NOTE]
    assert np.max(np.abs(plain.data - ours.data)) > 1e-6


def test_omsimulator_refuses_an_fmi3_controller_whose_dependencies_it_misreads(oms, tmp_path):
    """The README's loop (n = 3): the controller's outputs depend on y1 .. y3, value
    references 29 .. 31 of an FMU of 18 variables; OMSimulator, reading them as indices,
    refuses the FMU (its message), where our master runs the archive (above)."""
    from delaycomp.verify import omsimulator

    jacobi = _archive(tmp_path, str(MYLOOP), "--jacobi")
    res = omsimulator.run_ssp(jacobi, 1.0)
    assert not res.success
    assert res.message == ("omsimulator: error:   [initializeDependencyGraph_outputs] "
                           "controller: erroneous dependencies detected in "
                           "modelDescription.xml")


def test_a_clocked_jacobi_archive_is_refused_in_one_line(tmp_path):
    proc = cli("ssp", "example-3.6", "--fmi", "3", "--jacobi", "--clocked", "--out",
               tmp_path / "x.ssp")
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        "delaycomp: error: clocked = true is not allowed with jacobi = true: the Jacobi "
        "variant samples the step before each tick, a clocked controller samples at the "
        "tick (pack one or the other)")
    assert not (tmp_path / "x.ssp").exists()


def test_a_restored_state_must_hold_the_clock_schedule_of_its_time(clocked):
    """A state of the clocked controller holds the index of the clock's next tick
    (``tick_next``) beside the time. A crafted one whose index does not belong to its time
    would let a host step on without the ticks, or refuse every tick it sets: restored, it
    is refused with one message naming it; the true index restores, and at a tick instant
    both the handled tick's (i + 1) and the unhandled one's (i) do, the latter asking for
    the tick again before the next step."""
    from fmpy.fmi1 import FMICallException

    from .native_state import decode, encode, layout_of

    layout = layout_of(clocked)
    messages: list[str] = []
    slave, vr = _event_slave(clocked, messages)  # T = 0.2, steps of h = 0.01
    y = [vr["y1"], vr["y2"], vr["y3"]]

    def tick(k: int) -> None:
        slave.setFloat64(y, [1.0 + k, 2.0, 3.0])
        slave.setClock([vr["sample"]], [True])
        slave.updateDiscreteStates()
        slave.enterStepMode()

    slave.exitInitializationMode()
    tick(0)
    blobs = {}
    for k in range(30):  # t = 0 .. 0.3, the tick at 0.2 (k = 20) in between
        if k == 20:
            slave.enterEventMode()
            tick(k)
            blobs["at the tick"] = slave.serializeFMUState(slave.getFMUState())
        slave.doStep(k * 0.01, 0.01)
    blobs["between"] = slave.serializeFMUState(slave.getFMUState())

    def restore(blob: bytes, tick_next: int) -> bool:
        snap, buf = decode(layout, blob)
        snap.d.tick_next = tick_next
        try:
            slave.setFMUState(slave.deserializeFMUState(encode(snap, buf)))
        except FMICallException:
            return False
        return True

    assert decode(layout, blobs["between"])[0].d.tick_next == 2  # the tick at 0.4 is next
    for wrong in (0, 1, 3, 50, 10**6):
        assert not restore(blobs["between"], wrong)
        assert messages[-1] == (
            f"fmi3DeserializeFMUState: FMU state is not allowed: tick_next = {wrong}: must "
            "be the index i of the clock's next tick t0 + i T at or after time = 0.3 (t0 = "
            "0.0, T = 0.2)"), messages[-1]
    assert restore(blobs["between"], 2)
    slave.doStep(0.3, 0.01)  # on from the restored state
    assert decode(layout, blobs["at the tick"])[0].d.tick_next == 2
    assert not restore(blobs["at the tick"], 3)
    assert restore(blobs["at the tick"], 1)  # as before the tick at 0.2 was handled
    with pytest.raises(FMICallException):
        slave.doStep(0.2, 0.01)
    assert messages[-1].startswith("fmi3DoStep from t = 0.2 is not allowed: sample ticks "
                                   "there (t0 + 1 T) and did not")
    slave.freeInstance()


@pytest.mark.parametrize("kwargs, message", [
    ({"fmi": 4}, "fmi = int 4 is not allowed: must be 2 or 3 (the FMI version of "
                 "delaycomp's FMUs)"),
    ({"fmi": True}, "fmi = bool True is not allowed: must be 2 or 3"),
    ({"fmi": "3"}, "fmi = '3' is not allowed: must be 2 or 3"),
    ({"fmi": 3, "clocked": "yes"}, "clocked = 'yes' is not allowed: must be true or false"),
    ({"fmi": 3, "clocked": 1}, "clocked = int 1 is not allowed: must be true or false"),
    ({"clocked": True}, "clocked = true is not allowed with fmi = 2: the clocked controller "
                        "is an FMI 3.0 FMU (fmi = 3)"),
])
def test_the_api_refuses_a_bad_fmi_or_clocked_before_anything_is_built(kwargs, message,
                                                                       tmp_path):
    """``run`` (also with the FMU files given, where it used to ignore both),
    ``choose_fmus`` (also with the in-process engine, which used to return before it
    looked at ``clocked``), ``build`` and ``to_ssp``: one ``ParameterError`` naming the
    parameter and what is allowed, nothing written."""
    from delaycomp.errors import ParameterError

    calls = [lambda: api.run("example-3.6", fmu_dir=tmp_path / "c", **kwargs),
             lambda: api.run("example-3.6", fmus={}, **kwargs),  # files given: checked too
             lambda: api.choose_fmus("example-3.6", "auto", tmp_path / "c", **kwargs),
             lambda: api.choose_fmus("example-3.6", "auto", engine="inprocess", **kwargs),
             lambda: api.build("example-3.6", tmp_path / "fmus", **kwargs),
             lambda: api.to_ssp("example-3.6", tmp_path / "x.ssp", **kwargs)]
    for call in calls:
        with pytest.raises(ParameterError) as info:
            call()
        assert str(info.value).startswith(message), str(info.value)
    assert not list(tmp_path.iterdir())
