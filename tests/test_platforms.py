"""Native FMUs for the platforms tool chains run on (issue 24, items 2 and 3): every native
FMU carries linux64, win64 (mingw-w64) and aarch64-linux binaries where their compilers
are here (a platform whose compiler is absent is left out with one note), its sources
compile alone as C99 with gcc and clang, and the C closed-loop host built for Windows runs
the win64 binaries under wine and the one built for aarch64 runs the aarch64 binaries
under qemu-user, each trajectory equal to the linux64 run.

The tools are Debian packages that ``scripts/install_platform_tools.sh`` installs (CI runs
it); a test whose tool is missing is skipped with the reason in pytest's summary (``-ra``),
never passed silently.

Tolerance of the cross-platform runs: 1e-12 of each column's peak (the issue's bound). The
same C code and the same IEEE arithmetic run on each platform; only the C library's ``exp``
and friends (glibc against msvcrt) may differ in the last bit. Measured: 0 (the LTI maths
uses no libm function on the stepping path).
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from delaycomp.fmu import native
from delaycomp.fmu.native import (
    CROSS_TARGETS,
    NativeBuildError,
    build_native_fmu,
    compile_host,
    emulator,
    host_argv,
    pop_notes,
    unpack,
)
from delaycomp.formats.loopbuild import file_stem

from .conftest import every_platform
from .external import need
from .test_loopbuild import write_loop
from .tiers import tiered

pytestmark = [pytest.mark.fmu, pytest.mark.platforms]

REPO = Path(__file__).resolve().parent.parent
RTOL = 1e-12


def need_cross(platform: str) -> None:
    _, default, _, _, _ = CROSS_TARGETS[platform]
    need(default, what=f"the {platform} binaries")


def machine_of(binary: bytes) -> str:
    """The platform a shared library is for, from its header (PE or ELF)."""
    if binary[:2] == b"MZ":
        pe = struct.unpack_from("<I", binary, 0x3C)[0]
        assert binary[pe:pe + 4] == b"PE\0\0"
        machine = struct.unpack_from("<H", binary, pe + 4)[0]
        return {0x8664: "win64"}.get(machine, hex(machine))
    assert binary[:4] == b"\x7fELF" and binary[4] == 2  # 64-bit ELF
    machine = struct.unpack_from("<H", binary, 18)[0]
    return {62: "linux64", 183: "aarch64-linux"}.get(machine, str(machine))


def binaries(fmu: Path) -> dict[str, str]:
    """folder under binaries/ -> the platform its library is built for."""
    with zipfile.ZipFile(fmu) as zf:
        return {name.split("/")[1]: machine_of(zf.read(name)) for name in zf.namelist()
                if name.startswith("binaries/") and not name.endswith("/")}


@pytest.fixture(scope="module")
def model_file():
    return REPO / "delaycomp" / "paper" / "models" / "example_3_8.py"


@pytest.fixture(scope="module")
def built(model_file, tmp_path_factory):
    """``built(kind)``: the native FMU of ``kind``, with every platform whose compiler is
    here, built once for this module's tests (the compilers run once per kind, not per
    case)."""
    made: dict[str, Path] = {}

    def get(kind: str) -> Path:
        if kind not in made:
            config = {"model": str(model_file)} if kind.startswith("model") else None
            with every_platform():
                made[kind] = build_native_fmu(kind, tmp_path_factory.mktemp(kind), config)
        return made[kind]
    return get


KINDS = ["delay", "plant", "controller", "stamped_controller", "model_plant",
         "model_controller"]


@pytest.mark.parametrize("kind", KINDS)
def test_every_native_fmu_carries_three_platforms(kind, built):
    """linux64 (.so, x86-64), win64 (.dll, PE x86-64) and aarch64-linux (.so, AArch64):
    each folder holds a library built for the platform it names."""
    for platform in CROSS_TARGETS:
        need_cross(platform)
    fmu = built(kind)
    found = binaries(fmu)
    assert found == {"linux64": "linux64", "win64": "win64", "aarch64-linux": "aarch64-linux"}
    with zipfile.ZipFile(fmu) as zf:
        names = set(zf.namelist())
    ident = fmu.stem
    assert {f"binaries/win64/{ident}.dll", f"binaries/aarch64-linux/{ident}.so",
            f"binaries/linux64/{ident}.so"} <= names


def test_a_platform_without_its_compiler_is_left_out_with_one_note(monkeypatch, tmp_path):
    """No mingw-w64 here (its name points nowhere): the FMU has linux64 and aarch64-linux
    binaries, and one note says what is missing and how to get it; the command prints it
    once, however many FMUs it builds."""
    from delaycomp.cli import main

    need_cross("aarch64-linux")
    monkeypatch.delenv("CC_WIN64", raising=False)
    monkeypatch.setitem(CROSS_TARGETS, "win64", ("CC_WIN64", "no-such-mingw-gcc",
                                                 "gcc-mingw-w64-x86-64", ".dll", ()))
    monkeypatch.setattr(native, "_NOTED", set())
    pop_notes()
    fmu = build_native_fmu("delay", tmp_path / "a")
    assert sorted(binaries(fmu)) == ["aarch64-linux", "linux64"]
    notes = pop_notes()
    assert notes == ["note: native FMUs without win64 binaries: no no-such-mingw-gcc here "
                     "(`apt-get install gcc-mingw-w64-x86-64`, or set CC_WIN64; "
                     "DELAYCOMP_PLATFORMS chooses the platforms)"]
    monkeypatch.setattr(native, "_NOTED", set())
    loop_file = write_loop(tmp_path)
    import io
    from contextlib import redirect_stderr, redirect_stdout

    err = io.StringIO()
    with redirect_stderr(err), redirect_stdout(io.StringIO()):
        assert main(["build", str(loop_file), "--out", str(tmp_path / "b")]) == 0
    assert err.getvalue().count("note: native FMUs without win64 binaries") == 1
    assert "win64" not in binaries(tmp_path / "b" / "myloop_controller.fmu")


def test_delaycomp_platforms_chooses_the_platforms(monkeypatch, tmp_path):
    need_cross("win64")
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "")
    assert sorted(binaries(build_native_fmu("delay", tmp_path / "none"))) == ["linux64"]
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "win64")
    assert sorted(binaries(build_native_fmu("delay", tmp_path / "w"))) == ["linux64", "win64"]
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "win64,riscv64")
    with pytest.raises(NativeBuildError, match="DELAYCOMP_PLATFORMS names 'riscv64': "
                                               "allowed are win64, aarch64-linux"):
        build_native_fmu("delay", tmp_path / "bad")
    monkeypatch.delenv("DELAYCOMP_PLATFORMS")
    monkeypatch.setenv("CC_WIN64", "no-such-compiler")
    with pytest.raises(NativeBuildError, match="CC_WIN64 = 'no-such-compiler' is not "
                                               "allowed: no such program on PATH"):
        build_native_fmu("delay", tmp_path / "cc")


@pytest.mark.parametrize("cc", ["gcc", "clang"])
@pytest.mark.parametrize("kind", KINDS)
def test_sources_compile_alone_as_c99(cc, kind, built, tmp_path):
    """An importer builds the FMU for any other platform from ``sources/`` alone: the
    files modelDescription lists compile with ``-std=c99 -pedantic -Wall -Wextra
    -Werror``."""
    from fmpy import read_model_description

    need(cc, what="the sources compiled with it")
    fmu = built(kind)
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(tmp_path / "x", [n for n in zf.namelist() if n.startswith("sources/")])
    files = read_model_description(str(fmu)).buildConfigurations[0].sourceFileSets[0] \
        .sourceFiles
    src = tmp_path / "x" / "sources"
    proc = subprocess.run([cc, "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2",
                           "-fPIC", "-shared", "-I", str(src), "-o", str(tmp_path / "x.so"),
                           *(str(src / f) for f in files), "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


# -- the C host on the other platforms ---------------------------------------------------------

@pytest.fixture(scope="module")
def wine_prefix(tmp_path_factory):
    """A wine prefix of this test session's own (never the user's ~/.wine)."""
    return tmp_path_factory.mktemp("wine") / "prefix"


@pytest.fixture(scope="module")
def hosts(tmp_path_factory):
    """``hosts(platform)``: the C host built for ``platform`` (None: linux64), compiled
    once for the module's matrix."""
    made: dict = {}

    def get(platform: str | None) -> Path:
        if platform not in made:
            suffix = ".exe" if platform == "win64" else ""
            made[platform] = compile_host(
                tmp_path_factory.mktemp("host") / f"host-{platform or 'linux64'}{suffix}",
                platform)
        return made[platform]
    return get


@pytest.fixture(scope="module")
def case_loops(tmp_path_factory, hosts):
    """``case_loops(case)``: the case's loop, its FMUs unpacked (``delaycomp build``, every
    platform inside) and the linux64 host's trajectory, made once for both platforms."""
    from delaycomp import api
    from delaycomp.paper import scenarios

    made: dict = {}

    def get(case: str):
        if case not in made:
            tmp = tmp_path_factory.mktemp(f"case-{case}")
            if case == "myloop":
                source = write_loop(tmp)
                args = [str(source)]
                loop = api.load(source)
            else:
                args = CASES[case]
                loop = scenarios.get(case).loop([a for a in args[1:] if a != "--set"])
            out = tmp / "fmus"
            with every_platform():  # the FMUs with every platform inside
                proc = subprocess.run([sys.executable, "-m", "delaycomp", "build", *args,
                                       "--out", str(out)], capture_output=True, text=True)
            assert proc.returncode == 0, proc.stderr
            stem = file_stem(loop.name)
            fmus = {loop.by_role(role).name: out / f"{stem}_{role}.fmu"
                    for role in ("plant", "meas_delay", "controller", "input_delay")}
            dirs = unpack(fmus, tmp / "unpacked")
            made[case] = (loop, dirs, run_host(hosts(None), loop, STOP, dirs, None, None))
        return made[case]
    return get


def run_host(exe: Path, loop, stop: float, dirs, platform, env) -> np.ndarray:
    proc = subprocess.run(host_argv(exe, loop, stop, dirs, platform=platform),
                          capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    return np.array([line.split(",") for line in lines[1:]], dtype=float)


#: (what, build arguments): Example 3.6 (Figure 3), Corollary 3.7 (n = 3, dead-beat) and a
#: user's loop file (n = 3, m = 2), each built with ``delaycomp build``
CASES = {"example-3.6": ["example-3.6", "--set", "r=0.3", "--set", "u0=4"],
         "corollary-3.7": ["corollary-3.7"],
         "myloop": None}
#: the hosts' horizon [s]
STOP = 6.0


@pytest.mark.parametrize("platform", ["win64", "aarch64-linux"])
@pytest.mark.parametrize("case", tiered(sorted(CASES), {"myloop"}))
def test_the_c_host_runs_the_platform_binaries_as_linux64(platform, case, wine_prefix,
                                                          hosts, case_loops):
    """``delaycomp build`` the loop's FMUs (every platform inside); the C host built for
    ``platform`` runs that platform's binaries in its emulator (wine, qemu-user) and
    gives the linux64 host's trajectory to 1e-12 of each column's peak."""
    need_cross(platform)
    need(native.EMULATORS[platform][0][0], what=f"the {platform} binaries run")
    loop, dirs, ours = case_loops(case)
    env = {**os.environ, **emulator(platform)[1], "WINEPREFIX": str(wine_prefix)}
    theirs = run_host(hosts(platform), loop, STOP, dirs, platform, env)
    assert theirs.shape == ours.shape == (round(STOP / loop.h) + 1, ours.shape[1])
    peak = np.max(np.abs(ours), axis=0)
    assert np.all(np.abs(theirs - ours) <= RTOL * peak), np.max(np.abs(theirs - ours))
    assert np.max(np.abs(ours[:, 1:])) > 0.1  # the loop moves: a real comparison
