"""The C tool chains of the native FMUs: the platforms a build gives and what compiles each.

A native FMU carries binaries for five platforms (``PLATFORMS``, named by their FMI 3.0
platform tuples): x86_64 and aarch64 Linux, x86_64 Windows, x86_64 and arm64 macOS. One
compiler builds them all, wherever delaycomp runs: Zig's (``zig cc``, from the ``ziglang``
wheel of the ``native`` extra, or a ``zig`` on ``PATH``), which carries the C library
headers of every target. Its targets are chosen for reach:

- Linux: ``x86_64-linux-gnu.2.17`` and ``aarch64-linux-gnu.2.17``: no glibc symbol newer
  than 2.17 (RHEL 7, Ubuntu 14.04 and later), no shared library beyond libc and libm;
- Windows: ``x86_64-windows-gnu``: the universal C runtime and KERNEL32, system DLLs of
  every Windows since 10;
- macOS: ``x86_64-macos.10.13`` and ``aarch64-macos.11.0``: libSystem only. FMI 2.0 names
  one macOS folder, ``darwin64``: it gets a universal binary of both (``universal``), as
  importers on either architecture load it (fmpy, OMSimulator); the arm64 one also goes
  into ``aarch64-darwin``, the folder FMI 2.0.4 names for it. FMI 3.0 has a folder each.

Where no Zig is found, a system compiler builds what it can: this machine's
platform with ``$CC``, ``cc``, ``gcc`` or ``clang``; ``x86_64-windows`` and
``aarch64-linux`` with Debian's cross compilers (``$CC_WIN64``, ``$CC_AARCH64``); a
platform without a compiler is left out with one note. A compiler variable that is set
(``$CC`` for this machine's platform, ``$CC_WIN64``, ``$CC_AARCH64``) wins over Zig:
the user chose it. ``$DELAYCOMP_ZIG`` names the Zig command (empty: use none).

Examples
--------
>>> sorted(PLATFORMS)
['aarch64-darwin', 'aarch64-linux', 'x86_64-darwin', 'x86_64-linux', 'x86_64-windows']
>>> parse_platforms("win64, darwin64", "--platforms")
('x86_64-windows', 'x86_64-darwin', 'aarch64-darwin')
"""

from __future__ import annotations

import contextlib
import functools
import os
import shlex
import shutil
import struct
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from delaycomp.errors import DelaycompError

__all__ = ["ALIASES", "PLATFORMS", "Compiler", "NativeBuildError", "Platform", "chosen",
           "compiler_for", "host_compiler", "how_to_get", "parse_platforms", "place",
           "pop_notes", "requested", "system_compiler", "targets", "this_platform",
           "universal", "zig"]


class NativeBuildError(DelaycompError, RuntimeError):
    """A native FMU cannot be built here (no C compiler, or the compiler failed)."""


@dataclass(frozen=True)
class Platform:
    """One platform a native FMU carries a binary for."""

    #: the FMI 3.0 platform tuple: its binaries folder in an FMI 3.0 FMU
    name: str
    #: the binaries folder in an FMI 2.0 FMU (FMI 2.0's name, or FMI 2.0.4's tuple)
    fmi2: str
    #: Zig's target (``zig cc -target``)
    zig: str
    #: the shared library's suffix
    suffix: str
    #: without Zig: (the variable naming its compiler, the compiler's default name, the
    #: Debian package that brings it, flags beside ``CFLAGS``); ``None``: only Zig builds it
    #: (or, on this machine, the system compiler)
    system: tuple[str, str, str, tuple[str, ...]] | None = None

    @property
    def os(self) -> str:
        """``linux``, ``windows`` or ``darwin``."""
        return self.name.partition("-")[2]


#: the platforms of a native FMU, by FMI 3.0 platform tuple, in the order a build lists them
PLATFORMS: dict[str, Platform] = {p.name: p for p in (
    Platform("x86_64-linux", "linux64", "x86_64-linux-gnu.2.17", ".so"),
    Platform("aarch64-linux", "aarch64-linux", "aarch64-linux-gnu.2.17", ".so",
             ("CC_AARCH64", "aarch64-linux-gnu-gcc", "gcc-aarch64-linux-gnu", ())),
    Platform("x86_64-windows", "win64", "x86_64-windows-gnu", ".dll",
             ("CC_WIN64", "x86_64-w64-mingw32-gcc", "gcc-mingw-w64-x86-64",
              ("-static-libgcc",))),
    Platform("x86_64-darwin", "darwin64", "x86_64-macos.10.13", ".dylib"),
    Platform("aarch64-darwin", "darwin64", "aarch64-macos.11.0", ".dylib"),
)}
#: other names a platform list takes: FMI 2.0's folders (``darwin64``: both macOS ones)
ALIASES: dict[str, tuple[str, ...]] = {
    "linux64": ("x86_64-linux",), "win64": ("x86_64-windows",),
    "darwin64": ("x86_64-darwin", "aarch64-darwin")}
#: flags of every compiler beside the build's own (Windows: C99's printf in the MinGW
#: headers, whatever the runtime)
OS_FLAGS = {"windows": ("-D__USE_MINGW_ANSI_STDIO=1",)}
#: flags of Zig beside them: no debug information in the binaries
ZIG_FLAGS = ("-s",)
#: the Mach-O CPU types of ``universal`` (``mach/machine.h``)
_MACHO_CPU = {0x01000007: "x86_64", 0x0100000C: "arm64"}

#: notes of this process about platforms left out (each once; see ``pop_notes``)
_NOTES: list[str] = []
_NOTED: set[str] = set()
#: the platforms chosen for the builds of a block (``chosen``); None: ``requested``'s default
_CHOSEN: tuple[str, ...] | None = None


@dataclass(frozen=True)
class Compiler:
    """A C compiler command for one platform."""

    #: the command up to the build's flags (Zig: ``... cc -target T``)
    argv: tuple[str, ...]
    #: flags it needs beside the build's
    flags: tuple[str, ...]
    #: how ``-v`` names it (``zig 0.17.1``, ``gcc``, ``x86_64-w64-mingw32-gcc``)
    label: str
    #: Zig's (the build cache tells its FMUs from a system compiler's)
    zig: bool = False


def _note(text: str) -> None:
    if text not in _NOTED:
        _NOTED.add(text)
        _NOTES.append(text)


def pop_notes() -> list[str]:
    """The notes about platforms left out since the last call (each note once per
    process): the commands print them, ``delaycomp.api.build`` returns them."""
    out = list(_NOTES)
    _NOTES.clear()
    return out


def this_platform() -> str | None:
    """This machine's platform tuple where it is one of ``PLATFORMS`` (fmpy's name for
    it), else ``None`` (its binary is built by the system compiler alone)."""
    import fmpy

    name = getattr(fmpy, "platform_tuple", None)
    return name if name in PLATFORMS else None


def parse_platforms(text: str, where: str) -> tuple[str, ...]:
    """The platforms a comma-separated list names (tuples or ``ALIASES``), in
    ``PLATFORMS``' order, each once; ``where`` names the list in the error.

    Raises
    ------
    NativeBuildError
        A name that is no platform: one line with the allowed names.
    """
    names: list[str] = []
    for word in (w.strip() for w in text.split(",")):
        if not word:
            continue
        found = ALIASES.get(word, (word,) if word in PLATFORMS else None)
        if found is None:
            raise NativeBuildError(
                f"{where} names {word!r}: allowed are {', '.join(PLATFORMS)} (or "
                f"{', '.join(ALIASES)}), comma-separated")
        names.extend(found)
    return tuple(p for p in PLATFORMS if p in names)


@contextlib.contextmanager
def chosen(names: tuple[str, ...] | None) -> Iterator[None]:
    """The native builds of the block give exactly ``names`` (``build --platforms``);
    ``None``: ``requested``'s default."""
    global _CHOSEN
    before, _CHOSEN = _CHOSEN, names
    try:
        yield
    finally:
        _CHOSEN = before


def requested() -> tuple[str, ...]:
    """The platforms to build: those ``chosen`` for the block, else this machine's and
    those ``$DELAYCOMP_PLATFORMS`` names (comma-separated; empty: this machine's alone),
    else every one of ``PLATFORMS``."""
    if _CHOSEN is not None:
        return _CHOSEN
    text = os.environ.get("DELAYCOMP_PLATFORMS")
    if text is None:
        return tuple(PLATFORMS)
    listed = parse_platforms(text, "DELAYCOMP_PLATFORMS")
    here = this_platform()
    return tuple(p for p in PLATFORMS if p in listed or p == here)


def zig() -> list[str] | None:
    """The Zig command: ``$DELAYCOMP_ZIG`` (empty: none), else the ``ziglang`` wheel's
    (``python -m ziglang``), else ``zig`` on ``PATH``, else ``None``."""
    given = os.environ.get("DELAYCOMP_ZIG")
    if given is not None:
        if not given.strip():
            return None
        argv = shlex.split(given)
        if not shutil.which(argv[0]):
            raise NativeBuildError(f"DELAYCOMP_ZIG = {given!r} is not allowed: no such "
                                   "program on PATH (name a zig, or set it empty to use "
                                   "none)")
        return argv
    import importlib.util

    if importlib.util.find_spec("ziglang") is not None:
        return [sys.executable, "-m", "ziglang"]
    found = shutil.which("zig")
    return [found] if found else None


@functools.cache
def _zig_version(argv: tuple[str, ...]) -> str:
    """The version of the Zig command: the ziglang wheel's, else what ``zig version``
    says (asked once per process)."""
    if argv == (sys.executable, "-m", "ziglang"):
        from importlib.metadata import PackageNotFoundError, version

        with contextlib.suppress(PackageNotFoundError):
            return version("ziglang")
    try:
        proc = subprocess.run([*argv, "version"], capture_output=True, text=True,
                              timeout=120)
    except OSError:
        return "?"
    return proc.stdout.strip() or "?"


def system_compiler() -> list[str]:
    """This machine's system C compiler: ``$CC`` if set, else the first of ``cc``,
    ``gcc``, ``clang`` (what compiler-specific uses need: sanitizers, ``-print-file-name``).

    Raises
    ------
    NativeBuildError
        None found; the message names what to install.
    """
    cc = os.environ.get("CC")
    if cc:
        argv = shlex.split(cc)
        if argv and shutil.which(argv[0]):
            return argv
        raise NativeBuildError(f"CC = {cc!r} is not allowed: no such program on PATH "
                               "(set CC to a C compiler, or unset it)")
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return [path]
    raise NativeBuildError("no C compiler found (looked for zig, $CC, cc, gcc, clang): "
                           "`pip install 'delaycomp[native]'` brings one (zig) for every "
                           "platform; or install one, e.g. `apt-get install gcc` "
                           "(Debian/Ubuntu) or `xcode-select --install` (macOS), or set CC")


def host_compiler() -> list[str]:
    """The C compiler for programs and libraries of this machine (the C host, the channel
    kernel): ``$CC`` if set, else Zig with the target of this machine's FMU binaries (the
    platform's baseline CPU, as a system compiler's default: no instruction another
    machine of the platform lacks, and no fused multiply-adds, ``-ffp-contract=off``, as
    gcc in ISO C mode), else ``system_compiler``."""
    if not os.environ.get("CC"):
        z = zig()
        here = this_platform()
        if z is not None:
            target = ("-target", PLATFORMS[here].zig) if here else ()
            return [*z, "cc", *target, "-ffp-contract=off"]
    return system_compiler()


def compiler_for(name: str) -> Compiler | None:
    """The compiler of platform ``name`` (a key of ``PLATFORMS``): its variable where
    set (``$CC`` for this machine's), else Zig, else this machine's system compiler or
    the Debian cross compiler on ``PATH``; ``None`` where there is none.

    Raises
    ------
    NativeBuildError
        A variable that names no program.
    """
    p = PLATFORMS[name]
    here = name == this_platform()
    var = "CC" if here else p.system[0] if p.system else None
    extra = OS_FLAGS.get(p.os, ())
    if var and os.environ.get(var):
        given = os.environ[var]
        argv = shlex.split(given)
        if not shutil.which(argv[0]):
            whose = "" if here else f" for {name}"
            raise NativeBuildError(f"{var} = {given!r} is not allowed: no such program on "
                                   f"PATH (set {var} to a C compiler{whose}, or unset it)")
        flags = () if here or p.system is None else p.system[3]
        return Compiler(tuple(argv), (*flags, *extra), Path(argv[0]).name)
    z = zig()
    if z is not None:
        return Compiler((*z, "cc", "-target", p.zig), (*ZIG_FLAGS, *extra),
                        f"zig {_zig_version(tuple(z))}", zig=True)
    if here:
        with contextlib.suppress(NativeBuildError):
            argv = system_compiler()
            return Compiler(tuple(argv), extra, Path(argv[0]).name)
        return None
    if p.system is not None and shutil.which(p.system[1]):
        return Compiler((p.system[1],), (*p.system[3], *extra), p.system[1])
    return None


def how_to_get(name: str) -> str:
    """How to get a compiler for platform ``name``: Zig, or its Debian cross compiler."""
    p = PLATFORMS[name]
    how = f"; or `apt-get install {p.system[2]}`, or set {p.system[0]}" if p.system else ""
    return f"`pip install 'delaycomp[native]'` brings zig, which builds every platform{how}"


def targets() -> dict[str, Compiler]:
    """The platforms to build (``requested``) that have a compiler here, with it; each
    left out gets one note (``pop_notes``). This machine's platform, where it is not one
    of ``PLATFORMS``, is built by the system compiler under fmpy's names.

    Raises
    ------
    NativeBuildError
        No platform can be built (no compiler at all): one line naming what to install.
    """
    found: dict[str, Compiler] = {}
    here = this_platform()
    for name in sorted(requested(), key=lambda n: n != here):  # this machine's first
        c = compiler_for(name)
        if c is not None:
            found[name] = c
            continue
        _note(f"note: native FMUs without {name} binaries: no compiler for it here "
              f"({how_to_get(name)}; --platforms or DELAYCOMP_PLATFORMS chooses the "
              "platforms)")
    if here is None and _CHOSEN is None:
        found["host"] = Compiler(tuple(system_compiler()), (), "system")
    if here is not None and here in requested() and here not in found:
        system_compiler()  # raises: this machine's platform has no compiler at all
    if not found:
        raise NativeBuildError("no C compiler for any platform asked for ("
                               f"{', '.join(requested()) or 'none'}): `pip install "
                               "'delaycomp[native]'` brings zig, which builds every platform")
    return found


def folders(name: str, fmi: int) -> list[str]:
    """The binaries folders platform ``name``'s library goes into in an FMU of version
    ``fmi`` (``"host"``: this machine's, as fmpy names it)."""
    import fmpy

    if name == "host":
        return [fmpy.platform if fmi == 2 else fmpy.platform_tuple]
    p = PLATFORMS[name]
    if fmi == 3:
        return [p.name]
    return [p.fmi2, *([p.name] if p.name == "aarch64-darwin" else [])]


def suffix(name: str) -> str:
    """The shared library suffix of platform ``name``."""
    if name == "host":
        from fmpy import sharedLibraryExtension

        return sharedLibraryExtension
    return PLATFORMS[name].suffix


def place(built: dict[str, Path], binaries: Path, ident: str, fmi: int) -> None:
    """Copy each built library (platform -> file) into its folders under ``binaries``;
    the macOS ones of FMI 2.0's ``darwin64`` as one ``universal`` binary."""
    merged: dict[Path, list[bytes]] = {}
    for name, lib in built.items():
        for folder in folders(name, fmi):
            target = binaries / folder / f"{ident}{suffix(name)}"
            merged.setdefault(target, []).append(lib.read_bytes())
    for target, datas in merged.items():
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(datas[0] if len(datas) == 1 else universal(datas))


def universal(thin: list[bytes]) -> bytes:
    """A universal (fat) Mach-O binary of the thin 64-bit ones (``lipo -create``): the
    big-endian fat header, one ``fat_arch`` per architecture, each image at an offset
    aligned to 2^14 bytes (the arm64 page; Apple's lipo aligns so).

    Raises
    ------
    ValueError
        An image that is no thin little-endian 64-bit Mach-O, or two of one architecture.
    """
    align = 14
    entries, seen = [], set()
    offset = 8 + 20 * len(thin)
    for data in thin:
        if data[:4] != b"\xcf\xfa\xed\xfe":
            raise ValueError("universal: an image is not a thin 64-bit Mach-O")
        cputype, subtype = struct.unpack_from("<iI", data, 4)
        if cputype in seen:
            raise ValueError(f"universal: two images of CPU type {cputype:#x}")
        seen.add(cputype)
        offset = -(-offset // (1 << align)) * (1 << align)
        entries.append((cputype, subtype, offset, len(data), data))
        offset += len(data)
    out = bytearray(struct.pack(">II", 0xCAFEBABE, len(entries)))
    for cputype, subtype, off, size, _ in entries:
        out += struct.pack(">iIIII", cputype, subtype, off, size, align)
    for _, _, off, _, data in entries:
        out += b"\0" * (off - len(out)) + data
    return bytes(out)
