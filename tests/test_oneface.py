"""One face (issue 27, item 4): every API function takes a loop in the same three forms (a
``Loop``, a loop file's path, a scenario's name), ``sweep`` a ``Loop`` with grid axes over
its parameters (the rows of the same loop given as a loop file), the API importable from
``delaycomp`` itself (lazily), and errors that name what was passed in a short form."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import delaycomp
from delaycomp import api
from delaycomp.errors import ParameterError, short
from delaycomp.paper.scenarios import loop_file, open_source
from delaycomp.system import lti_loop

REPO = Path(__file__).resolve().parent.parent
CART = REPO / "docs" / "examples" / "cart.py"

# -- the same loop as a Loop and as a loop file --------------------------------------------

DOUBLE = dict(A=[[0.0, 1.0], [0.0, 0.0]], B=[[0.0], [1.0]], K=[[-1.0, -1.6]])
DOUBLE_TOML = """\
name = "dbl"
T = 0.2
N = 20
r = 0.36
tau = 0.4
stop_time = 6.0

[plant]
A = [[0.0, 1.0], [0.0, 0.0]]
B = [[0.0], [1.0]]
x0 = [1.0, 0.0]

[controller]
K = [[-1.0, -1.6]]
u0 = [0.0]
mode = "compensated"
"""

SCALAR_TOML = """\
name = "scalar"
T = 1.0
N = 10
stop_time = 10.0

[plant]
A = [[1.0]]
B = [[1.0]]
x0 = [1.0]

[controller]
K = [[-2.0]]
mode = "uncompensated"
allow_unstable = true
"""

CART_TOML = f"""\
name = "cart"
T = 1.0
N = 20
r = 0.5
tau = 1.0
stop_time = 8.0

[plant]
model = "{CART.as_posix()}"
x0 = [1.0, 0.0]

[controller]
mode = "compensated"
u0 = [0.0]
mass = 2.0
"""


def _file(tmp_path: Path, text: str, name: str) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def double() -> delaycomp.Loop:
    return api.lti(DOUBLE["A"], DOUBLE["B"], DOUBLE["K"], T=0.2, r=0.36, tau=0.4, N=20,
                   x0=[1.0, 0.0], name="dbl", stop_time=6.0)


def test_lti_and_model_loops_keep_their_loop_file_data(tmp_path):
    """What api.lti and api.model build is the loop of the same loop file (Loop equality:
    instances, connections, timing, recorded ports), and it keeps that data (origin)."""
    loop = double()
    assert loop.origin is not None
    assert loop == api.load(_file(tmp_path, DOUBLE_TOML, "dbl"))
    assert open_source(loop).loop() == loop
    cart = api.model(CART, T=1.0, r=0.5, tau=1.0, N=20, x0=[1.0, 0.0], mass=2.0,
                     stop_time=8.0)
    assert cart == api.load(_file(tmp_path, CART_TOML, "cart"))
    assert open_source(cart).loop() == cart


@pytest.mark.parametrize("engine", ["batch", "inprocess"])
def test_a_loop_sweeps_to_the_rows_of_its_loop_file(tmp_path, engine):
    """sweep(Loop) == sweep(the same loop as a loop file), row for row, over the delays
    (a Loop from api.lti) and over the gain by its short name (one state: K=-1.5 is
    [[-1.5]])."""
    grid = {"r": [0.0, 0.2, 0.36], "tau": [0.0, 0.4]}
    rows = api.sweep(double(), grid, engine=engine)
    assert rows == api.sweep(_file(tmp_path, DOUBLE_TOML, "dbl"), grid, engine=engine)
    assert len(rows) == 6 and all(row["failed"] == "" for row in rows)

    scalar = api.lti([[1.0]], [[1.0]], [[-2.0]], T=1.0, N=10, x0=[1.0], name="scalar",
                     mode="uncompensated", allow_unstable=True, stop_time=10.0)
    grid = {"K": [-1.5, -2.0], "r": [0.0, 0.5]}
    rows = api.sweep(scalar, grid, engine=engine)
    assert rows == api.sweep(str(_file(tmp_path, SCALAR_TOML, "scalar")), grid,
                             engine=engine)
    assert [row["stable"] for row in rows] == [1, 0, 1, 0]
    # at r = 0 the sampled loop is x+ = (e + (e - 1) K) x: rho = |e - 1.5 (e - 1)|, which
    # the trajectory's estimate finds within 0.017 (delaycomp.studies.sweep's docstring)
    e = np.e
    assert rows[0]["rho"] == pytest.approx(abs(e - 1.5 * (e - 1)), abs=0.017)


def test_a_model_loop_sweeps_over_its_own_parameters(tmp_path):
    """A Loop from api.model, swept over the model's parameter (``mass``, its short name)
    and a delay, on the batch engine and point by point: the loop file's rows."""
    cart = api.model(CART, T=1.0, r=0.5, tau=1.0, N=20, x0=[1.0, 0.0], mass=2.0,
                     stop_time=8.0)
    grid = {"mass": [1.5, 2.0], "r": [0.0, 0.5]}
    path = _file(tmp_path, CART_TOML, "cart")
    notes: list[str] = []
    rows = api.sweep(cart, grid, notes=notes)
    assert rows == api.sweep(path, grid)
    assert rows == api.sweep(cart, grid, engine="inprocess")
    assert [(row["mass"], row["r"]) for row in rows] == [(1.5, 0.0), (1.5, 0.5),
                                                         (2.0, 0.0), (2.0, 0.5)]
    assert any("batch engine" in n for n in notes), notes


def test_a_loop_of_a_scenario_or_a_loop_file_sweeps_as_its_source():
    rows = api.sweep(api.load("example-3.6"), {"r": [0.0, 0.5]}, stop_time=10.0)
    assert rows == api.sweep("example-3.6", {"r": [0.0, 0.5]}, stop_time=10.0)
    path = loop_file("example-3.6")
    assert list(api.iter_sweep(api.load(path), {"r": [0.0, 0.5]}, stop_time=10.0)) == rows


@pytest.mark.fmu
def test_a_loop_sweeps_on_the_fmu_engine_as_in_process():
    """Each point's FMUs built from the loop's data (prebuilt once) and run: the native
    ones where there is a C compiler (stepped by the native core), else the Python ones
    through fmpy; the in-process engine's rows (the same maths; to the native FMUs'
    round-off, ``NATIVE_ULPS``)."""
    from .roundoff import NATIVE_ULPS, assert_same_values

    grid = {"r": [0.0, 0.36]}
    assert_same_values(api.sweep(double(), grid, engine="fmu"),
                       api.sweep(double(), grid, engine="inprocess"), NATIVE_ULPS, "rows")


def test_a_loop_sweeps_on_worker_processes(tmp_path):
    """The loop's data travels to the workers with each point (it pickles)."""
    grid = {"r": [0.0, 0.36]}
    assert api.sweep(double(), grid, engine="inprocess", workers=2) == api.sweep(
        double(), grid, engine="inprocess")


def test_a_changed_or_bare_loop_is_refused_for_a_sweep():
    loop = double()
    changed = loop.set_parameters("controller", **{"K[1,1]": -2.0})
    with pytest.raises(ParameterError, match="changed after it was built") as exc:
        api.sweep(changed, {"r": [0.0]})
    assert len(str(exc.value)) < 300 and "<Loop 'dbl' n=2 m=1" in str(exc.value)
    bare = lti_loop([[1.0]], [[1.0]], [[-2.0]], T=1.0, r=0.0, tau=0.0, N=10,
                    mode="compensated", x0=[1.0], u0=[0.0])
    with pytest.raises(ParameterError, match="keeps no loop-file data"):
        api.sweep(bare, {"r": [0.0]})
    api.run(bare, 1.0, engine="inprocess")  # a bare loop runs as it is


# -- every function, the three forms -------------------------------------------------------

def test_every_function_takes_a_loop_a_path_or_a_name(tmp_path):
    path = loop_file("example-3.6")
    forms = ["example-3.6", path, str(path), api.load(path)]
    runs = [api.run(f, 3.0, engine="inprocess", sets=["r=0.5"]) for f in forms]
    for res in runs[1:]:
        np.testing.assert_array_equal(res.data, runs[0].data)
    assert len({api.critical_delay(f) for f in forms}) == 1
    assert api.choose_fmus("example-3.6", "python") == (None, None)
    out = api.export_c("example-3.6", tmp_path / "c", "ctl", sets={"r": 0.4})
    assert [p.name for p in out] == ["ctl.h", "ctl.c"]
    built = api.build(path, tmp_path / "b", only=["controller"], fmus="python")
    assert sorted(p.name for p in built.paths) == ["example-3.6_controller.fmu",
                                                   "example-3.6_wiring.txt"]
    ssp = api.to_ssp("example-3.6", tmp_path / "x.ssp", fmus="python", fmu_dir=tmp_path)
    assert ssp.is_file()


def test_load_takes_sets_and_overrides_in_every_form():
    loop = double()
    again = api.load(loop, sets=["r=0.2"], tau=0.2, plant__x0=np.array([0.5, 0.0]))
    assert (again.lti.r, again.lti.tau, again.lti.x0.tolist()) == (0.2, 0.2, [0.5, 0.0])
    assert api.load(loop, sets={"K": [[-2.0, -3.0]]}).lti.K.tolist() == [[-2.0, -3.0]]
    assert api.load(loop) is loop
    assert api.load("example-3.6", k=1.5).lti.K.tolist() == [[-1.5]]


# -- errors name what was passed, in a short form ------------------------------------------

class Huge:
    def __repr__(self):
        return "Huge(" + "x" * 5000 + ")"


@pytest.mark.parametrize("source", [Huge(), {"T": 1.0, "plant": {"A": [[0.0] * 60] * 60}},
                                    3.5, None], ids=["object", "dict", "float", "None"])
def test_a_wrong_type_is_refused_in_one_short_line(source):
    for call in (lambda: api.run(source, 1.0), lambda: api.sweep(source, {"r": [0.0]}),
                 lambda: api.load(source), lambda: api.critical_delay(source)):
        with pytest.raises(ParameterError) as exc:
            call()
        text = str(exc.value)
        assert len(text) < 200 and "\n" not in text, text
        assert text.startswith(f"source = {type(source).__name__}") or text.startswith(
            "source = <"), text
        assert "give a Loop, a loop file path or a scenario name" in text


def test_an_unknown_scenario_is_named_in_part():
    with pytest.raises(ParameterError, match="unknown scenario 'xxx") as exc:
        api.run("x" * 5000, 1.0)
    assert len(str(exc.value)) < 250


def test_a_loop_is_shown_in_short():
    loop = double()
    assert repr(loop) == "<Loop 'dbl' n=2 m=1 T=0.2 N=20>"
    assert short(loop) == repr(loop)
    assert len(short({"a": list(range(10_000))})) <= 80


# -- the API from delaycomp itself, lazily -------------------------------------------------

LAZY = """
import json, sys
before = set(sys.modules)
import delaycomp
light = sorted(set(sys.modules) - before)
names = dir(delaycomp)
import delaycomp.api
print(json.dumps({"light": light, "names": names, "all": delaycomp.__all__,
                  "same": [getattr(delaycomp, n) is getattr(delaycomp.api, n)
                           for n in delaycomp.__all__]}))
"""


def test_import_delaycomp_is_light_and_offers_the_api():
    proc = subprocess.run([sys.executable, "-c", LAZY], capture_output=True, text=True,
                          timeout=120, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    heavy = [m for m in got["light"] if m.split(".")[0] in (
        "numpy", "scipy", "fmpy", "matplotlib", "lxml", "pythonfmu")
        or m in ("delaycomp.api", "delaycomp.system", "delaycomp.maths")]
    assert not heavy, got["light"]
    assert all(got["same"]) and len(got["same"]) == len(api.__all__)
    assert got["all"] == api.__all__ and set(got["all"]) <= set(got["names"])
    assert {"run", "load", "lti", "model", "sweep", "plot", "ParameterError"} <= set(
        got["names"])


def test_the_api_names_are_the_api_functions():
    assert delaycomp.run is api.run and delaycomp.sweep is api.sweep
    assert delaycomp.ParameterError is ParameterError
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        delaycomp.no_such_name  # noqa: B018


# -- short names of loop-file keys, for files too ------------------------------------------

def test_a_loop_file_takes_short_names_and_a_number_for_a_one_by_one_matrix(tmp_path):
    path = _file(tmp_path, SCALAR_TOML, "scalar")
    loop = api.load(path, sets=["K=-1.5", "x0=2", "mode=compensated"])
    assert (loop.lti.K.tolist(), loop.lti.x0.tolist(), loop.lti.mode) == (
        [[-1.5]], [2.0], "compensated")
    cart = api.load(_file(tmp_path, CART_TOML, "cart"), mass=3.0)
    assert cart.by_role("plant").parameters["mass"] == 3.0
    with pytest.raises(ParameterError, match="unknown key 'speed'"):
        api.load(path, speed=1.0)
