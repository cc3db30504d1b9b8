"""Issue 33, items 2 to 4: ``delaycomp export-c``, the controller as plain C.

- **Strict and cross builds**: each export compiles with ``-std=c99 -Wall -Wextra
  -pedantic -Werror`` for this machine (gcc and clang), for aarch64 and for a Cortex-M4
  (``arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb -mfloat-abi=hard -mfpu=fpv4-sp-d16``); the
  objects reference no ``malloc``, ``calloc``, ``realloc``, ``free`` and nothing of stdio,
  and hold no writable data (``.data`` and ``.bss`` empty: no global state).
- **Equal to the FMU**: a closed loop of the native FMUs (stepped here in the order of our
  master) records the controller FMU's measurements and outputs at every base step; a C
  driver (``tests/native_export/driver.c``) feeds the same measurements to the exported
  controller, whose outputs must equal the FMU's: 1e-12 of the peak for LTI (the matrices
  are scipy's, the FMU's its own C expm: both backward stable, their differences are
  round-off), ``10 tol (1 + |u|)`` for the models (the same C: measured equal to the
  last bit). The same driver built for aarch64 and run under qemu-aarch64 prints the same
  numbers. Padded loops (``pad = true``, Remark 3.3(b)), LTI and model: ``u_i`` reaches
  the output ``D`` base steps after ``t_i`` as in the FMU (an LTI loop with tau = 0.7,
  T = 0.5: measured 3.8e-16 of the peak; one tick off would be 1.7).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from delaycomp.errors import ParameterError
from delaycomp.fmu.native import compiler
from delaycomp.formats.exportc import EXPORT_CODES, check_prefix, closed_loop_io, export_c
from delaycomp.paper import scenarios
from tests.external import need
from tests.test_native_alloc import stable_mimo_loop
from tests.tiers import tiered

DRIVER = Path(__file__).parent / "native_export" / "driver.c"
#: a loop file whose plant is a model file (the tutorial's cart)
CART = Path(__file__).resolve().parents[1] / "docs" / "examples" / "cart.toml"
CLI = [sys.executable, "-m", "delaycomp"]
STRICT = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O2"]
CORTEX_M4 = ["arm-none-eabi-gcc", "-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard",
             "-mfpu=fpv4-sp-d16"]
#: the ODE tolerance of the model controllers (rtol = atol, delaycomp.maths.predictors)
TOL = 1e-10


def _scenario(name, sets):
    sc = scenarios.get(name)
    return sc.make(sc.resolve(sets))


#: every shipped scenario's controller (and the families, predictors and padding of the
#: models), and an LTI loop with n = 3, m = 2
LOOPS = {
    "example-3.6": lambda: _scenario("example-3.6", []),
    "example-3.6-uncompensated": lambda: _scenario("example-3.6", ["mode=uncompensated"]),
    "corollary-3.7-n3": lambda: _scenario("corollary-3.7", ["n=3"]),
    # pad (Remark 3.3(b)): tau = 0.7 padded to 1.0, u_i out at t_i + 0.3 (6 base steps)
    "corollary-3.7-padded": lambda: _scenario("corollary-3.7", [
        "n=2", "T=0.5", "tau=0.7", "N=10", "r=0.2", "pad=1"]),
    "example-3.6-padded-uncompensated": lambda: _scenario("example-3.6", [
        "T=0.5", "tau=0.7", "N=5", "r=0.2", "pad=1", "mode=uncompensated"]),
    "mimo-n3-m2": stable_mimo_loop,
    "example-2.4": lambda: _scenario("example-2.4", []),
    "example-2.4-numerical": lambda: _scenario("example-2.4", ["predictor=numerical"]),
    "example-3.8": lambda: _scenario("example-3.8", []),
    "example-3.8-padded": lambda: _scenario("example-3.8", ["tau=0.5", "pad=true"]),
    "example-3.8-sin-numerical": lambda: _scenario("example-3.8", ["p=sin",
                                                                   "predictor=numerical"]),
    "corollary-4.1": lambda: _scenario("corollary-4.1", []),
    "proposition-4.2": lambda: _scenario("proposition-4.2", []),
    "cart-loop-file": lambda: scenarios.open_source(str(CART)).loop([]),
    # no delay at all: an empty window (the prediction is the sample)
    "example-3.8-no-delay": lambda: _scenario("example-3.8", ["r=0", "tau=0",
                                                              "predictor=numerical"]),
    "example-2.4-no-delay": lambda: _scenario("example-2.4", ["r=0", "tau=0",
                                                              "predictor=numerical"]),
    "example-3.6-no-delay": lambda: _scenario("example-3.6", ["r=0"]),
}
LTI = {"example-3.6", "example-3.6-uncompensated", "example-3.6-no-delay", "corollary-3.7-n3",
       "mimo-n3-m2", "corollary-3.7-padded", "example-3.6-padded-uncompensated"}


def _tool(name: str) -> str:
    """The tool's path; where it is missing the test is skipped, and pytest's summary
    (``-ra``) names the tool, the package and what was not checked."""
    return need(name, what="the export built or run for its target")


def _driver(out: Path, prefix: str, cc: list[str], exe: Path) -> Path:
    subprocess.run([*cc, *STRICT, f"-DPREFIX={prefix}", "-include",
                    str(out / f"{prefix}.h"), "-I", str(out), str(DRIVER),
                    str(out / f"{prefix}.c"), "-o", str(exe), "-lm"], check=True)
    return exe


def _run_driver(argv: list[str], loop, ys: np.ndarray) -> np.ndarray:
    lines = "".join(f"{k * loop.h!r} " + " ".join(repr(float(v)) for v in y) + "\n"
                    for k, y in enumerate(ys))
    proc = subprocess.run(argv, input=lines, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-500:] + proc.stderr[-2000:]
    return np.array([line.split() for line in proc.stdout.splitlines()], dtype=float)


@pytest.mark.parametrize("name", tiered(sorted(LOOPS), {
    "example-3.6-uncompensated", "mimo-n3-m2", "example-2.4-numerical", "example-3.8-padded",
    "example-3.8-no-delay", "cart-loop-file", "corollary-3.7-padded"}))
def test_the_export_equals_the_controller_fmu(name, tmp_path):
    loop = LOOPS[name]()
    ticks = 6 * loop.N + 7  # six periods and a part
    ys, want = closed_loop_io(loop, ticks, tmp_path / "fmus")
    export_c(loop, tmp_path / "c", "ctl")
    exe = _driver(tmp_path / "c", "ctl", compiler(), tmp_path / "drive")
    got = _run_driver([str(exe)], loop, ys)
    assert got.shape == want.shape
    peak = np.max(np.abs(want))
    assert peak > 0 and len(np.unique(want)) > 3  # the control moves
    if name in LTI:
        assert np.max(np.abs(got - want)) <= 1e-12 * peak
    else:
        assert np.all(np.abs(got - want) <= 10 * TOL * (1 + np.abs(want)))


@pytest.mark.parametrize("name", ["mimo-n3-m2", "example-3.8-sin-numerical",
                                  "corollary-4.1"])
def test_the_aarch64_build_prints_the_same_numbers(name, tmp_path):
    """Under qemu-aarch64 (ISO C: no contraction into fused multiply-adds; the same libm
    algorithms): the very numbers of this machine's build."""
    from delaycomp.fmu.host import emulator

    _tool("aarch64-linux-gnu-gcc")
    _tool("qemu-aarch64")
    loop = LOOPS[name]()
    ticks = 3 * loop.N + 5
    ys, _ = closed_loop_io(loop, ticks, tmp_path / "fmus")
    export_c(loop, tmp_path / "c", "ctl")
    here = _run_driver([str(_driver(tmp_path / "c", "ctl", compiler(), tmp_path / "d"))],
                       loop, ys)
    exe = _driver(tmp_path / "c", "ctl", ["aarch64-linux-gnu-gcc"], tmp_path / "d64")
    prefix, _env = emulator("aarch64-linux")
    there = _run_driver([*prefix, str(exe)], loop, ys)
    assert np.array_equal(here, there)


#: the symbols an object of the export must not reference
FORBIDDEN = {"malloc", "calloc", "realloc", "free", "printf", "fprintf", "sprintf",
             "snprintf", "puts", "fputs", "fwrite", "fopen", "stdout", "stderr", "getenv",
             "exit", "abort"}


@pytest.mark.parametrize("target", ["gcc", "clang", "aarch64", "cortex-m4"])
@pytest.mark.parametrize("name", sorted(LOOPS))
def test_strict_builds_without_heap_io_or_global_state(name, target, tmp_path):
    cc = {"gcc": ["gcc"], "clang": ["clang"], "aarch64": ["aarch64-linux-gnu-gcc"],
          "cortex-m4": CORTEX_M4}[target]
    _tool(cc[0])
    nm = _tool("arm-none-eabi-nm" if target == "cortex-m4" else "nm")
    loop = LOOPS[name]()
    paths = export_c(loop, tmp_path, "ctl")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ctl.c", "ctl.h"]
    for path in paths:  # every name of the templates took the prefix
        assert "NAME" not in path.read_text(), path
    obj = tmp_path / "ctl.o"
    proc = subprocess.run([*cc, *STRICT, "-c", str(paths[1]), "-o", str(obj)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    symbols = subprocess.run([nm, str(obj)], capture_output=True, text=True,
                             check=True).stdout.split("\n")
    undefined = {line.split()[-1] for line in symbols if " U " in line}
    assert not undefined & FORBIDDEN, undefined
    defined = {line.split()[-1]: line.split()[-2] for line in symbols
               if len(line.split()) == 3}
    # the three functions, nothing else global; no writable data (D/d, B/b: .data, .bss)
    assert {s for s, kind in defined.items() if kind.isupper()} == {
        "ctl_init", "ctl_sample", "ctl_output"}
    assert not {s for s, kind in defined.items() if kind in "DdBbCc"}, defined


def test_two_controllers_link_into_one_program(tmp_path):
    """Two exports (an LTI and a numerical model controller, which carries DOP853) in one
    program: their names do not clash."""
    export_c(LOOPS["mimo-n3-m2"](), tmp_path, "lti")
    export_c(LOOPS["example-2.4-numerical"](), tmp_path, "nl")
    main = tmp_path / "main.c"
    main.write_text('#include "lti.h"\n#include "nl.h"\n'
                    "int main(void) {\n"
                    "    lti_state a; nl_state b; double y3[3] = {1, 2, 3}, u[2];\n"
                    "    lti_init(&a); nl_init(&b);\n"
                    "    if (lti_sample(&a, 0.0, y3) || lti_output(&a, 0.0, u)) return 1;\n"
                    "    if (nl_sample(&b, 0.0, y3) || nl_output(&b, 0.0, u)) return 2;\n"
                    "    return nl_output(&b, 0.0, u) == nl_E_ORDER ? 0 : 3;\n}\n")
    exe = tmp_path / "both"
    subprocess.run([*compiler(), *STRICT, "-I", str(tmp_path), str(main),
                    str(tmp_path / "lti.c"), str(tmp_path / "nl.c"), "-o", str(exe), "-lm"],
                   check=True)
    assert subprocess.run([str(exe)]).returncode == 0


def test_refused_calls_return_the_codes_of_the_header(tmp_path):
    """Each code of the header, for the call it names; a refused call changes nothing
    (the loop goes on as if it had not been made)."""
    export_c(LOOPS["example-3.6"](), tmp_path, "ctl")
    header = (tmp_path / "ctl.h").read_text()
    for name, (code, _) in EXPORT_CODES.items():
        assert f"#define ctl_{name} {code}" in header
    main = tmp_path / "main.c"
    main.write_text(r'''
#include <math.h>
#include <stdio.h>
#include "ctl.h"
int main(void) {
    ctl_state s;
    double y[1] = {0.5}, bad[1] = {NAN}, u[1];
    int k;
    ctl_init(&s);
    printf("%d\n", ctl_output(&s, 0.0, u));             /* before any sample */
    printf("%d\n", ctl_sample(&s, 0.0, bad));           /* NaN in y */
    printf("%d\n", ctl_sample(&s, INFINITY, y));        /* t not finite */
    printf("%d\n", ctl_sample(&s, 1.0, y));             /* the first sample: t0 = 1 */
    printf("%d\n", ctl_output(&s, 1.0 + 0.5 * ctl_H, u)); /* off the grid */
    printf("%d\n", ctl_output(&s, 1.0 + ctl_H, u));     /* a tick ahead */
    printf("%d\n", ctl_output(&s, 1.0, u));             /* tick 0 */
    printf("%d\n", ctl_output(&s, 1.0, u));             /* tick 0 again */
    printf("%d\n", ctl_sample(&s, 1.0 + ctl_H, y));     /* not a sample instant */
    printf("%d\n", ctl_sample(&s, 1.0 + 2 * ctl_T, y)); /* a period too far */
    for (k = 1; k < ctl_N; k++)
        if (ctl_output(&s, 1.0 + k * ctl_H, u)) return 9;
    printf("%d\n", ctl_output(&s, 1.0 + ctl_T, u));     /* its sample not given */
    printf("%d\n", ctl_sample(&s, 1.0 + ctl_T, y));
    printf("%d\n", ctl_output(&s, 1.0 + ctl_T, u));
    return 0;
}
''')
    exe = tmp_path / "refusals"
    subprocess.run([*compiler(), *STRICT, "-I", str(tmp_path), str(main),
                    str(tmp_path / "ctl.c"), "-o", str(exe), "-lm"], check=True)
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
    c = {name: code for name, (code, _) in EXPORT_CODES.items()}
    assert [int(v) for v in out.split()] == [
        c["E_ORDER"], c["E_NOT_FINITE"], c["E_NOT_FINITE"], c["OK"], c["E_OFF_GRID"],
        c["E_ORDER"], c["OK"], c["E_ORDER"], c["E_OFF_GRID"], c["E_ORDER"],
        c["E_NO_SAMPLE"], c["OK"], c["OK"]]


def test_the_command_writes_the_two_files_and_refuses_bad_input_in_one_line(tmp_path):
    """``delaycomp export-c LOOP.toml --prefix NAME --out DIR`` (and a scenario): the two
    files, their paths printed; bad input: exit 2, one line naming the parameter, nothing
    written."""
    out = tmp_path / "fw"
    done = subprocess.run([*CLI, "export-c", str(CART), "--prefix", "cart", "--out",
                           str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == [str(out / "cart.h"), str(out / "cart.c")]
    assert sorted(p.name for p in out.iterdir()) == ["cart.c", "cart.h"]
    done = subprocess.run([*CLI, "export-c", "example-3.8", "--set", "p=sin", "--prefix",
                           "ex38", "--out", str(out)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "model example_3_8" in (out / "ex38.c").read_text()
    (tmp_path / "file").write_text("")
    for argv, words in [
            (["example-3.6", "--prefix", "1ctl"], "--prefix '1ctl' is not allowed"),
            (["example-3.6", "--prefix", "int"], "--prefix 'int' is not allowed"),
            (["example-3.6", "--prefix", "a-b"], "--prefix 'a-b' is not allowed"),
            (["example-3.6", "--prefix", "math"], "math.h would shadow the system header "
                                                  "<math.h>"),
            (["example-3.6", "--prefix", "main"], "would clash with the program's own main"),
            (["example-3.6", "--prefix", "CON"], "CON is a device name Windows reserves"),
            (["example-3.6", "--prefix", "c", "--set", "T=0"], "T = "),
            (["example-3.8", "--prefix", "c", "--set", "tau=0.3"], "tau = 0.3 is not allowed"),
            (["loop.ssp", "--prefix", "c"], "not an SSP archive")]:
        bad = subprocess.run([*CLI, "export-c", *argv, "--out", str(tmp_path / "none")],
                             capture_output=True, text=True)
        assert bad.returncode == 2, (argv, bad.stderr)
        assert len(bad.stderr.splitlines()) == 1 and words in bad.stderr, bad.stderr
        assert "Traceback" not in bad.stderr
    assert not (tmp_path / "none").exists()
    bad = subprocess.run([*CLI, "export-c", "example-3.6", "--prefix", "c", "--out",
                          str(tmp_path / "file")], capture_output=True, text=True)
    assert bad.returncode == 2 and "it is a file" in bad.stderr


@pytest.mark.parametrize("prefix, rule", [
    ("math", "would shadow the system header <math.h>"),  # sqrt undeclared in its .c
    ("stdio", "<stdio.h>"), ("string", "<string.h>"), ("stdlib", "<stdlib.h>"),
    ("stdint", "<stdint.h>"), ("Math", "<math.h>"), ("STDIO", "<stdio.h>"),  # macOS, Windows
    ("threads", "<threads.h>"), ("stdckdint", "<stdckdint.h>"),  # C11, C23
    ("unistd", "<unistd.h>"), ("pthread", "<pthread.h>"), ("strings", "<strings.h>"),
    ("main", "own main file"), ("Main", "own main file"),
    ("CON", "Windows reserves"), ("nul", "Windows reserves"), ("Aux", "Windows reserves"),
    ("PRN", "Windows reserves"), ("COM1", "Windows reserves"), ("lpt9", "Windows reserves"),
    ("com0", "Windows reserves"),
])
def test_a_prefix_whose_files_break_the_users_build_is_refused(prefix, rule, tmp_path):
    """Before: ``--prefix math`` wrote ``math.h``, shadowing ``<math.h>`` for every file
    compiled with the folder on its include path; ``main`` clashed with the program's own
    file; ``CON`` cannot be a file on Windows. Refused in one line, nothing written."""
    sc = scenarios.get("example-3.6")
    with pytest.raises(ParameterError) as info:
        export_c(sc.make(sc.resolve([])), tmp_path / "out", prefix)
    msg = str(info.value)
    assert msg.startswith(f"--prefix {prefix!r} is not allowed: ") and rule in msg, msg
    assert "\n" not in msg
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("prefix", ["ctl", "mathx", "my_math", "stdio2", "mainloop",
                                    "console", "com10", "lpt", "nullable", "sys", "net"])
def test_a_prefix_near_a_refused_name_is_allowed(prefix):
    """Only the names themselves: a longer name shadows no header and is a file anywhere."""
    assert check_prefix(prefix) == prefix


def test_the_firmware_example_runs_the_loop_of_delaycomp_run(tmp_path):
    """``docs/examples/firmware.c`` (the page's firmware loop, with the cart and the
    network's delays simulated on the base grid) against ``delaycomp run`` of the same
    loop file: the cart's state and the force at every base step. The example's cart
    moves by its exact flow, the run's plant FMU by DOP853 at 1e-10, so 1e-8 of the peak;
    a delay off by one step, or a sample read at the wrong tick, is O(1) (measured:
    4e-15)."""
    from delaycomp import api
    export_c(api.load(CART), tmp_path, "cart")
    exe = tmp_path / "firmware"
    subprocess.run([*compiler(), *STRICT, "-I", str(tmp_path),
                    str(CART.parent / "firmware.c"), str(tmp_path / "cart.c"), "-o",
                    str(exe), "-lm"], check=True)
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
    lines = out.splitlines()
    assert lines[0] == "time,position,velocity,force"
    got = np.array([line.split(",") for line in lines[1:]], dtype=float)
    res = api.run(api.load(CART))
    assert res.names == ["plant.position", "plant.velocity", "controller.force"]
    assert got.shape == (len(res.times), 4)
    assert np.allclose(got[:, 0], res.times, rtol=0, atol=1e-12)
    peak = np.max(np.abs(res.data), axis=0)
    assert np.all(np.abs(got[:, 1:] - res.data) <= 1e-8 * peak)
    assert np.max(np.abs(got[-1, 1:3])) < 1e-9  # dead-beat: at rest well before 10 s


@pytest.mark.parametrize("name", tiered(["mimo-n3-m2", "example-2.4-numerical",
                                         "example-3.8-padded", "corollary-3.7-padded"],
                                        {"example-3.8-padded"}))
def test_valgrind_finds_no_invalid_access_in_the_export(name, tmp_path):
    """The driver running an exported controller under valgrind (memcheck): no invalid
    read or write, no use of an uninitialized value (the state is a stack struct, so
    memcheck sees every field that ``NAME_init`` left unset)."""
    valgrind = _tool("valgrind")
    loop = LOOPS[name]()
    ys, _ = closed_loop_io(loop, 2 * loop.N + 3, tmp_path / "fmus")
    export_c(loop, tmp_path / "c", "ctl")
    exe = _driver(tmp_path / "c", "ctl", compiler(), tmp_path / "d")
    lines = "".join(f"{k * loop.h!r} " + " ".join(repr(float(v)) for v in y) + "\n"
                    for k, y in enumerate(ys))
    proc = subprocess.run([valgrind, "--error-exitcode=9", "--track-origins=yes", str(exe)],
                          input=lines, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "ERROR SUMMARY: 0 errors" in proc.stderr


def _random_lti_loop(seed: int):
    """A random LTI loop: n in 1..5, m in 1..3, T, N, r (a whole number of base steps, up
    to 3 periods, with a fractional part of T) and tau = l T drawn; a stable plant with a
    small gain (the delay-free sampled loop stable)."""
    from scipy.linalg import solve_continuous_are

    from delaycomp.paper.scenarios import lti_loop

    rng = np.random.default_rng(1000 + seed)
    n, m = int(rng.integers(1, 6)), int(rng.integers(1, 4))
    T = float(rng.choice([0.2, 0.5, 1.0]))
    N = int(rng.choice([1, 3, 10]))
    h = T / N
    r = float(rng.integers(0, 3 * N + 1)) * h
    tau = float(rng.integers(0, 3)) * T
    A = rng.standard_normal((n, n)) * 0.4
    B = rng.standard_normal((n, m))
    K = -0.3 * B.T @ solve_continuous_are(A, B, np.eye(n), np.eye(m))
    return lti_loop(A, B, K, T=T, r=r, tau=tau, N=N, mode="compensated",
                    x0=tuple(rng.uniform(-1, 1, n)), u0=tuple(rng.uniform(-0.5, 0.5, m)))


def _random_model_loop(seed: int):
    """A shipped model with T, N, r, tau (padded where zero-order hold needs it) and the
    predictor drawn."""
    rng = np.random.default_rng(2000 + seed)
    name = ["example-2.4", "example-3.8", "corollary-4.1", "proposition-4.2"][seed % 4]
    T = float(rng.choice([0.5, 1.0]))
    N = int(rng.choice([2, 5, 10]))
    h = T / N
    r = float(rng.integers(0, 2 * N + 1)) * h
    tau = float(rng.integers(0, 2 * N + 1)) * h
    sets = [f"T={T!r}", f"N={N}", f"r={r!r}", f"tau={tau!r}",
            f"predictor={rng.choice(['closed', 'numerical'])}"]
    if name in ("example-3.8", "proposition-4.2"):
        sets.append("pad=true")
    return _scenario(name, sets)


@pytest.mark.parametrize("kind,seed", tiered(
    [("lti", s) for s in range(6)] + [("model", s) for s in range(8)],
    {("lti", 0), ("model", 0)}), ids=str)
def test_random_loops_export_equal_to_the_fmu(kind, seed, tmp_path):
    """Loops the shipped cases do not cover (random dimensions, periods, base steps,
    delays with fractional parts, padding, both predictors): the export equals the
    controller FMU as in ``test_the_export_equals_the_controller_fmu``."""
    loop = (_random_lti_loop if kind == "lti" else _random_model_loop)(seed)
    ticks = 5 * loop.N + 3
    ys, want = closed_loop_io(loop, ticks, tmp_path / "fmus")
    export_c(loop, tmp_path / "c", "ctl")
    got = _run_driver([str(_driver(tmp_path / "c", "ctl", compiler(), tmp_path / "d"))],
                      loop, ys)
    assert len(np.unique(want)) > 2  # the control moves: the comparison means something
    peak = np.max(np.abs(want))
    if kind == "lti":
        assert np.max(np.abs(got - want)) <= 1e-12 * peak
    else:
        assert np.all(np.abs(got - want) <= 10 * TOL * (1 + np.abs(want)))
