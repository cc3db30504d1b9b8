"""A CLI that answers at once: what only reads its arguments, prints help or lists the
scenarios imports neither scipy nor matplotlib nor fmpy (nor lxml, pythonfmu), nor numpy.

Not a timed test (speed is measured in ``bench/``): a fresh interpreter runs the command
through ``delaycomp.cli.main`` and reports which of those packages ``sys.modules``
holds at its end. Importing scipy alone cost ``delaycomp --help`` about 0.35 s of its
0.45 s on a 2-core machine (``python -X importtime``); numpy, through the scenarios and
the loop-file reader, 47 ms of 0.18 s (issue 50, item 3). A value that only the loop-file
reader can judge (``r`` off the base grid, ``k`` not a number) is refused after it has
read the scenario's file, with numpy (``NEEDS_READER``)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from .roundoff import EPS, assert_columns_close

#: what a command that does no maths, runs no FMU and writes no SSP must not import
HEAVY = ("scipy", "matplotlib", "fmpy", "lxml", "pythonfmu")
#: ... nor, where it reads no loop file (help, version, list, argument errors and unknown
#: names), numpy
NUMPY = ("numpy",)

PROBE = """
import contextlib, io, json, sys
from delaycomp import cli
with contextlib.redirect_stdout(io.StringIO()) as out, \\
        contextlib.redirect_stderr(io.StringIO()) as err:
    try:
        code = cli.main(sys.argv[1:])
    except SystemExit as exc:
        code = exc.code
print(json.dumps({"code": code, "out": out.getvalue(), "err": err.getvalue(),
                  "modules": sorted({m.split(".")[0] for m in sys.modules})}))
"""


def run_probe(*argv: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


LIGHT = [
    (["--help"], 0, "usage: delaycomp"),
    (["--version"], 0, "delaycomp"),
    (["list"], 0, "example-3.6"),
    (["run", "--help"], 0, "usage: delaycomp run"),
    (["run", "example-3.6", "--no-such-flag"], 2, "unrecognized arguments"),
    (["run", "example-9.9"], 2, "unknown scenario 'example-9.9'"),
    (["run", "example-3.6", "--set", "r=0.305"], 2, "r = 0.305 is not allowed"),
    (["run", "example-3.6", "--set", "k=abc"], 2, "k = 'abc' is not allowed"),
    (["run", "example-3.6", "--set", "zz=1"], 2, "unknown parameter 'zz' for example-3.6"),
    (["run", "example-3.6", "--set", "r"], 2, "expected NAME=VALUE"),
    (["list", "--no-such-flag"], 2, "unrecognized arguments"),
    (["run"], 2, "the following arguments are required"),
    (["sweep", "example-3.6", "--grid", "r=bad", "--out", "x.csv"], 2,
     "expected NAME=START:STOP:COUNT"),
    (["sweep", "example-3.6", "--grid", "r=0:1:0", "--out", "x.csv"], 2, "COUNT = 0"),
    (["sweep", "example-9.9", "--grid", "r=0:1:3", "--out", "x.csv"], 2, "unknown scenario"),
    (["critical-delay", "example-9.9"], 2, "unknown scenario"),
    (["export-loop", "example-9.9", "--out", "x.fmu"], 2, "unknown scenario"),
    (["check", "--case", "example-9.9/x"], 2, "example-9.9/x"),
    (["ssp", "example-9.9", "--out", "x.ssp"], 2, "unknown scenario"),
]
#: the refusals of values that the loop-file reader (numpy) judges, after reading the file
NEEDS_READER = {("run", "example-3.6", "--set", "r=0.305"),
                ("run", "example-3.6", "--set", "k=abc")}


@pytest.mark.parametrize("argv,code,text", LIGHT, ids=[" ".join(a) for a, _, _ in LIGHT])
def test_help_list_and_argument_errors_import_no_heavy_package(argv, code, text):
    res = run_probe(*argv)
    assert res["code"] == code, res
    assert text in res["out"] + res["err"], res
    forbidden = HEAVY if tuple(argv) in NEEDS_READER else HEAVY + NUMPY
    heavy = sorted(set(forbidden) & set(res["modules"]))
    assert not heavy, f"delaycomp {' '.join(argv)} imported {heavy}"


def test_the_probe_sees_numpy_when_a_value_needs_the_reader():
    """Not vacuous for numpy either: a value the loop-file reader judges imports it."""
    res = run_probe("run", "example-3.6", "--set", "r=0.305")
    assert res["code"] == 2 and "numpy" in res["modules"], res


def test_import_delaycomp_loads_no_importlib_resources():
    """The finder of the earlier module names (``delaycomp.layout``) is a plain class:
    ``importlib.abc`` imports ``importlib.resources`` (36 ms of ``--help``'s 0.18 s, issue
    50), which importing delaycomp (in every Python FMU too) does not need."""
    code = ("import sys; before = set(sys.modules); import delaycomp, delaycomp.cli; "
            "print(sorted(m for m in set(sys.modules) - before "
            "if m.startswith(('importlib.abc', 'importlib.resources', 'numpy'))))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=True)
    assert proc.stdout.strip() == "[]", proc.stdout


def test_the_light_list_equals_the_readers(capsys, monkeypatch):
    """``delaycomp list`` reads the shipped loop files as TOML holds them
    (``Scenario.listing``, no numpy); what it shows equals the loop-file reader's title,
    stop time and parameters (defaults, allowed ranges), and so does the printed list."""
    from delaycomp import cli
    from delaycomp.paper import scenarios

    def full(sc):
        return scenarios.Listing(sc.title, sc.default_stop_time, sc.params)

    for sc in scenarios.SCENARIOS.values():
        light, read = sc.listing(), full(sc)
        assert light == read, sc.name
        for a, b in zip(light.params, read.params):  # 2 == 2.0: the types too
            assert type(a.default) is type(b.default), (sc.name, a.name)
            if isinstance(a.default, tuple):
                assert [type(v) for v in a.default] == [type(v) for v in b.default]
    assert cli.main(["list"]) == 0
    shown = capsys.readouterr().out
    monkeypatch.setattr(scenarios.Scenario, "listing", full)
    assert cli.main(["list"]) == 0
    assert capsys.readouterr().out == shown
    assert shown.count("\n\n") == len(scenarios.SCENARIOS) - 1


def test_the_probe_sees_an_import_when_there_is_one():
    """Not vacuous: a command that does the maths (``critical-delay``) does import scipy."""
    res = run_probe("critical-delay", "example-3.6", "--periods", "10")
    assert res["code"] in (0, 1), res
    assert "scipy" in res["modules"]


# -- Python FMUs: what instantiating one imports (issue "Start fast", items 2 and 3) ------

#: Per FMU: the packages its maths needs, and the bundled delaycomp modules it may import.
#: The LTI plant and controller need a matrix exponential (scipy.linalg); the delay copies
#: values; the model FMUs of Example 2.4 use the model's own exact step and Phi (scipy's
#: ODE solver is loaded at a model's first numerical solve, never at instantiation).
#: every Python FMU imports these: the package's finder of its bundled part (``layout``), the
#: two packages (their ``__init__`` imports nothing), the base slave and its FMU-state
#: handles, the names and the errors (the one ``ParameterError``; the standard library
#: only); the sampled controllers add ``fmu.sampling``, which the others never import
FMU_BASE = {"layout", "version", "maths", "fmu", "fmu.slave", "fmu.statehandle", "names",
            "errors"}
FMU_NEEDS = {
    "delay": (("numpy", "pythonfmu"),
              FMU_BASE | {"maths.delayline", "maths.grid"}),
    "plant": (("numpy", "pythonfmu", "scipy.linalg"),
              FMU_BASE | {"maths.grid", "maths.lti"}),
    "controller": (("numpy", "pythonfmu", "scipy.linalg"),
                   FMU_BASE | {"fmu.sampling", "maths.zoh", "maths.grid", "maths.lti"}),
    "model_plant": (("numpy", "pythonfmu"),
                    FMU_BASE | {"maths.delayline", "maths.grid", "maths.history",
                                "maths.model", "maths.nlcontrol", "maths.predictors"}),
    "model_controller": (("numpy", "pythonfmu"),
                         FMU_BASE | {"fmu.sampling", "maths.delayline", "maths.grid",
                                     "maths.history", "maths.model", "maths.nlcontrol",
                                     "maths.predictors"}),
}

IMPORTS_OF = """
import importlib, json, sys
before = set(sys.modules)
for name in sys.argv[1:]:
    importlib.import_module(name)
print(json.dumps(sorted(set(sys.modules) - before)))
"""


def installed_modules(modules) -> set[str]:
    """The modules of installed packages (neither the standard library nor delaycomp's)."""
    return {m for m in modules if not m.startswith(("_", "delaycomp"))
            and m.split(".")[0] not in sys.stdlib_module_names}


@pytest.fixture(scope="module")
def python_fmus(fmu_dir):
    from delaycomp.fmu.cache import fmu_path
    from delaycomp.paper.models import path as builtin_model

    model = {"model": str(builtin_model("example_2_4"))}
    return {"delay": fmu_dir / "DelaycompDelay.fmu",
            "plant": fmu_dir / "DelaycompPlantLTI.fmu",
            "controller": fmu_dir / "DelaycompControllerLTI.fmu",
            "model_plant": fmu_path("model_plant", model),
            "model_controller": fmu_path("model_controller", model)}


@pytest.mark.parametrize("kind", FMU_NEEDS)
def test_a_python_fmu_imports_only_what_its_maths_needs(kind, python_fmus):
    """Instantiated as pythonfmu's binary does it (``delaycomp.fmu.build.probe_instantiation``),
    the FMU imports no installed module that importing its short list alone would not
    (no matplotlib, fmpy, lxml; no scipy.optimize for a matrix exponential), and of the
    bundled delaycomp only its maths (no CLI, SSP, masters or plotting)."""
    from delaycomp.fmu.build import probe_instantiation

    needs, own = FMU_NEEDS[kind]
    probe = probe_instantiation(python_fmus[kind])
    proc = subprocess.run([sys.executable, "-c", IMPORTS_OF, *needs], capture_output=True,
                          text=True, timeout=120, check=True)
    allowed = installed_modules(json.loads(proc.stdout))
    extra = {".".join(m.split(".")[:2]) for m in installed_modules(probe.modules) - allowed}
    assert not extra, f"instantiating the {kind} FMU imported {sorted(extra)[:12]}"
    bundled = {m.split(".", 1)[1] for m in probe.delaycomp_modules}
    assert bundled <= own, f"the {kind} FMU imported delaycomp.{sorted(bundled - own)}"
    assert "pythonfmu" in probe.packages  # the probe did instantiate a pythonfmu slave


def test_the_fmu_probe_sees_what_an_fmu_imports(python_fmus):
    """Not vacuous: the LTI plant's matrix exponential does load scipy.linalg, which the
    delay's allowed list would refuse."""
    from delaycomp.fmu.build import probe_instantiation

    probe = probe_instantiation(python_fmus["plant"])
    assert "scipy.linalg" in probe.subpackages
    assert "scipy" not in FMU_NEEDS["delay"][0]


# -- a packed loop of native FMUs (issue "Start fast", item 4) ----------------------------

#: the probe above, leaving with os._exit once it has printed (as ``delaycomp`` itself does
#: with FMUs loaded: see ``delaycomp.cli.entry``)
PROBE_EXIT = PROBE + "sys.stdout.flush()\nimport os\nos._exit(0)\n"


@pytest.fixture(scope="module")
def native_ssp(tmp_path_factory):
    out = tmp_path_factory.mktemp("packed") / "ex36-native.ssp"
    proc = subprocess.run([sys.executable, "-m", "delaycomp", "ssp", "example-3.6",
                           "--native", "--out", str(out), "-q"], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return out


def test_a_packed_native_run_loads_neither_a_progress_bar_nor_a_blas_limiter(native_ssp):
    """No bar shows (``-q``, or standard error not a terminal): tqdm is not imported; no
    Python maths runs in the process (native FMUs): threadpoolctl is not imported."""
    proc = subprocess.run([sys.executable, "-c", PROBE_EXIT, "run", str(native_ssp),
                           "--stop-time", "1"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    assert res["code"] == 0 and "101 rows to t = 1" in res["out"], res
    loaded = sorted({"tqdm", "threadpoolctl", "scipy", "matplotlib"} & set(res["modules"]))
    assert not loaded, f"a packed native run imported {loaded}"


def test_blas_runs_on_one_thread_where_python_maths_runs(native_ssp, fmu_dir, monkeypatch):
    """The limit is entered for a loop of Python FMUs (their slaves use this numpy), not for
    one of native FMUs; the run is the same either way."""
    from delaycomp.formats.ssp import Archive
    from delaycomp.orchestrator import simulate
    from delaycomp.paper import scenarios

    entered = []
    real = simulate.single_threaded_blas

    def counting():
        entered.append(1)
        return real()

    monkeypatch.setattr(simulate, "single_threaded_blas", counting)
    sc = scenarios.get("example-3.6")
    python = simulate.run_loop(sc.make(sc.resolve([])), 1.0, fmu_dir)
    assert python.success and entered == [1]
    with Archive(native_ssp, None) as archive:
        native = simulate.run_loop(archive.system.spec, 1.0, fmus=archive.fmus())
    assert native.success and entered == [1]
    # twins: the same maths in C and in Python, 1e-12 of each signal's peak as in
    # tests/test_native.py (measured at most 3.4e-14, fmus/native/README.md)
    assert_columns_close(native.data, python.data, 1e-12 / EPS, "native vs Python")


def test_an_fmu_is_unpacked_with_what_running_it_needs(fmu_dir):
    """modelDescription, resources and this platform's binaries; not the sources, the
    documentation or another platform's library (a Python FMU carries a Windows DLL)."""
    import fmpy

    from delaycomp.orchestrator.fmu import FmuComponent

    comp = FmuComponent("delay", fmu_dir / "DelaycompDelay.fmu")
    root = Path(comp._unzipdir)
    assert (root / "modelDescription.xml").is_file()
    assert (root / "resources" / "slavemodule.txt").is_file()
    assert [p.name for p in (root / "binaries").iterdir()] == [fmpy.platform]
    assert not (root / "documentation").exists() and not (root / "sources").exists()
