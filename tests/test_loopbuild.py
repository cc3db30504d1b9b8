"""``delaycomp build LOOP.toml`` (issue 24, item 1): the FMUs of a user's loop, named after
it, with the loop's values as their start values, and the wiring sheet.

The proof that the start values are the loop's: the built FMUs run in our master with no
parameter set at all and give the same trajectory as ``delaycomp run LOOP.toml`` (which
sets every parameter), for native and Python FMUs, an LTI loop of n = 3, m = 2 and a
nonlinear model loop; and each start value in the modelDescription reads back as the
loop's value exactly (Real starts as ``repr``: 16 digits, as pythonfmu writes them, lose
the last bit of values such as -11/6).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest

from delaycomp import api
from delaycomp.fmu.cache import fmu_path
from delaycomp.fmu.twins import native_fmus
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.system.loopfile import read_loop

from .roundoff import SAME_ARITHMETIC_ULPS, assert_columns_close

pytestmark = pytest.mark.fmu

REPO = Path(__file__).resolve().parent.parent

#: a user's loop: n = 3 states, m = 2 inputs, a gain with an entry that 16 digits do not
#: hold (-11/6), delays and histories that differ from every default
MYLOOP = """
T = 0.5
N = 50
r = 0.3
tau = 0.5
stop_time = 4.0

[plant]
A = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-0.5, 0.2, 0.1]]
B = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]
x0 = [1.0, -0.5, 0.25]

[controller]
mode = "compensated"
K = [[-0.8, -1.2, 0.0], [0.3, -0.4, -1.8333333333333333]]
u0 = [0.1, -0.2]
"""

ROLES = ("plant", "meas_delay", "controller", "input_delay")


def cli(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "delaycomp", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, env=env)


def write_loop(folder: Path, text: str = MYLOOP, name: str = "myloop") -> Path:
    path = folder / f"{name}.toml"
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


def starts(fmu: Path) -> dict[str, tuple[str, str]]:
    """name -> (type, start text) of every variable with a start, read from the file."""
    with zipfile.ZipFile(fmu) as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    out = {}
    for sv in root.find("ModelVariables"):
        typed = next(iter(sv))
        if typed.get("start") is not None:
            out[sv.get("name")] = (typed.tag, typed.get("start"))
    return out


def assert_starts_are_the_loops(fmu: Path, parameters: dict) -> None:
    table = starts(fmu)
    for name, value in parameters.items():
        typ, text = table[name]
        if typ == "Real":
            assert float(text) == float(value), (fmu.name, name, text, value)
        elif typ == "Boolean":
            assert text == ("true" if value else "false"), (fmu.name, name)
        elif typ == "Integer":
            assert int(text) == int(value), (fmu.name, name)
        else:
            assert text == str(value), (fmu.name, name)


def without_parameters(loop):
    """The loop with no parameter to set: a host that only instantiates the FMUs."""
    return loop.with_instances(dataclasses.replace(i, parameters={}) for i in loop.instances)


def is_native(fmu: Path) -> bool:
    with zipfile.ZipFile(fmu) as zf:
        names = zf.namelist()
        md = zf.read("modelDescription.xml").decode()
    return 'needsExecutionTool="false"' in md and not any(n.endswith(".py") for n in names)


@pytest.mark.parametrize("flag", ["--native", "--python"])
def test_build_loop_file_writes_its_fmus_with_its_values_as_start_values(flag, tmp_path):
    """n = 3, m = 2: four FMUs named after the loop file and the wiring sheet; every
    parameter's start value is the loop's, exactly; with no parameter set the FMUs give
    ``delaycomp run``'s trajectory (same arithmetic: 4 EPS of each column's peak; a start
    value off in its last bit would still pass that, which is why the starts are also
    compared exactly above)."""
    loop_file = write_loop(tmp_path)
    out = tmp_path / "out"
    proc = cli("build", loop_file, "--out", out, flag)
    assert proc.returncode == 0, proc.stderr
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted([*(f"myloop_{r}.fmu" for r in ROLES), "myloop_wiring.txt"])
    assert proc.stdout.split() == [str(out / f"myloop_{r}.fmu") for r in ROLES] + [
        str(out / "myloop_wiring.txt")]
    loop = read_loop(loop_file)
    fmus = {}
    for inst in loop.instances:
        fmu = out / f"myloop_{inst.role}.fmu"
        assert is_native(fmu) == (flag == "--native")
        assert_starts_are_the_loops(fmu, dict(inst.parameters))
        fmus[inst.name] = fmu
    assert starts(out / "myloop_controller.fmu")["K[2,3]"][1] == "-1.8333333333333333"
    # `delaycomp run --native` / `--python`: the FMUs of the cache, every parameter set
    cache = native_fmus(loop) if flag == "--native" else None
    want = run_loop(loop, 4.0, fmus=cache)
    got = run_loop(without_parameters(loop), 4.0, fmus=fmus)
    assert want.success and got.success, got.message
    assert got.names == want.names
    assert_columns_close(got.data, want.data, SAME_ARITHMETIC_ULPS, "no parameters set")
    # not vacuous: with the cache's controller (its own defaults) in place of the built
    # one and no parameter set, the loop is another one (or refused)
    other = run_loop(without_parameters(loop), 4.0, fmus={
        **fmus, "controller": native_fmus(loop)["controller"] if flag == "--native"
        else fmu_path(*loop.by_role("controller").source.build_key())})
    assert not other.success or np.max(np.abs(other.data - want.data)) > 1e-3


def test_a_model_loop_builds_natively_and_runs_with_no_parameter_set(tmp_path):
    """A loop file naming a model (Example 3.8 with p = sin, padded input delay,
    numerical predictor: String, Boolean and model parameters among the starts): the
    native model FMUs carry the loop's values and run it as ``delaycomp run`` does."""
    model = REPO / "delaycomp" / "paper" / "models" / "example_3_8.py"
    (tmp_path / model.name).write_bytes(model.read_bytes())
    loop_file = write_loop(tmp_path, """
        T = 1.0
        N = 20
        r = 0.5
        tau = 0.0
        stop_time = 5.0
        [plant]
        model = "example_3_8.py"
        x0 = [1.0, -1.0]
        [controller]
        predictor = "numerical"
        pad = true
        p = "square"
        u0 = [0.2]
    """, "e38")
    sets = ["--set", "tau=0.3", "--set", "controller.p=sin"]
    out = tmp_path / "out"
    proc = cli("build", loop_file, "--out", out, "--native", *sets)
    assert proc.returncode == 0, proc.stderr
    loop = api.load(loop_file, tau=0.3, controller__p="sin")
    ctrl = loop.by_role("controller").parameters
    assert ctrl["pad"] is True and ctrl["p"] == "sin" and ctrl["predictor"] == "numerical"
    fmus = {}
    for inst in loop.instances:
        fmu = out / f"e38_{inst.role}.fmu"
        assert is_native(fmu)
        assert_starts_are_the_loops(fmu, dict(inst.parameters))
        fmus[inst.name] = fmu
    want = run_loop(loop, 5.0, fmus=native_fmus(loop))  # `delaycomp run --native`
    got = run_loop(without_parameters(loop), 5.0, fmus=fmus)
    assert want.success and got.success, got.message
    assert_columns_close(got.data, want.data, SAME_ARITHMETIC_ULPS, "no parameters set")


def test_only_builds_the_groups_asked_for_and_the_sheet(tmp_path):
    loop_file = write_loop(tmp_path)
    for only, roles in ((["controller"], ["controller"]),
                        (["delays"], ["meas_delay", "input_delay"]),
                        (["plant", "controller"], ["plant", "controller"])):
        out = tmp_path / "-".join(only)
        proc = cli("build", loop_file, "--out", out, *[a for o in only for a in ("--only", o)])
        assert proc.returncode == 0, proc.stderr
        assert sorted(p.name for p in out.iterdir()) == sorted(
            [*(f"myloop_{r}.fmu" for r in roles), "myloop_wiring.txt"])


def test_wiring_sheet_says_what_a_host_needs(tmp_path):
    """The sheet names each FMU's inputs and outputs (as its modelDescription has them),
    every connection, T and the base step, the step order, and, for the controller alone,
    which plant signal feeds which input r earlier, where its outputs go tau later, and
    the histories."""
    from fmpy import read_model_description

    loop_file = write_loop(tmp_path)
    out = tmp_path / "out"
    assert cli("build", loop_file, "--out", out, "--native").returncode == 0
    sheet = (out / "myloop_wiring.txt").read_text(encoding="utf-8")
    loop = read_loop(loop_file)
    assert "T = 0.5 s" in sheet and "h = T/N = 0.01 s (N = 50)" in sheet
    assert "r = 0.3 s (measurement), tau = 0.5 s (input)" in sheet
    for role in ROLES:
        md = read_model_description(str(out / f"myloop_{role}.fmu"))
        ins = [v.name for v in md.modelVariables if v.causality == "input"]
        outs = [v.name for v in md.modelVariables if v.causality == "output"]
        assert f"myloop_{role}.fmu" in sheet
        assert f"inputs {', '.join(ins)}; outputs {', '.join(outs)}" in sheet
    for c in loop.connections:
        assert f"  {c}\n" in sheet
    assert "1. read the outputs of plant" in sheet
    assert "2. for meas_delay, controller, input_delay, in this order" in sheet
    for i in (1, 2, 3):
        assert f"controller.y{i} <- plant.x{i}(t - r)" in sheet
    for j in (1, 2):
        assert f"plant.u{j}(t) <- controller.u{j}(t - tau)" in sheet
    assert "x0 = 1, -0.5, 0.25" in sheet and "u0 = 0.1, -0.2" in sheet
    assert "tau a multiple of T" in sheet  # the LTI controller holds over each period


def test_a_plant_fmu_of_another_tool_is_named_not_rebuilt(tmp_path):
    """A loop file whose plant is a C FMU (tests/cfmu): the delays and the controller are
    built, the plant is the user's file, used as it is, with a note; the sheet names it."""
    from tests.cfmu.build import build_oscillator

    from .test_plant_fmu import LOOP

    build_oscillator(tmp_path)
    loop_file = write_loop(tmp_path, LOOP, "osc")
    out = tmp_path / "out"
    proc = cli("build", loop_file, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["osc_meas_delay.fmu", "osc_controller.fmu", "osc_input_delay.fmu", "osc_wiring.txt"])
    assert "note: the plant is the loop's own FMU file" in proc.stderr
    sheet = (out / "osc_wiring.txt").read_text(encoding="utf-8")
    assert str(tmp_path / "Oscillator.fmu") in sheet and "used as it is" in sheet
    assert "controller.y1 <- plant.position(t - r)" in sheet


def test_the_default_falls_back_to_python_fmus_with_a_note(tmp_path):
    loop_file = write_loop(tmp_path)
    env = {**os.environ, "CC": "no-such-compiler"}
    proc = cli("build", loop_file, "--out", tmp_path / "out", "--only", "controller", env=env)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.startswith("note: building the Python FMUs (no native ones here: CC")
    assert not is_native(tmp_path / "out" / "myloop_controller.fmu")
    proc = cli("build", loop_file, "--out", tmp_path / "n", "--native", env=env)
    assert proc.returncode == 1 and "CC = 'no-such-compiler'" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "n" / "myloop_plant.fmu").exists()


def test_default_out_is_the_current_folder_and_names_stay_inside(tmp_path):
    """Without --out the files go to the current folder; a loop ``name`` with separators
    names files inside it, never elsewhere."""
    text = 'name = "../../evil name"\n' + MYLOOP
    loop_file = write_loop(tmp_path, text, "evil")
    work = tmp_path / "work"
    work.mkdir()
    proc = cli("build", loop_file, "--only", "controller", cwd=work)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in work.iterdir()) == ["evil_name_controller.fmu",
                                                      "evil_name_wiring.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["evil.toml", "work"]


@pytest.mark.parametrize("args,message", [
    (["--model", "x.py"], "--model is not allowed with LOOP.toml"),
    (["--only", "sensor"], "argument --only: invalid choice: 'sensor'"),
    (["--set", "r=-1"], "r = -1"),
    (["--native", "--python"], "not allowed with argument"),
])
def test_bad_build_of_a_loop_is_one_line(args, message, tmp_path):
    proc = cli("build", write_loop(tmp_path), "--out", tmp_path / "o", *args)
    assert proc.returncode == 2, proc.stderr
    assert message in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("args,message", [
    (["--out", "o", "--only", "controller"], "--only is not allowed without LOOP.toml"),
    (["--out", "o", "--set", "r=1"], "--set is not allowed without LOOP.toml"),
    ([], "the following arguments are required: --out"),
    (["x.ssp"], "not an SSP archive"),
    (["nosuch.toml"], "no such loop file"),
])
def test_bad_build_arguments_are_one_line(args, message, tmp_path):
    proc = cli("build", *args, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert message in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_api_build_is_the_command(tmp_path):
    """``api.build`` writes the same files as the command, from a loop made in Python."""
    loop = api.load(write_loop(tmp_path))
    built = api.build(loop, tmp_path / "api", only=["controller", "delays"], fmus="native")
    assert built.native and built.notes == ()
    assert sorted(built.fmus) == ["controller", "input_delay", "meas_delay"]
    assert [p.name for p in built.paths] == ["myloop_meas_delay.fmu", "myloop_controller.fmu",
                                             "myloop_input_delay.fmu", "myloop_wiring.txt"]
    proc = cli("build", tmp_path / "myloop.toml", "--out", tmp_path / "cli", "--only",
               "controller", "--only", "delays")
    assert proc.returncode == 0, proc.stderr
    for name in ("myloop_wiring.txt",):
        assert (tmp_path / "api" / name).read_text() == (tmp_path / "cli" / name).read_text()
    assert starts(tmp_path / "api" / "myloop_controller.fmu") == starts(
        tmp_path / "cli" / "myloop_controller.fmu")
    with pytest.raises(api.ParameterError, match="only"):
        api.build(loop, tmp_path / "x", only=["sensor"])
