"""What a shared library asks of the machine that loads it, read from its file with LIEF
(ELF, PE and Mach-O, universal binaries included): its architecture, the libraries it
imports, the newest glibc symbol version it needs, and the functions it exports.

The rule every native FMU's binaries follow (issue 51, item 3): a library loads anywhere
its platform runs.

- Linux: no glibc symbol newer than 2.17 and no library beyond libc and libm;
- Windows: only DLLs of Windows itself (KERNEL32 and the universal C runtime's API sets);
- macOS: only libSystem, and the library names itself by its file (``@rpath/<file>``),
  never by the folder it was built in.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from .external import need

#: the libraries a Linux binary may import
LINUX_LIBS = {"libc.so.6", "libm.so.6"}
#: the newest glibc symbol version a Linux binary may need
GLIBC_MAX = (2, 17)
#: macOS's C library
LIB_SYSTEM = "/usr/lib/libSystem.B.dylib"


def lief():
    """LIEF (the test extra), or the test skipped/failed naming it (tests/external.py)."""
    def find():
        import lief as module

        module.logging.disable()
        return module
    return need("lief", find, absent=(ImportError,), what="the binaries' imports")


@dataclass(frozen=True)
class Image:
    """One architecture's image of a shared library."""

    #: ``x86_64-linux``, ``aarch64-linux``, ``x86_64-windows``, ``x86_64-darwin``,
    #: ``aarch64-darwin``
    platform: str
    #: the libraries it imports (ELF: DT_NEEDED; PE: the DLLs; Mach-O: LC_LOAD_DYLIB)
    imports: frozenset[str]
    #: the functions it exports (Mach-O's without their leading underscore)
    exports: frozenset[str]
    #: ELF: the newest GLIBC_x.y version of its imported symbols; else None
    glibc: tuple[int, ...] | None = None
    #: Mach-O: the name it gives itself (LC_ID_DYLIB); else None
    install_name: str | None = None


def images(data: bytes) -> list[Image]:
    """The images of a shared library's bytes (a universal Mach-O has several)."""
    lf = lief()
    if data[:4] in (b"\xca\xfe\xba\xbe", b"\xcf\xfa\xed\xfe"):
        fat = lf.MachO.parse(list(data))
        return [_macho(lf, fat.at(i)) for i in range(fat.size)]
    binary = lf.parse(list(data))
    if isinstance(binary, lf.ELF.Binary):
        arch = {lf.ELF.ARCH.X86_64: "x86_64", lf.ELF.ARCH.AARCH64: "aarch64"}[
            binary.header.machine_type]
        versions = [tuple(int(x) for x in m.group(1).split("."))
                    for s in binary.imported_symbols
                    if s.has_version and s.symbol_version.has_auxiliary_version
                    for m in [re.fullmatch(r"GLIBC_([\d.]+)",
                                           s.symbol_version.symbol_version_auxiliary.name)]
                    if m]
        return [Image(f"{arch}-linux", frozenset(binary.libraries),
                      frozenset(s.name for s in binary.exported_symbols),
                      glibc=max(versions) if versions else None)]
    assert isinstance(binary, lf.PE.Binary), type(binary)
    assert binary.header.machine == lf.PE.Header.MACHINE_TYPES.AMD64
    return [Image("x86_64-windows", frozenset(i.name for i in binary.imports),
                  frozenset(e.name for e in binary.get_export().entries))]


def _macho(lf, binary) -> Image:
    arch = {lf.MachO.Header.CPU_TYPE.X86_64: "x86_64",
            lf.MachO.Header.CPU_TYPE.ARM64: "aarch64"}[binary.header.cpu_type]
    loads = {lib.name for lib in binary.libraries
             if lib.command == lf.MachO.LoadCommand.TYPE.LOAD_DYLIB}
    ids = [lib.name for lib in binary.libraries
           if lib.command == lf.MachO.LoadCommand.TYPE.ID_DYLIB]
    return Image(f"{arch}-darwin", frozenset(loads),
                 frozenset(s.name.removeprefix("_") for s in binary.exported_symbols),
                 install_name=ids[0] if ids else None)


def fmi_functions(version: int) -> set[str]:
    """Every function the FMI headers declare for ``version`` (2 or 3) that a
    co-simulation FMU's library exports (fmpy's copy of the headers): FMI 2.0's without
    the Model Exchange ones (an FMU of one interface exports its own), FMI 3.0's all (the
    standard asks every function of a library)."""
    from delaycomp.fmu.native import fmi_header_dir

    text = (fmi_header_dir() / f"fmi{version}Functions.h").read_text()
    if version == 2:  # the exports' part of the header: common, ME, CS
        me = text.rindex("Functions for FMI2 for Model Exchange")
        cs = text.rindex("Functions for FMI2 for Co-Simulation")
        text = text[:me] + text[cs:]
    return set(re.findall(rf"FMI{version}_Export\s+\w+TYPE\s+(fmi{version}\w+)\s*;", text))


def system_dll(name: str) -> bool:
    """A DLL every Windows (10 and later) has: KERNEL32 and the universal C runtime's
    API sets."""
    low = name.lower()
    return low == "kernel32.dll" or re.fullmatch(r"api-ms-win-crt-[a-z]+-l1-1-0\.dll",
                                                 low) is not None


def loads_anywhere(image: Image, file: str) -> list[str]:
    """What keeps ``image`` (of the library ``file``) from loading on every machine of
    its platform: empty where nothing does."""
    why = []
    if image.platform.endswith("-linux"):
        if not image.imports <= LINUX_LIBS:
            why.append(f"imports {sorted(image.imports - LINUX_LIBS)}")
        if image.glibc is not None and image.glibc > GLIBC_MAX:
            why.append(f"needs GLIBC_{'.'.join(map(str, image.glibc))}")
    elif image.platform.endswith("-windows"):
        others = sorted(n for n in image.imports if not system_dll(n))
        if others:
            why.append(f"imports {others}")
    else:
        if image.imports != {LIB_SYSTEM}:
            why.append(f"imports {sorted(image.imports)}")
        if image.install_name != f"@rpath/{Path(file).name}":
            why.append(f"names itself {image.install_name!r}")
    return why
