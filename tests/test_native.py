"""Native C FMUs (``delaycomp build --native``, ``delaycomp.fmu.native``).

What is checked, and why each tolerance:

- the C matrix exponential and flow against scipy on random and stiff matrices: both are
  backward stable Pade approximations with scaling and squaring, so they agree to about
  ``cond(exp, A) eps`` relative to the largest entry (bound: ``1e3 max(1, ||A||_1) eps``);
- every LTI reference case run with native FMUs in our master equals the run with the
  Python FMUs to 1e-12 relative to each signal's peak (the maths is the same, only the
  rounding of the exponentials and of the sums differs: measured <= 4e-14), and the
  reference within the cross-check's own tolerance (``delaycomp.verify.check.compare``);
- the C host run under ``env -i`` (no Python in the process) gives the very numbers of our
  master with the same FMUs (same binary, same sequence of calls): equal bit for bit;
- FMI 2.0 semantics: calls in the wrong state, bad parameters and inputs return fmi2Error
  with the Python FMU's message; FMU state (with buffers) restores bit-identically.
"""

from __future__ import annotations

import ctypes
import os
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from scipy.linalg import expm

from delaycomp.fmu.build import DEFAULT_CONFIG, FMUS
from delaycomp.fmu.host import host_argv, unpack
from delaycomp.fmu.native import (
    CFLAGS,
    COMMON_SOURCES,
    NATIVE_KINDS,
    SOURCE_DIR,
    NativeBuildError,
    build_native_fmu,
    compiler,
    fmi_header_dir,
)
from delaycomp.fmu.twins import native_fmus
from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused
from delaycomp.orchestrator.inprocess import SlaveComponent, SlaveRefused
from delaycomp.orchestrator.simulate import make_master, parameters_of, run_loop, stop_ticks
from delaycomp.paper import scenarios
from delaycomp.paper.scenarios import lti_loop
from delaycomp.verify.check import CASES, compare

from .conftest import machine_blas_settings
from .roundoff import SAME_ARITHMETIC_ULPS, assert_columns_close

pytestmark = pytest.mark.fmu

LTI_CASES = [c for c in CASES if c.scenario in ("example-3.6", "corollary-3.7")]


# -- the maths in C ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def linalg(tmp_path_factory):
    """linalg.c, grid.c and fmi2.c with a stub model, compiled with their symbols visible,
    called through ctypes."""
    tmp = tmp_path_factory.mktemp("linalg")
    (tmp / "config.h").write_text(
        "#define MODEL_HEADER \"stub.h\"\n#define NIN 1\n#define NOUT 1\n#define NVR 1\n"
        "#define NSTRING 0\n#define INSTANTIATION_TOKEN \"stub\"\n"
        "#define OUTPUT_NAMES \"['v']\"\n"
        "static const char *const VAR_NAME[NVR] = {\"v\"};\n"
        "static const char VAR_TYPE[NVR + 1] = \"r\";\n"
        "static const char VAR_CAUSALITY[NVR + 1] = \"p\";\n"
        "static const double REAL_START[NVR] = {0.0};\n"
        "static const int BOOLEAN_START[NVR] = {0};\n"
        "static const int INTEGER_START[NVR] = {0};\n")
    (tmp / "stub.h").write_text("#define NX NOUT\n#define NU NIN\n"
                                "typedef struct { int unused; } ModelData;\n")
    (tmp / "stub.c").write_text(
        '#include "native.h"\n'
        "int model_setup(Instance *c) { (void)c; return 0; }\n"
        "int model_step(Instance *c, double t, double h) { (void)c; (void)t; (void)h; "
        "return 0; }\n"
        "int model_output(Instance *c, ValueRef vr, double *v) { (void)c; "
        "(void)vr; *v = 0; return 0; }\n"
        "void model_input_set(Instance *c) { (void)c; }\n"
        "int model_state_ok(const StateView *v) { return v->nbuf == 0; }\n")
    lib = tmp / "liblinalg.so"
    flags = [f for f in CFLAGS if f != "-fvisibility=hidden"]
    subprocess.run([*compiler(), *flags, "-I", str(tmp), "-I", str(SOURCE_DIR), "-I",
                    str(fmi_header_dir()), "-o", str(lib),
                    *(str(SOURCE_DIR / f) for f in ("linalg.c", "grid.c", *COMMON_SOURCES)),
                    str(tmp / "stub.c"), "-lm"], check=True)
    return ctypes.CDLL(str(lib))


class _Num(ctypes.Structure):
    _fields_ = [("s", ctypes.c_char * 40)]


def test_numbers_in_messages_are_written_as_python_repr(linalg):
    """The messages name values as the Python FMUs do (``repr``)."""
    linalg.num.restype = _Num
    linalg.num.argtypes = [ctypes.c_double]
    rng = np.random.default_rng(3)
    values = [0.0, -0.0, 1.0, 0.3, 0.1 + 0.2, 800.0, 1e16, 1e15, 123456789.0, 1e-4, 1e-5,
              2.0 ** -24, 2.0 ** -30, 2.0 ** 60, *(2.0 ** -k for k in range(1, 80, 7)),
              1.5e-7, -2.5, 5e-324, 1.7976931348623157e308, float("nan"), float("inf"),
              -float("inf"), *(rng.standard_normal(50) * 10.0 ** rng.integers(-8, 20, 50))]
    values += list(rng.random(300) * 10.0 ** rng.integers(-12, 12, 300))
    for v in values:
        assert linalg.num(v).s.decode() == repr(float(v))


def test_grid_rules_are_python_s(linalg):
    """grid.c, the one copy of the grid's rules in C (every native model's answer whether a
    value is a whole number of a step), answers as delaycomp.maths.grid on each value:
    round-off of decimal inputs, just inside and outside GRID_RTOL, ties (to even), huge,
    tiny, zero, negative and non-finite ratios."""
    from delaycomp.maths import grid

    dbl = ctypes.c_double
    linalg.nearest_multiple.restype = ctypes.c_int
    linalg.nearest_multiple.argtypes = [dbl, dbl, ctypes.POINTER(dbl)]
    linalg.steps_up.restype = dbl
    linalg.steps_up.argtypes = [dbl, dbl]
    linalg.split.restype = None
    linalg.split.argtypes = [dbl, dbl, ctypes.POINTER(dbl), ctypes.POINTER(dbl)]
    linalg.padded_delay.restype = dbl
    linalg.padded_delay.argtypes = [dbl, dbl]
    rng = np.random.default_rng(52)
    steps = [0.01, 0.1, 0.3, 1.0, 0.005, 1e-7, 3.0]
    values = [0.0, -0.0, 0.3, 0.36, 0.361, 0.305, 2.5, 0.5, 1.5, 2.0, 1e6, 1e-320,
              float("inf"), -float("inf"), float("nan"), -0.3, -2.5, 1e300]
    cases = [(v, s) for v in values for s in steps]
    for s in steps:  # k s, and k s (1 +- d) for d on either side of GRID_RTOL
        for k in (*range(0, 40), *rng.integers(0, 10 ** 6, 30)):
            for d in (0.0, 1e-16, 5e-10, 9.9e-10, 1.01e-9, 2e-9, 1e-6):
                for sign in (1.0, -1.0):
                    cases.append((float(k) * s * (1 + sign * d), s))
            cases.append(((float(k) + 0.5) * s, s))
    cases += [(float(v), float(s)) for v, s in zip(rng.random(500) * 100,
                                                   rng.random(500) * 0.1 + 1e-3)]
    for value, step in cases:
        k = dbl(-7.0)
        on = linalg.nearest_multiple(value, step, ctypes.byref(k))
        want = grid.nearest_multiple(value, step)
        assert (k.value if on else None) == want, (value, step)
        if not (np.isfinite(value) and value >= 0):
            continue
        assert linalg.steps_up(value, step) == grid.steps_up(value, step), (value, step)
        q, rest = dbl(), dbl()
        linalg.split(value, step, ctypes.byref(q), ctypes.byref(rest))
        assert (q.value, rest.value) == grid.split(value, step), (value, step)
        assert linalg.padded_delay(value, step) == grid.padded_delay(value, step)


def _c_expm(lib, a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=float)
    out = np.zeros_like(a)
    dbl = ctypes.POINTER(ctypes.c_double)
    n = a.shape[0]
    lib.expm_work_size.restype = ctypes.c_size_t
    work = np.full(lib.expm_work_size(ctypes.c_size_t(n)), np.nan)  # garbage: never read
    assert work.size == 7 * n * n
    lib.expm(a.ctypes.data_as(dbl), ctypes.c_size_t(n), out.ctypes.data_as(dbl),
             work.ctypes.data_as(dbl))
    return out


def _matrices():
    rng = np.random.default_rng(15)
    cases = {f"random{n}-scale{s}": rng.standard_normal((n, n)) * s
             for n in (2, 3, 5, 8) for s in (1e-3, 0.3, 1.0, 4.0, 20.0)}
    # stiff-ish: eigenvalues from -1e3 to -1e-2, non-normal through a similarity
    V = rng.standard_normal((4, 4))
    cases["stiff"] = V @ np.diag([-1e3, -10.0, -1.0, -1e-2]) @ np.linalg.inv(V) * 0.01
    cases["jordan"] = np.array([[-50.0, 100.0, 0.0], [0.0, -50.0, 100.0], [0.0, 0.0, -50.0]])
    cases["augmented"] = np.array([[1.5, 0.3], [0.0, 0.0]])  # the closed-form 2 x 2 case
    cases["scalar"] = np.array([[0.7]])
    return cases


@pytest.mark.parametrize("name", sorted(_matrices()))
def test_expm_in_c_matches_scipy(linalg, name):
    a = _matrices()[name]
    got, want = _c_expm(linalg, a), expm(a)
    # Both are backward stable (Pade + scaling and squaring); their forward errors, relative
    # to the largest entry of e^A, are about cond(exp, A) * eps. That condition number is
    # at least ||A|| and, for these non-normal matrices, up to a few hundred times it
    # (measured: 2e-12 = 170 ||A||_1 eps for random3-scale20, ||A||_1 = 54).
    tol = 1e3 * max(1.0, np.abs(a).sum(axis=0).max()) * np.finfo(float).eps
    assert np.max(np.abs(got - want)) <= tol * np.max(np.abs(want))


@pytest.mark.parametrize("n,m,s", [(1, 1, 0.01), (2, 1, 1.0), (3, 2, 0.3), (4, 2, 2.5)])
def test_flow_in_c_matches_scipy(linalg, n, m, s):
    """E = e^{As}, G = int_0^s e^{Aw} dw B (the exact discretization and the predictor's
    integrals), against Van Loan's exponential in scipy and a quadrature of the integral."""
    rng = np.random.default_rng(n * 10 + m)
    A, B = rng.standard_normal((n, n)), rng.standard_normal((n, m))
    E, G = np.zeros((n, n)), np.zeros((n, m))
    dbl = ctypes.POINTER(ctypes.c_double)
    linalg.flow_work_size.restype = ctypes.c_size_t
    # garbage in the work memory: flow must not read what it did not write
    work = np.full(linalg.flow_work_size(ctypes.c_size_t(n), ctypes.c_size_t(m)), np.nan)
    assert work.size == 9 * (n + m) ** 2
    linalg.flow(A.ctypes.data_as(dbl), B.ctypes.data_as(dbl), ctypes.c_size_t(n),
                ctypes.c_size_t(m), ctypes.c_double(s), E.ctypes.data_as(dbl),
                G.ctypes.data_as(dbl), work.ctypes.data_as(dbl))
    assert np.max(np.abs(E - expm(A * s))) <= 1e-12 * np.max(np.abs(E))
    # Gauss-Legendre with 30 nodes: exact to round-off for this smooth integrand
    w_nodes, w = np.polynomial.legendre.leggauss(30)
    ws = (w_nodes + 1) * s / 2
    G_quad = sum(wi * expm(A * t) for wi, t in zip(w, ws)) @ B * (s / 2)
    assert np.max(np.abs(G - G_quad)) <= 1e-12 * np.max(np.abs(G))


# -- the FMUs in our master ---------------------------------------------------------------
def _spec(c):
    return c.loop()


@pytest.mark.parametrize("c", LTI_CASES, ids=lambda c: c.id)
def test_native_equals_python_fmus_and_reference(native_dir, fmu_dir, c):
    spec = _spec(c)
    stop = c.stop_time()
    native = run_loop(spec, stop, fmus=native_fmus(spec, native_dir / "cache"))
    python = run_loop(spec, stop, fmu_dir / "cache")
    assert native.success and python.success, (native.message, python.message)
    assert native.names == python.names
    peak = np.max(np.abs(python.data), axis=0)
    # same maths, different rounding of expm and of the sums (measured <= 4e-14)
    assert np.all(np.abs(native.data - python.data) <= 1e-12 * peak)
    cmp = compare(c, native.names, native.times, native.data)
    assert cmp.passed, cmp


def random_mimo_loop():
    """A random loop: n = 3 states, m = 2 inputs, ``T = 0.5``, ``r = 0.35``
    (a fractional part of ``T``), ``tau = 0.5``, ``N = 10``, compensated."""
    rng = np.random.default_rng(7)
    A = rng.standard_normal((3, 3)) * 0.5
    B = rng.standard_normal((3, 2))
    K = -rng.standard_normal((2, 3)) * 0.3
    return lti_loop(A, B, K, T=0.5, r=0.35, tau=0.5, N=10, mode="compensated",
                    x0=(1.0, -0.5, 0.25), u0=(0.3, -0.2))


def test_native_equals_inprocess_on_a_random_mimo_loop(native_dir):
    """n = 3 states, m = 2 inputs, r and tau with a fractional part of r: every block of
    the predictor (E, Q_p B for p <= l + q, Q_{l+q+1} B with r~) enters."""
    spec = random_mimo_loop()
    native = run_loop(spec, 5.0, fmus=native_fmus(spec, native_dir / "mimo"))
    python = run_loop(spec, 5.0, engine="inprocess")
    assert native.success, native.message
    peak = np.max(np.abs(python.data), axis=0)
    assert np.all(np.abs(native.data - python.data) <= 1e-12 * peak)


# -- the C host, no Python in the process ---------------------------------------------------
@pytest.mark.parametrize("c", LTI_CASES[:3], ids=lambda c: c.id)
def test_c_host_without_python_equals_our_master(native_dir, chost, tmp_path, c):
    spec = _spec(c)
    stop = c.stop_time()
    fmus = native_fmus(spec, native_dir / "cache")
    dirs = unpack(fmus, tmp_path)
    proc = subprocess.run(["env", "-i", *machine_blas_settings(),
                           *host_argv(chost, spec, stop, dirs)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == "time,plant.x,controller.u"
    rows = np.array([line.split(",") for line in lines[1:]], dtype=float)
    ours = run_loop(spec, stop, fmus=fmus)
    assert rows.shape == (stop_ticks(stop, spec.T, spec.N) + 1, 3)
    assert np.allclose(rows[:, 0], ours.times, rtol=0, atol=1e-12)
    # same FMU binaries, same calls in the same order: the same numbers (two processes:
    # to the last bits)
    assert_columns_close(rows[:, 1:], ours.data, SAME_ARITHMETIC_ULPS, "C host")


def test_c_host_runs_a_vector_loop_and_an_exact_grid(native_dir, chost, tmp_path):
    """A MIMO loop (3 states, 2 inputs) in the C host: our master's numbers (same binaries,
    same calls); with ``--exact-grid`` (steps ``t_{k+1} - t_k`` of ``t_k = k h``, off from
    ``h`` in the last bits) the very same numbers, bit for bit: from ``t0 = 0`` the first
    step is ``h`` exactly, every later one is ``h`` for the FMUs' grid rule
    (``delaycomp.maths.grid.same_step``), so the plant reuses ``Ad(h), Bd(h)`` and the delays and
    the controller do what they do on constant steps."""
    spec = random_mimo_loop()
    fmus = native_fmus(spec, native_dir / "mimo")
    dirs = unpack(fmus, tmp_path)
    runs = {}
    for exact in (False, True):
        proc = subprocess.run(["env", "-i", *machine_blas_settings(),
                               *host_argv(chost, spec, 20.0, dirs, exact_grid=exact)],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        lines = proc.stdout.splitlines()
        assert lines[0] == ("time,plant.x1,plant.x2,plant.x3,controller.u1,controller.u2")
        runs[exact] = np.array([line.split(",") for line in lines[1:]], dtype=float)
    steps = np.diff(np.arange(401) * (spec.T / spec.N))
    assert len(set(steps.tolist())) > 1  # the exact grid's steps are not all h
    assert np.array_equal(runs[True], runs[False])
    ours = run_loop(spec, 20.0, fmus=fmus)
    assert runs[False].shape == (401, 6)
    assert_columns_close(runs[False][:, 1:], ours.data, SAME_ARITHMETIC_ULPS, "C host")
    bad = subprocess.run([str(chost), "--exact", "1", "0.1"], capture_output=True, text=True)
    assert bad.returncode == 1
    assert bad.stderr == ("host: error: unknown option --exact (allowed: --timing, "
                          "--exact-grid, --start=T0)\n")
    for start in ("--start=", "--start=x", "--start=nan", "--start=1e5x"):
        bad = subprocess.run([str(chost), start, "1", "0.1"], capture_output=True, text=True)
        assert bad.returncode == 1 and f"unknown option {start} " in bad.stderr


def test_native_binary_needs_only_libc_and_libm(native_dir, tmp_path):
    for ident in ("DelaycompDelay", "DelaycompPlantLTI", "DelaycompControllerLTI"):
        with zipfile.ZipFile(native_dir / f"{ident}.fmu") as zf:
            so = Path(zf.extract(f"binaries/linux64/{ident}.so", tmp_path))
        out = subprocess.run(["readelf", "-d", str(so)], capture_output=True, text=True,
                             check=True).stdout
        needed = {line.split("[")[1].split("]")[0] for line in out.splitlines()
                  if "(NEEDED)" in line}
        assert needed <= {"libc.so.6", "libm.so.6"}, needed


# -- the build -------------------------------------------------------------------------------
def _source_files(md) -> list[str]:
    return md.buildConfigurations[0].sourceFileSets[0].sourceFiles


def assert_same_table(nat, py) -> None:
    """Two model descriptions (fmpy's) with the same variables (names, value references,
    types, causalities, variabilities, starts, descriptions) and output dependencies."""
    def table(md):
        return [(v.name, v.valueReference, v.type, v.causality, v.variability, v.start,
                 v.description) for v in md.modelVariables]

    assert table(nat) == table(py)
    assert [(u.variable.name, [d.name for d in u.dependencies]) for u in nat.outputs] == \
        [(u.variable.name, [d.name for d in u.dependencies]) for u in py.outputs]


@pytest.mark.parametrize("kind", sorted(NATIVE_KINDS))
def test_native_model_description_is_the_python_table(native_dir, fmu_dir, kind):
    ident = FMUS[kind].model_identifier
    nat = read_model_description(str(native_dir / f"{ident}.fmu"), validate=True)
    py = read_model_description(str(fmu_dir / f"{ident}.fmu"), validate=True)
    assert_same_table(nat, py)
    cs = nat.coSimulation
    assert not cs.needsExecutionTool and cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    # the FMI layer, the shared sources of the model's manifest, the model's own C
    uses = {"plant": ["linalg.c"], "delay": ["grid.c"], "channel": ["draws.c", "grid.c"],
            "controller": ["linalg.c", "grid.c", "held.c"],
            "stamped_controller": ["linalg.c", "held.c"]}[kind]
    assert _source_files(nat) == ["fmi2.c", "core.c", "native.c", "pyrepr.c", *uses,
                                  NATIVE_KINDS[kind]]
    assert nat.guid != py.guid
    assert "-fvisibility=hidden" in CFLAGS and "-Werror" in CFLAGS


@pytest.mark.parametrize("kind", sorted(NATIVE_KINDS))
def test_sources_in_the_fmu_compile_on_their_own(native_dir, tmp_path, kind):
    """An importer compiles the FMU from its sources/ folder alone (strict warnings)."""
    ident = FMUS[kind].model_identifier
    with zipfile.ZipFile(native_dir / f"{ident}.fmu") as zf:
        zf.extractall(tmp_path)
    md = read_model_description(str(native_dir / f"{ident}.fmu"))
    src = tmp_path / "sources"
    subprocess.run([*compiler(), *CFLAGS, "-I", str(src), "-o", str(tmp_path / "x.so"),
                    *(str(src / f) for f in _source_files(md)), "-lm"], check=True)


def test_build_is_reproducible(native_dir, tmp_path):
    again = build_native_fmu("controller", tmp_path)
    with zipfile.ZipFile(again) as a, zipfile.ZipFile(native_dir / again.name) as b:
        assert a.read("modelDescription.xml") == b.read("modelDescription.xml")
        assert a.read("sources/config.h") == b.read("sources/config.h")


def test_no_compiler_is_one_line_naming_what_to_install(monkeypatch, tmp_path):
    """No zig (``DELAYCOMP_ZIG`` empty: the ziglang wheel is not used) and no system
    compiler: one line naming both ways to get one."""
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setenv("DELAYCOMP_ZIG", "")
    monkeypatch.setenv("PATH", str(tmp_path))  # an empty folder: no cc, gcc or clang
    with pytest.raises(NativeBuildError) as info:
        build_native_fmu("delay", tmp_path)
    msg = str(info.value)
    assert "\n" not in msg and "no C compiler found" in msg and "apt-get install gcc" in msg
    assert "pip install 'delaycomp[native]'" in msg


def test_cli_no_compiler_exit_status_and_one_line(tmp_path):
    env = {**os.environ, "PATH": str(tmp_path), "CC": "", "DELAYCOMP_ZIG": ""}
    env.pop("CC")
    from delaycomp.child import module_argv

    proc = subprocess.run(module_argv("delaycomp.cli", "build", "--native", "--out",
                                      str(tmp_path / "out")),
                          capture_output=True, text=True, env=env)
    assert proc.returncode == 1
    assert proc.stderr.strip().count("\n") == 0 and "install" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_run_native_refuses_a_loop_with_a_users_fmu_file(tmp_path):
    """A user's FMU (another tool's plant) has no native twin to build: refused, naming
    the instance. (A model file's plant and controller have one:
    tests/test_native_model_controller.py.)"""
    import dataclasses

    from delaycomp.system.loop import FmuFile

    sc = scenarios.get("example-3.8")
    loop = sc.make(sc.resolve([]))
    loop = dataclasses.replace(loop, instances=[
        dataclasses.replace(i, source=FmuFile(tmp_path / "theirs.fmu")) if i.name == "plant"
        else i for i in loop.instances])
    with pytest.raises(ValueError, match="--native is not allowed for this loop: instance "
                                         "'plant' is a user's FMU file"):
        native_fmus(loop)


# -- FMI 2.0 semantics ---------------------------------------------------------------------------
def _component(native_dir, kind, name="x") -> FmuComponent:
    return FmuComponent(name, native_dir / f"{FMUS[kind].model_identifier}.fmu")


BAD_PARAMETERS = [
    ("delay", {"delay": -0.5}),
    ("delay", {"u0[1]": float("nan")}),
    ("plant", {"A[1,1]": float("inf")}),
    ("controller", {"T": 0.0}),
    ("controller", {"r": -1.0}),
    ("controller", {"T": 1.0, "tau": 0.5}),
    ("controller", {"mode": "predictive"}),
    ("controller", {"T": 1e-7, "r": 1.0}),
    ("controller", {"A[1,1]": 800.0, "r": 1.0, "B[1,1]": 1.0}),
]


@pytest.mark.parametrize("kind,params", BAD_PARAMETERS, ids=lambda p: str(p))
def test_bad_parameter_is_fmi2error_with_the_python_message(native_dir, kind, params):
    slave = SlaveComponent("x", kind, dict(DEFAULT_CONFIG[kind]))
    slave.setup(0.0, 10.0, params)
    comp = _component(native_dir, kind)
    try:
        comp.setup(0.0, 10.0, params)
        assert_initialize_refused_alike(slave, comp)
    finally:
        comp.terminate()


def assert_initialize_refused_alike(slave, comp) -> None:
    """The Python slave and the native FMU, set up alike, both refuse to initialize: the
    FMU with fmi2Error, and with the slave's message."""
    with pytest.raises(SlaveRefused):
        slave.initialize()
    with pytest.raises(FMICallException) as info:
        comp.initialize()
    assert info.value.status == 3  # fmi2Error
    assert comp.last_message == slave.last_message


def test_bad_input_and_bad_step_are_fmi2error_with_the_python_message(native_dir):
    for step, inputs in (((0.0, 0.1), {"u": float("nan")}), ((0.0, -0.1), {"u": 1.0})):
        slave = SlaveComponent("x", "delay", {"n": 1})
        comp = _component(native_dir, "delay")
        try:
            for c in (slave, comp):
                c.setup(0.0, 1.0, {"delay": 0.2})
            assert_step_refused_alike(slave, comp, inputs, step)
        finally:
            comp.terminate()


def assert_step_refused_alike(slave, comp, inputs: dict, step) -> None:
    """Both, set up alike, initialized and given ``inputs``, refuse ``do_step(*step)``,
    the FMU with the slave's message."""
    for c in (slave, comp):
        c.initialize()
        c.set_inputs(list(inputs), list(inputs.values()))
    with pytest.raises(SlaveRefused):
        slave.do_step(*step)
    with pytest.raises(FMICallException):
        comp.do_step(*step)
    assert comp.last_message == slave.last_message


def _latest(comp) -> str:
    """The newest logged message (``last_message`` keeps the first error)."""
    return comp.messages[-1].split("] ", 1)[1]


def test_a_step_over_a_sampling_instant_is_refused(native_dir):
    comp = _component(native_dir, "controller")
    try:
        comp.setup(0.0, 10.0, {"T": 1.0})
        comp.initialize()
        with pytest.raises(FMICallException):
            comp.do_step(0.0, 1.5)
        assert comp.last_message == ("step [0.0, 1.5] is not allowed: it passes over the "
                                     "sampling instant 1.0; steps must end on t0 + iT")
        # the error state: a further step is refused, naming the state
        with pytest.raises(FMICallException):
            comp.do_step(1.5, 0.5)
        assert "fmi2DoStep is not allowed in state 'error'" in _latest(comp)
    finally:
        comp.terminate()


def test_calls_in_the_wrong_state_are_refused(native_dir):
    comp = _component(native_dir, "plant")
    try:
        comp.setup(0.0, 1.0, {})
        fmu = comp.fmu
        with pytest.raises(FMICallException):  # in initialization mode
            fmu.doStep(0.0, 0.1)
        assert "fmi2DoStep is not allowed in state 'initialization mode'" in _latest(comp)
        fmu.exitInitializationMode()
        with pytest.raises(FMICallException):  # a fixed parameter after initialization
            fmu.setReal([0], [2.0])
        assert "A[1,1] is a fixed parameter" in _latest(comp)
        with pytest.raises(FMICallException):
            fmu.setReal([4], [2.0])  # the output x
        assert "x is an output" in _latest(comp)
        with pytest.raises(FMICallException):
            fmu.getReal([99])
        assert "value reference 99 is not allowed" in _latest(comp)
        with pytest.raises(FMICallException):
            fmu.enterInitializationMode()
        fmu.doStep(0.0, 0.1)  # still usable: wrong calls do not change the state
        fmu.terminate()
        with pytest.raises(FMICallException):
            fmu.doStep(0.1, 0.1)
        assert "state 'terminated'" in _latest(comp)
        fmu.reset()  # back to instantiated, start values
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        assert fmu.getReal([4]) == [0.0]
    finally:
        comp.fmu.freeInstance()
        comp.fmu = None
        comp.terminate()


def test_terminate_after_a_fault_is_accepted_as_by_the_python_fmus(native_dir):
    """A host ends every instance of a failed run with fmi2Terminate: after a refused step
    both twins accept it (refused, OMSimulator's command line then called instances it had
    freed: a use-after-free and a double free in the host)."""
    slave = SlaveComponent("x", "delay", {"n": 1})
    comp = _component(native_dir, "delay")
    try:
        for c in (slave, comp):
            c.setup(0.0, 1.0, {"delay": 0.2})
        assert_step_refused_alike(slave, comp, {"u": 1.0}, (0.0, -0.1))
        slave.slave.terminate()  # pythonfmu's fmi2Terminate: accepted (no error logged)
        assert slave.slave.phase == "terminated"
        comp.fmu.terminate()  # fmi2OK: fmpy raises on anything else
        with pytest.raises(FMICallException):
            comp.fmu.doStep(0.0, 0.1)
        assert "state 'terminated'" in _latest(comp)
    finally:
        comp.fmu.freeInstance()
        comp.fmu = None
        comp.terminate()


def test_a_roundoff_sliver_step_of_the_delay_moves_nothing(native_dir):
    """OMSimulator adds h to its time and ends 1.7e-13 s short of the stop time, then
    takes that sliver: the delay (Python and native) accepts it and does not shift."""
    slave = SlaveComponent("x", "delay", {"n": 1})
    comp = _component(native_dir, "delay")
    try:
        outs = []
        for c in (slave, comp):
            c.setup(0.0, 1.0, {"delay": 0.2})
            c.initialize()
            for k in range(5):
                c.set_inputs(["u"], [float(k + 1)])
                c.do_step(k * 0.1, 0.1 - (1e-13 if k == 4 else 0.0))
            c.do_step(0.5 - 1e-13, 1e-13)
            c.set_inputs(["u"], [9.0])
            outs.append(c.get_outputs(["y"]))
            c.do_step(0.5, 0.1)
            outs.append(c.get_outputs(["y"]))
        assert outs[:2] == outs[2:] == [[4.0], [5.0]]
    finally:
        comp.terminate()


def _restore_run(fmus, spec, stop, save_at):
    ticks = stop_ticks(stop, spec.T, spec.N)
    master, rec = make_master(spec, fmus=fmus)
    try:
        master.setup(stop, parameters_of(spec))
        master.initialize()
        master.run_until(save_at)
        state = master.get_state()
        n0 = len(rec.rows)
        master.run_until(ticks)
        first = rec.rows[n0:]
        master.set_state(state)
        n1 = len(rec.rows)
        master.run_until(ticks)
        second = rec.rows[n1:]
    finally:
        master.terminate()
    fresh, rec2 = make_master(spec, fmus=fmus)
    try:
        fresh.setup(stop, parameters_of(spec))
        fresh.initialize()
        n2 = len(rec2.rows)
        fresh.set_state(state)
        fresh.run_until(ticks)
        third = rec2.rows[n2:]
    finally:
        fresh.terminate()
    return first, second, third


@pytest.mark.parametrize("held", [False, True], ids=["direct", "held_sample"])
def test_fmu_state_with_buffers_continues_bit_identically(native_dir, held):
    sc = scenarios.get("example-3.6")
    spec = sc.make(sc.resolve(["r=0.5", "tau=1", "u0=4", "N=4"]))
    if held:
        from delaycomp.verify.thirdparty import jacobi_variant

        spec = jacobi_variant(spec)
    fmus = native_fmus(spec, native_dir / "state")
    ticks = stop_ticks(6.0, spec.T, spec.N)
    save_at = (ticks // 2) // spec.N * spec.N if held else ticks // 2 + 1
    first, second, third = _restore_run(fmus, spec, 6.0, save_at)
    assert len(first) > 5
    assert second == first and third == first


def test_foreign_or_corrupt_state_is_refused_and_double_free_is_harmless(native_dir):
    plant, delay = _component(native_dir, "plant", "p"), _component(native_dir, "delay", "d")
    try:
        for c in (plant, delay):
            c.setup(0.0, 1.0, {})
            c.initialize()
        with pytest.raises(FMICallException):
            plant.set_state(delay.get_state())
        # refused by its size or its contents (the two models' Data differ in size)
        assert "not allowed" in _latest(plant) and "state of this FMU" in _latest(plant)
        data = bytearray(plant.get_state())
        with pytest.raises(FMICallException):
            plant.set_state(bytes(data[:-3]))
        data[200:208] = b"\xff" * 8  # inside the state: the check must catch or ignore it
        try:
            plant.set_state(bytes(data))
        except (FMICallException, FmuRefused):
            pass
        state = plant.fmu.getFMUstate()
        plant.fmu.freeFMUstate(state)
        plant.fmu.freeFMUstate(state)  # fmi2FreeFMUstate set it to NULL: a no-op
    finally:
        plant.terminate()
        delay.terminate()


def test_python_fmus_in_the_c_host_with_the_three_settings(chost, fmu_dir, tmp_path):
    """The recipe of the Python FMUs' READMEs ("In a host without Python"): the C host
    runs the pythonfmu FMUs with LD_PRELOAD of libpython, PYTHONHOME and PYTHONPATH, and
    gives our master's numbers bit for bit (same slave code, same calls)."""
    import sys
    import sysconfig

    sc = scenarios.get("example-3.6")
    spec = sc.make(sc.resolve(["r=0.3", "u0=4", "mode=compensated"]))
    from delaycomp.fmu.cache import fmu_path

    fmus = {i.name: fmu_path(*i.source.build_key(), fmu_dir / "cache") for i in spec.instances}
    libpython = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("LDLIBRARY")
    assert libpython.exists(), "this Python has no shared libpython: the recipe needs one"
    settings = [f"LD_PRELOAD={libpython}", f"PYTHONHOME={sys.base_prefix}",
                f"PYTHONPATH={sysconfig.get_paths()['purelib']}", *machine_blas_settings()]
    proc = subprocess.run(["env", "-i", *settings,
                           *host_argv(chost, spec, 20.0, unpack(fmus, tmp_path))],
                          capture_output=True, text=True, timeout=300)
    rows = np.array([line.split(",") for line in proc.stdout.splitlines()[1:]], dtype=float)
    ours = run_loop(spec, 20.0, fmus=fmus)
    assert rows.shape == (2001, 3), proc.stderr
    assert_columns_close(rows[:, 1:], ours.data, SAME_ARITHMETIC_ULPS, "C host")
    # pythonfmu finalizes Python in a thread of its own at unload: hosts may crash at exit
    # after a complete run (abort or segfault; measured 0 in 5 of 5 runs here with 3.11)
    assert proc.returncode in (0, -6, -11, 134, 139), proc.stderr


# -- native FMUs in the SSP archives and the Jacobi variant (the container: see
# test_native_model_controller) ------------------------------------------------------------
@pytest.mark.parametrize("master", ["delaycomp", "libcosim", "ecos"])
def test_jacobi_archive_with_native_fmus_in_every_master(tmp_path, master):
    """``delaycomp ssp --jacobi --native``: libcosim and Ecos load the native FMUs from the
    archive (held_sample, shortened measurement delay) and reproduce the reference within
    the cross-check's tolerance, and the Python FMUs' run to 1e-12 of the peak."""
    from delaycomp.fmu.native import native_archive
    from delaycomp.formats.ssp import Archive
    from delaycomp.verify.check import case
    from delaycomp.verify.thirdparty import pack_jacobi, run_ssp

    c = case("example-3.6/fig3")
    python = pack_jacobi(c.loop(), tmp_path / "case.ssp", parameter_set=c.case)
    native = native_archive(python, tmp_path / "native.ssp")
    with zipfile.ZipFile(native) as zf:
        inner = [n for n in zf.namelist() if n.endswith(".fmu")]
        assert inner
        for name in inner:
            (tmp_path / Path(name).name).write_bytes(zf.read(name))
            md = read_model_description(str(tmp_path / Path(name).name))
            assert not md.coSimulation.needsExecutionTool  # the native twin
    if master == "delaycomp":
        with Archive(native) as archive:
            a = run_loop(archive.system.spec, c.stop_time(), fmus=archive.fmus())
        with Archive(python) as archive:
            b = run_loop(archive.system.spec, c.stop_time(), fmus=archive.fmus())
    else:
        a, b = run_ssp(master, native, c.stop_time()), run_ssp(master, python, c.stop_time())
    assert a.success and b.success, (a.message, b.message)
    assert compare(c, a.names, a.times, a.data).passed
    assert np.all(np.abs(a.data - b.data) <= 1e-12 * np.max(np.abs(b.data), axis=0))


def test_native_archive_refuses_an_fmu_without_a_native_twin(tmp_path):
    """An FMU that is not delaycomp's (here: a model controller whose configuration lost
    its model id, as another tool's FMU has none) has no twin to build: refused, naming
    the file. (A model file's FMUs have one: tests/test_native_model_controller.py.)"""
    import shutil

    from delaycomp.fmu.native import native_archive
    from delaycomp.formats.ssp import pack, scenario_system

    spec, info = scenario_system("example-3.8", [])
    path = pack(spec, info, tmp_path / "m.ssp")
    hacked = tmp_path / "h.ssp"
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(hacked, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if "DelaycompController_" in item.filename:
                inner = tmp_path / "inner.fmu"
                inner.write_bytes(data)
                patched = tmp_path / "patched.fmu"
                with zipfile.ZipFile(inner) as a, zipfile.ZipFile(patched, "w") as b:
                    for it in a.infolist():
                        b.writestr(it, b"{}" if it.filename.endswith("delaycomp_fmu.json")
                                   else a.read(it))
                data = patched.read_bytes()
            zout.writestr(item, data)
    shutil.rmtree(tmp_path / "unused", ignore_errors=True)
    with pytest.raises(ValueError, match=r"resources/DelaycompController_example_3_8_\w+\.fmu "
                                         r"\(DelaycompController_example_3_8_\w+\) is not "
                                         "allowed in a native archive"):
        native_archive(hacked, tmp_path / "n.ssp")


# -- fuzz: the native FMUs refuse and accept exactly what the Python slaves do --------------
from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_WEIRD = [0.0, -0.0, 1e-300, 1e300, -1e300, float("nan"), float("inf"), -float("inf")]
_reals = st.one_of(st.floats(-3, 3), st.sampled_from(_WEIRD))
_inputs = st.one_of(st.floats(-100, 100), st.sampled_from(_WEIRD))


@given(T=st.one_of(st.sampled_from([0.5, 1.0, 0.1]), _reals),
       r=st.one_of(st.sampled_from([0.0, 0.3, 1.0, 1.25]), _reals),
       tau=st.one_of(st.sampled_from([0.0, 0.5, 1.0]), _reals),
       a=st.one_of(st.floats(-3, 3), st.sampled_from([w for w in _WEIRD if w != -1e300])),
       k=_reals, mode=st.sampled_from(["compensated", "uncompensated", "x"]),
       held=st.booleans(), ys=st.lists(_inputs, min_size=6, max_size=6))
def test_fuzz_native_controller_behaves_as_the_python_slave(native_dir, T, r, tau, a, k,
                                                            mode, held, ys):
    """Random parameters and inputs (finite, huge, non-finite): the native controller and
    the Python slave refuse the same calls with the same message, and otherwise give the
    same outputs to 1e-12 relative (the predictor's exponentials differ in rounding).
    A hugely negative ``A`` is left out: there the two differ on purpose (next test)."""
    params = {"T": T, "r": r, "tau": tau, "A[1,1]": a, "B[1,1]": 1.0, "K[1,1]": k,
              "u0[1]": 0.5, "mode": mode, "held_sample": held}
    slave = SlaveComponent("x", "controller", {"n": 1, "m": 1})
    comp = _component(native_dir, "controller")
    try:
        outcome = []
        for c, refused in ((slave, (SlaveRefused,)), (comp, (FMICallException, FmuRefused))):
            got = []
            try:
                c.setup(0.0, 100.0, params)
                c.initialize()
                h = T / 2
                for i, y in enumerate(ys):
                    c.set_inputs(["y"], [y])
                    got.append(c.get_outputs(["u"])[0])
                    c.do_step(i * h, h)
            except refused:
                got.append(("refused", c.last_message))
            outcome.append(got)
        assert_same_outcome(*outcome)
    finally:
        comp.terminate()


def assert_same_outcome(py: list, nat: list) -> None:
    """The Python slave's and the native FMU's outputs step by step, and the refusal that
    ended either run (same message), equal to 1e-12 relative (round-off of the exact
    flows)."""
    assert len(py) == len(nat)
    for p, n in zip(py, nat):
        if isinstance(p, tuple):
            assert p == n
        else:
            assert p == n or (np.isnan(p) and np.isnan(n)) or \
                abs(p - n) <= 1e-12 * max(1.0, abs(p))


def test_hugely_negative_a_native_is_exact_where_scipy_overflows(native_dir):
    """The one known difference: A = -1e300. e^{A s} is 0 and int_0^s e^{Aw} dw B is
    B / |A| for every s > 0, finite. scipy's expm of the augmented matrix overflows in its
    scaling, so the Python controller refuses A ("it overflows"); the native one uses the
    closed form of the scalar case and runs, with u = K Phi = K (0 y + ~1e-300 u0) = ~0."""
    params = {"T": 0.5, "r": 0.0, "tau": 0.5, "A[1,1]": -1e300, "B[1,1]": 1.0,
              "K[1,1]": 1.0, "u0[1]": 0.5}
    slave = SlaveComponent("x", "controller", {"n": 1, "m": 1})
    slave.setup(0.0, 10.0, params)
    with pytest.raises(SlaveRefused, match="it overflows"):
        slave.initialize()
    comp = _component(native_dir, "controller")
    try:
        comp.setup(0.0, 10.0, params)
        comp.initialize()
        comp.set_inputs(["y"], [2.0])
        u = comp.get_outputs(["u"])[0]
        assert 0.0 <= u <= 1e-299  # K (e^{-inf} y + G(T) u0) with G(T) = 1e-300
    finally:
        comp.terminate()


_moderate = st.one_of(st.floats(-3, 3), st.sampled_from([0.0, float("nan"), float("inf")]))


@given(kind=st.sampled_from(["delay", "plant"]),
       p1=st.one_of(st.sampled_from([0.0, 0.2, 0.25, 1.0]), _reals), p2=_moderate,
       p3=_moderate, h=st.one_of(st.sampled_from([0.1, 0.05]), _reals),
       us=st.lists(_inputs, min_size=5, max_size=5))
def test_fuzz_native_delay_and_plant_behave_as_the_python_slaves(native_dir, kind, p1, p2,
                                                                 p3, h, us):
    """As above for the delay (delay, u0, step size) and the plant (A, B, x0 with moderate
    A: a hugely negative one is exact in C and overflows in scipy, see the test above)."""
    params = ({"delay": p1, "u0[1]": p2} if kind == "delay"
              else {"A[1,1]": p2, "B[1,1]": p3, "x0[1]": p1})
    slave = SlaveComponent("x", kind, dict(DEFAULT_CONFIG[kind]))
    comp = _component(native_dir, kind)
    inp, out = ("u", "y") if kind == "delay" else ("u", "x")
    try:
        outcome = []
        for c, refused in ((slave, (SlaveRefused,)), (comp, (FMICallException, FmuRefused))):
            got = []
            try:
                c.setup(0.0, 100.0, params)
                c.initialize()
                for i, u in enumerate(us):
                    c.set_inputs([inp], [u])
                    got.append(c.get_outputs([out])[0])
                    c.do_step(i * h, h)
            except refused:
                got.append(("refused", c.last_message))
            outcome.append(got)
        assert_same_outcome(*outcome)
    finally:
        comp.terminate()


def test_concurrent_asks_for_one_cached_native_fmu_compile_it_once(tmp_path, monkeypatch):
    """The build cache (``native_fmu_path``, what ``run`` and the tests' workers ask)
    compiles a missing FMU under a lock named after it: four asking at once, one
    compiles, the others wait and take its file (before: each compiled its own)."""
    from concurrent.futures import ThreadPoolExecutor

    from delaycomp.fmu import native

    compiled = []
    build = native.build_native_fmu

    def counted(*args, **kwargs):
        compiled.append(args[0])
        return build(*args, **kwargs)

    monkeypatch.setattr(native, "build_native_fmu", counted)
    with ThreadPoolExecutor(max_workers=4) as pool:
        paths = list(pool.map(lambda _: native.native_fmu_path("delay", {"n": 2}, tmp_path),
                              range(4)))
    assert compiled == ["delay"] and len(set(paths)) == 1
    assert read_model_description(str(paths[0])).coSimulation.modelIdentifier == \
        "DelaycompDelay"


def test_concurrent_builds_of_one_native_fmu_give_one_whole_file(tmp_path):
    """Native FMUs are the default: two runs at once build the same FMU into the same
    cache. Each writes a part file of its own and renames it over the target, so every
    build succeeds and the file is a whole FMU (four builds at once, twice)."""
    from concurrent.futures import ThreadPoolExecutor

    from delaycomp.fmu.native import build_native_fmu

    for _ in range(2):
        with ThreadPoolExecutor(max_workers=4) as pool:
            paths = list(pool.map(lambda _: build_native_fmu("delay", tmp_path), range(4)))
        assert len(set(paths)) == 1
        assert read_model_description(str(paths[0])).coSimulation.modelIdentifier == \
            "DelaycompDelay"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["DelaycompDelay.fmu"]
