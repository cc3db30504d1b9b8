"""The C closed-loop host (``fmus/native/host/host.c``): a program that loads a loop's
native FMUs and steps them as our master does, with no Python in the loop. It is built
here for this machine or for another platform (``compile_host``), run there or under an
emulator (``emulator``: wine, qemu-user), and given the loop on its command line
(``host_argv``, with the FMUs ``unpack``-ed into folders). The tests and the benchmarks
hold the native FMUs' numbers to the Python master's through it.

The native stepping core (``fmus/native/host/stepping.c``), the library our master hands
a loop of native FMUs to (``delaycomp.orchestrator.native_core``), is built here too:
``core_library``, once per version, source and compiler, in the build cache.
"""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
from pathlib import Path

from delaycomp.fmu import toolchain
from delaycomp.fmu.native import SOURCE_DIR, compiler, fmi_header_dir
from delaycomp.fmu.toolchain import NativeBuildError

__all__ = ["EMULATORS", "compile_host", "core_library", "emulator", "host_argv", "unpack"]


def compile_host(exe: Path, platform: str | None = None) -> Path:
    """Compile the C closed-loop host (``fmus/native/host/host.c``) to ``exe``: for this
    machine, or for ``platform`` (a key of ``delaycomp.fmu.toolchain.PLATFORMS``, or its
    FMI 2.0 name: ``win64``), by the compiler that builds that platform's FMU binaries
    (``toolchain.compiler_for``: Zig where it is here); the host then loads that
    platform's binaries of the FMUs (run it with ``host_argv``'s ``platform``)."""
    flags: tuple[str, ...] = ()
    if platform is None:
        name, argv = toolchain.this_platform(), compiler()
    else:
        name = _platform_name(platform)
        c = toolchain.compiler_for(name)
        if c is None:
            raise NativeBuildError(f"no C compiler here to build the C host for {name}: "
                                   f"{toolchain.how_to_get(name)}")
        argv, flags = list(c.argv), c.flags
    windows = name is not None and toolchain.PLATFORMS[name].os == "windows"
    libs = ["-lm"] if windows else ["-ldl", "-lm"]  # dlopen is in libdl before glibc 2.34
    proc = subprocess.run([*argv, "-std=c11", "-O2", "-Wall", "-Wextra", "-Werror", *flags,
                           "-I", str(fmi_header_dir()), str(SOURCE_DIR / "host" / "host.c"),
                           "-o", str(exe), *libs], capture_output=True, text=True)
    if proc.returncode != 0:
        raise NativeBuildError(f"compiling the C host failed:\n{proc.stderr.strip()}")
    return Path(exe)


#: the native stepping core's source, in the C host's folder
CORE_SOURCE = SOURCE_DIR / "host" / "stepping.c"


def core_library(cache: Path | None = None) -> Path:
    """The native stepping core (``fmus/native/host/stepping.c``) as a shared library of
    this machine, compiled on first use by this machine's C compiler (``compiler``:
    ``$CC``, else Zig's, else ``cc``, ``gcc`` or ``clang``; ``-ffp-contract=off``: every
    time is computed as Python computes it) into ``cache`` (default: beside the native
    FMUs' build cache), named by the digest of the source, this version and the compiler
    command, and taken from there afterwards.

    Raises
    ------
    NativeBuildError
        No C compiler here, or it failed (the message says which).
    """
    from delaycomp.fmu.native import native_fmu_dir
    from delaycomp.tmpfiles import build_lock
    from delaycomp.version import __version__

    argv = compiler()
    digest = hashlib.sha256("\0".join([__version__, *argv]).encode()
                            + CORE_SOURCE.read_bytes()).hexdigest()[:12]
    folder = Path(cache) if cache is not None else native_fmu_dir().parent / "core"
    suffix = {"win32": ".dll", "darwin": ".dylib"}.get(sys.platform, ".so")
    lib = folder / f"delaycomp_core-{digest}{suffix}"
    if lib.is_file():
        return lib
    folder.mkdir(parents=True, exist_ok=True)
    with build_lock(lib):  # parallel first runs: one compiles, the others wait
        if lib.is_file():
            return lib
        part = lib.with_name(f".{lib.name}.part")
        proc = subprocess.run([*argv, "-std=c11", "-O2", "-fPIC", "-shared",
                               "-ffp-contract=off", "-Wall", "-Wextra", "-Werror",
                               str(CORE_SOURCE), "-o", str(part), "-lm"],
                              capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            first = (proc.stderr.strip().splitlines() or ["(no message)"])[0]
            raise NativeBuildError(f"compiling the native stepping core failed: {first}")
        part.replace(lib)
    from delaycomp.progress import detail

    detail(f"built the native stepping core: {lib}")
    return lib


def _platform_name(platform: str) -> str:
    """A platform's tuple from its tuple or FMI 2.0 name (``win64``, ``linux64``)."""
    names = toolchain.ALIASES.get(platform, (platform,))
    if len(names) != 1 or names[0] not in toolchain.PLATFORMS:
        raise ValueError(f"platform {platform!r} is not allowed: allowed are "
                         f"{', '.join(toolchain.PLATFORMS)}, linux64, win64 (or None: this "
                         "machine)")
    return names[0]


#: how this machine runs a C host built for another platform: the emulator (a Debian
#: package), its arguments before the program
EMULATORS = {"x86_64-windows": (("wine",), "wine"),
             "aarch64-linux": (("qemu-aarch64", "-L", "/usr/aarch64-linux-gnu"), "qemu-user")}


def emulator(platform: str) -> tuple[list[str], dict[str, str]]:
    """The command prefix that runs a program built for ``platform`` here (wine for
    ``x86_64-windows``, alias ``win64``; qemu-user for ``aarch64-linux``, with Debian's
    aarch64 C library) and the environment variables it needs (wine: no debug output, no
    Mono or Gecko installers; ``WINEPREFIX`` is the caller's). Raises
    ``NativeBuildError`` naming the package to install where it is absent."""
    name = _platform_name(platform)
    if name not in EMULATORS:
        raise ValueError(f"platform {platform!r} is not allowed: this machine runs "
                         f"{', '.join(EMULATORS)} programs in an emulator")
    prefix, package = EMULATORS[name]
    if shutil.which(prefix[0]) is None:
        raise NativeBuildError(f"no {prefix[0]} here to run {name} programs "
                               f"(`apt-get install {package}`)")
    env = {"WINEDEBUG": "-all", "WINEDLLOVERRIDES": "mscoree=d;mshtml=d"} \
        if name == "x86_64-windows" else {}
    return list(prefix), env


def _host_path(path: Path, platform: str | None) -> str:
    """A folder as the host built for ``platform`` names it (wine maps / to drive Z:)."""
    text = str(Path(path).resolve())
    windows = platform is not None and _platform_name(platform) == "x86_64-windows"
    return "Z:" + text.replace("/", "\\") if windows else text


def unpack(fmus: dict[str, Path], into: Path) -> dict[str, Path]:
    """Unpack each FMU of ``fmus`` (instance -> file) into ``into/<instance>``."""
    from delaycomp.unpack import extract

    dirs = {}
    for name, path in fmus.items():
        dirs[name] = extract(path, Path(into) / name)  # within delaycomp.unpack's limits
    return dirs


def host_argv(exe: Path, loop, stop: float, dirs: dict[str, Path],
              timing: bool = False, exact_grid: bool = False,
              platform: str | None = None, start: float = 0.0) -> list[str]:
    """The C host's command line for the LTI loop ``loop`` (a
    ``Loop``, scalar or with vectors, its delays network channels or not) with the FMUs unpacked
    in ``dirs`` (instance -> folder): stop time, base step, folders, every parameter.

    Parameters
    ----------
    timing : bool
        The host prints the wall time of its stepping loop to stderr (``--timing``).
    exact_grid : bool
        The host keeps time as the FMI guides ask (``--exact-grid``): ``t_k = t0 + k h``
        computed from ``k``, each step ``t_{k+1} - t_k``; else every step is ``h``.
    platform : str, optional
        The host was built for this platform (``compile_host``): the command starts
        with its emulator (``emulator``; its environment is the caller's to pass) and
        names the folders as the emulated program sees them.
    start : float
        The start time ``t0`` (``--start=T0``); the run ends at ``stop``, an absolute time.
    """
    sets = [f"{inst.name}.{k}={str(v).lower() if isinstance(v, bool) else v}"
            for inst in loop.instances for k, v in inst.parameters.items()]
    prefix = emulator(platform)[0] if platform is not None else []
    return [*prefix, str(exe), *(["--timing"] if timing else []),
            *(["--exact-grid"] if exact_grid else []),
            *([f"--start={start!r}"] if start else []), repr(stop), repr(loop.T / loop.N),
            *(f"{n}={_host_path(dirs[n], platform)}"
              for n in ("plant", "meas_delay", "controller", "input_delay")),
            *sets]
