"""Native FMUs for every platform from one pip install (issues 24 and 51): Zig, from the
``native`` extra, builds every native FMU for x86_64 and aarch64 Linux, x86_64 Windows and
x86_64 and arm64 macOS on this machine, with no system compiler; each binary loads anywhere
its platform runs (its imports read from the file: ``tests/binimports.py``); without Zig
a system compiler builds what it can and each platform left out gets one note; the sources
compile alone as C99 with gcc and clang; and the C closed-loop host, built by the same
compiler for Windows and for aarch64 Linux, runs those binaries under wine and qemu-user,
each trajectory equal to the x86_64 Linux run. The macOS binaries cannot run here: they are
read (architectures, exported FMI functions, imports), not run.

The emulators are Debian packages that ``scripts/install_platform_tools.sh`` installs (CI
runs it); a test whose tool is missing is skipped with the reason in pytest's summary
(``-ra``), never passed silently.

Tolerance of the cross-platform runs: 1e-12 of each column's peak (the issue's bound). The
same C code and the same IEEE arithmetic run on each platform, contraction to fused
multiply-adds off (``-ffp-contract=off``: aarch64 has them); only the C library's ``exp``
and friends (glibc against the universal C runtime) may differ in the last bit. Measured: 0
(the LTI maths uses no libm function on the stepping path).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from delaycomp.fmu import toolchain
from delaycomp.fmu.host import EMULATORS, compile_host, emulator, host_argv, unpack
from delaycomp.fmu.native import NativeBuildError, build_native_fmu, pop_notes
from delaycomp.formats.loopbuild import file_stem

from .binimports import fmi_functions, images, loads_anywhere
from .conftest import every_platform
from .external import Absent, need
from .test_loopbuild import write_loop
from .tiers import tiered

pytestmark = [pytest.mark.fmu, pytest.mark.platforms]

REPO = Path(__file__).resolve().parent.parent
RTOL = 1e-12
#: FMI 2.0 binaries folder -> the platform of the library there (a universal macOS one in
#: darwin64: both)
FMI2_FOLDERS = {"linux64": ["x86_64-linux"], "aarch64-linux": ["aarch64-linux"],
                "win64": ["x86_64-windows"], "darwin64": ["x86_64-darwin", "aarch64-darwin"],
                "aarch64-darwin": ["aarch64-darwin"]}


def need_zig() -> None:
    def find():
        if toolchain.zig() is None:
            raise Absent("no ziglang wheel and no zig on PATH")
    need("zig", find, what="the native FMUs of every platform")


def need_cross(platform: str) -> None:
    """The Debian cross compiler of ``platform`` (the builds without Zig)."""
    p = toolchain.PLATFORMS[platform]
    assert p.system is not None
    need(p.system[1], what=f"the {platform} binaries without zig")


def binaries(fmu: Path) -> dict[str, list[str]]:
    """folder under binaries/ -> the platforms of its library's images."""
    with zipfile.ZipFile(fmu) as zf:
        return {name.split("/")[1]: sorted(i.platform for i in images(zf.read(name)))
                for name in zf.namelist()
                if name.startswith("binaries/") and not name.endswith("/")}


@pytest.fixture(scope="module")
def model_file():
    return REPO / "delaycomp" / "paper" / "models" / "example_3_8.py"


@pytest.fixture(scope="module")
def built(model_file, tmp_path_factory):
    """``built(kind, fmi=2)``: the native FMU of ``kind``, with every platform (Zig), built
    once for this module's tests (the compilers run once per kind, not per case)."""
    made: dict[tuple, Path] = {}

    def get(kind: str, fmi: int = 2) -> Path:
        if (kind, fmi) not in made:
            need_zig()
            config = {"model": str(model_file)} if kind.startswith("model") else None
            with every_platform():
                made[kind, fmi] = build_native_fmu(
                    kind, tmp_path_factory.mktemp(f"{kind}{fmi}"), config, fmi=fmi)
        return made[kind, fmi]
    return get


KINDS = ["delay", "plant", "controller", "stamped_controller", "model_plant",
         "model_controller"]


@pytest.mark.parametrize("kind", tiered(KINDS, {"controller", "model_controller"}))
def test_every_native_fmu_carries_five_platforms(kind, built):
    """Zig builds x86_64-linux (linux64), aarch64-linux, x86_64-windows (win64) and both
    macOS ones: one universal library in darwin64 (fmpy and OMSimulator load darwin64 on
    either Mac), the arm64 one also in aarch64-darwin (FMI 2.0.4's name for it)."""
    fmu = built(kind)
    found = binaries(fmu)
    assert found == {folder: sorted(p) for folder, p in FMI2_FOLDERS.items()}
    ident = fmu.stem
    with zipfile.ZipFile(fmu) as zf:
        names = set(zf.namelist())
    assert {f"binaries/win64/{ident}.dll", f"binaries/aarch64-linux/{ident}.so",
            f"binaries/linux64/{ident}.so", f"binaries/darwin64/{ident}.dylib",
            f"binaries/aarch64-darwin/{ident}.dylib"} <= names


def test_an_fmi3_fmu_has_a_folder_per_platform(built):
    """FMI 3.0: each platform in the folder its tuple names."""
    found = binaries(built("controller", 3))
    assert found == {p: [p] for p in toolchain.PLATFORMS}


@pytest.mark.parametrize("kind,fmi", tiered(
    [*((k, 2) for k in KINDS), ("controller", 3), ("model_controller", 3)],
    {("controller", 2), ("model_controller", 3)}))
def test_every_binary_loads_anywhere_its_platform_runs(kind, fmi, built):
    """Read from each binary: Linux ones need no glibc symbol newer than 2.17 and no
    library beyond libc and libm; Windows ones only system DLLs; macOS ones only
    libSystem, named by their file; and each exports every function of the FMI
    version's headers."""
    fmu = built(kind, fmi)
    wanted = fmi_functions(fmi)
    assert len(wanted) > 30  # the headers were read
    with zipfile.ZipFile(fmu) as zf:
        libs = [n for n in zf.namelist() if n.startswith("binaries/") and not n.endswith("/")]
        assert len(libs) == 5  # FMI 2.0: darwin64 (universal) and aarch64-darwin
        for name in libs:
            for image in images(zf.read(name)):
                assert loads_anywhere(image, name) == [], (name, image.platform)
                assert wanted <= image.exports, (name, sorted(wanted - image.exports))
                if image.platform.endswith("-linux"):
                    assert image.glibc is not None  # versions were read: a real check


def test_no_system_compiler_a_loop_and_a_model_build_for_every_platform(tmp_path,
                                                                        model_file):
    """With no gcc, cc or clang on PATH (an empty PATH, CC unset), ``delaycomp build
    LOOP.toml`` and ``build --model`` give native FMUs with all five platforms, -v says
    which compiler built which folders, and the loop's FMUs run in our master."""
    need_zig()
    env = {k: v for k, v in os.environ.items()
           if k not in ("CC", "CC_WIN64", "CC_AARCH64", "DELAYCOMP_PLATFORMS")}
    env["PATH"] = str(tmp_path / "empty")
    from delaycomp.child import module_argv

    loop = write_loop(tmp_path)
    for i, (args, fmu) in enumerate((
            (["build", str(loop)], "myloop_controller.fmu"),
            (["build", "--model", str(model_file), "--native"], "DelaycompController_"))):
        out = tmp_path / f"out{i}"
        proc = subprocess.run(module_argv("delaycomp.cli", *args, "--out", str(out), "-v"),
                              capture_output=True, text=True, env=env, timeout=600)
        assert proc.returncode == 0, proc.stderr
        assert "note:" not in proc.stderr
        lines = [line for line in proc.stderr.splitlines() if line.startswith("building")]
        assert lines and all(", linux64 aarch64-linux win64 darwin64 aarch64-darwin "
                             "with zig " in line for line in lines), proc.stderr
        path = next(p for p in out.iterdir() if p.name.startswith(fmu))
        assert sorted(binaries(path)) == sorted(FMI2_FOLDERS)
    # the loop's x86_64 Linux FMUs, built by Zig for the run (still no system compiler),
    # run in our master: the Python FMUs' run to 1e-12 of each signal's peak (check's
    # native-vs-python bound)
    runs = {}
    env["DELAYCOMP_CACHE_DIR"] = str(tmp_path / "cache")  # its own: the run builds them
    for kind, extra in (("native", ["--native"]), ("python", ["--python"])):
        csv = tmp_path / f"{kind}.csv"
        proc = subprocess.run(module_argv("delaycomp.cli", "run", str(loop), "--stop-time",
                                          "4", *extra, "--out", str(csv), "-v"),
                              capture_output=True, text=True, env=env, timeout=600)
        assert proc.returncode == 0, proc.stderr
        built = [line for line in proc.stderr.splitlines() if line.startswith("building")]
        assert kind == "python" or (built and all(
            "(native, linux64 with zig " in line for line in built)), proc.stderr
        runs[kind] = np.loadtxt(csv, delimiter=",", skiprows=1)
    peak = np.max(np.abs(runs["python"]), axis=0)
    assert runs["native"].shape == runs["python"].shape
    assert np.all(np.abs(runs["native"] - runs["python"]) <= 1e-12 * peak)
    assert np.max(np.abs(runs["python"][:, 1:])) > 0.1  # the loop moves


def test_platforms_narrows_the_set(tmp_path):
    """``build --platforms`` gives exactly the platforms it names (FMI 2.0 names too);
    a bad name is one line naming the allowed ones, exit status 2."""
    need_zig()
    from delaycomp.child import module_argv

    loop = write_loop(tmp_path)
    proc = subprocess.run(module_argv("delaycomp.cli", "build", str(loop), "--only",
                                      "controller", "--out", str(tmp_path / "o"),
                                      "--platforms", "win64,aarch64-darwin"),
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert binaries(tmp_path / "o" / "myloop_controller.fmu") == {
        "win64": ["x86_64-windows"], "darwin64": ["aarch64-darwin"],
        "aarch64-darwin": ["aarch64-darwin"]}
    proc = subprocess.run(module_argv("delaycomp.cli", "build", str(loop), "--out",
                                      str(tmp_path / "p"), "--platforms", "linux64,riscv64"),
                          capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    assert "--platforms: names 'riscv64': allowed are x86_64-linux, aarch64-linux, " \
           "x86_64-windows, x86_64-darwin, aarch64-darwin" in proc.stderr


def test_without_zig_a_platform_without_its_compiler_is_left_out_with_one_note(
        monkeypatch, tmp_path):
    """No Zig (``DELAYCOMP_ZIG`` empty) and no mingw-w64 here (its name points nowhere):
    the system compilers build linux64 and aarch64-linux, and one note per platform left
    out says what is missing and how to get it; the command prints each once, however
    many FMUs it builds."""
    from delaycomp.cli import main

    need_cross("aarch64-linux")
    monkeypatch.setenv("DELAYCOMP_ZIG", "")
    for var in ("CC", "CC_WIN64", "CC_AARCH64"):
        monkeypatch.delenv(var, raising=False)
    win = toolchain.PLATFORMS["x86_64-windows"]
    monkeypatch.setitem(toolchain.PLATFORMS, "x86_64-windows", dataclasses.replace(
        win, system=("CC_WIN64", "no-such-mingw-gcc", "gcc-mingw-w64-x86-64", ())))
    monkeypatch.setattr(toolchain, "_NOTED", set())
    pop_notes()
    fmu = build_native_fmu("delay", tmp_path / "a")
    assert binaries(fmu) == {"linux64": ["x86_64-linux"], "aarch64-linux": ["aarch64-linux"]}
    notes = pop_notes()
    assert notes[0] == ("note: native FMUs without x86_64-windows binaries: no compiler for "
                        "it here (`pip install 'delaycomp[native]'` brings zig, which builds "
                        "every platform; or `apt-get install gcc-mingw-w64-x86-64`, or set "
                        "CC_WIN64; --platforms or DELAYCOMP_PLATFORMS chooses the platforms)")
    assert [n.split(" binaries")[0] for n in notes[1:]] == [
        "note: native FMUs without x86_64-darwin", "note: native FMUs without aarch64-darwin"]
    monkeypatch.setattr(toolchain, "_NOTED", set())
    loop_file = write_loop(tmp_path)
    import io
    from contextlib import redirect_stderr, redirect_stdout

    err = io.StringIO()
    with redirect_stderr(err), redirect_stdout(io.StringIO()):
        assert main(["build", str(loop_file), "--out", str(tmp_path / "b")]) == 0
    assert err.getvalue().count("note: native FMUs without x86_64-windows binaries") == 1
    assert "win64" not in binaries(tmp_path / "b" / "myloop_controller.fmu")


def test_delaycomp_platforms_chooses_the_platforms(monkeypatch, tmp_path):
    """``DELAYCOMP_PLATFORMS``: this machine's and those it names (empty: this machine's
    alone); a bad name, or a compiler variable naming no program, is one line."""
    need_zig()
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "")
    assert sorted(binaries(build_native_fmu("delay", tmp_path / "none"))) == ["linux64"]
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "win64")
    assert sorted(binaries(build_native_fmu("delay", tmp_path / "w"))) == ["linux64", "win64"]
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "win64,riscv64")
    with pytest.raises(NativeBuildError, match="DELAYCOMP_PLATFORMS names 'riscv64': "
                                               "allowed are x86_64-linux, aarch64-linux"):
        build_native_fmu("delay", tmp_path / "bad")
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "win64")
    monkeypatch.setenv("CC_WIN64", "no-such-compiler")
    with pytest.raises(NativeBuildError, match="CC_WIN64 = 'no-such-compiler' is not "
                                               "allowed: no such program on PATH"):
        build_native_fmu("delay", tmp_path / "cc")


def test_api_build_takes_platforms(tmp_path):
    """``api.build(platforms=)``: the names as ``--platforms`` takes them; a bad one is a
    ``ParameterError`` naming the allowed ones (no build)."""
    from delaycomp import api
    from delaycomp.errors import ParameterError

    loop = api.lti([[0.0]], [[1.0]], [[-1.0]], T=0.5, r=0.1, tau=0.5, N=5, x0=[1.0])
    with pytest.raises(ParameterError, match="platforms names 'mac': allowed are"):
        api.build(loop, tmp_path, platforms="linux64,mac")
    with pytest.raises(ParameterError, match="names no platform"):
        api.build(loop, tmp_path, platforms=[])
    need_zig()
    out = api.build(loop, tmp_path, only=["controller"], fmus="native",
                    platforms=["win64"])
    with zipfile.ZipFile(out.fmus["controller"]) as zf:
        assert {n.split("/")[1] for n in zf.namelist() if n.startswith("binaries/")} == {
            "win64"}


def test_a_run_builds_its_fmus_for_this_machine_alone(monkeypatch):
    """The FMUs a run takes from the native cache (``native_fmus``) carry this machine's
    binary alone, where ``delaycomp build`` would give all five (``DELAYCOMP_PLATFORMS``
    unset here): a first run compiles one platform."""
    need_zig()
    import fmpy

    from delaycomp import api
    from delaycomp.fmu.twins import native_fmus

    monkeypatch.delenv("DELAYCOMP_PLATFORMS", raising=False)
    assert toolchain.requested() == tuple(toolchain.PLATFORMS)
    loop = api.lti([[0.0]], [[1.0]], [[-1.0]], T=0.5, r=0.1, tau=0.5, N=5, x0=[1.0])
    for path in native_fmus(loop).values():
        assert list(binaries(path)) == [fmpy.platform], path


@pytest.mark.parametrize("cc", ["gcc", "clang"])
@pytest.mark.parametrize("kind", tiered(KINDS, {"controller", "model_controller"}))
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
    gives the linux64 host's trajectory to 1e-12 of each column's peak. The hosts and
    the FMUs' binaries are built by Zig (with no Zig: skipped, saying so)."""
    need_zig()
    name = "x86_64-windows" if platform == "win64" else platform
    need(EMULATORS[name][0][0], what=f"the {platform} binaries run")
    if platform == "aarch64-linux":
        sysroot = Path(EMULATORS[name][0][2])

        def libc():
            if not (sysroot / "lib" / "ld-linux-aarch64.so.1").exists():
                raise Absent(f"no {sysroot}/lib/ld-linux-aarch64.so.1")
        need("aarch64-libc", libc, what="the aarch64 binaries run")
    loop, dirs, ours = case_loops(case)
    env = {**os.environ, **emulator(platform)[1], "WINEPREFIX": str(wine_prefix)}
    theirs = run_host(hosts(platform), loop, STOP, dirs, platform, env)
    assert theirs.shape == ours.shape == (round(STOP / loop.h) + 1, ours.shape[1])
    peak = np.max(np.abs(ours), axis=0)
    assert np.all(np.abs(theirs - ours) <= RTOL * peak), np.max(np.abs(theirs - ours))
    assert np.max(np.abs(ours[:, 1:])) > 0.1  # the loop moves: a real comparison
