"""pythonfmu's runtime library as the Python FMUs ship it: with one fix.

pythonfmu copies its C++ runtime (``libpythonfmu-export.so``, sources
``src/pythonfmu/PySlaveInstance.cpp`` of https://github.com/NTNU-IHB/PythonFMU, version
0.7.0) into every FMU as ``binaries/linux64/<modelIdentifier>.so``. It keeps the state
shared by the instances in a namespace-scope ``std::shared_ptr<PyState> pyState`` and also
resets it from a library destructor (``__attribute__((destructor)) onLibraryUnload``, which
calls the exported ``finalizePythonInterpreter``: ``pyState = nullptr``).

The defect: a library still loaded when the process exits (always the first pythonfmu FMU a
process loads: its ``STB_GNU_UNIQUE`` symbols make ``dlclose`` keep it) has its C++ static
destructors run first, by ``exit``'s handlers, which free the ``PyState`` block (128 bytes,
shared count and object in one); the library destructors run after them (``_dl_fini``), and
``finalizePythonInterpreter`` then decrements the use count inside the freed block, at the
offset where a free chunk keeps its ``bk`` link. A later ``free`` at exit aborts with
"corrupted double-linked list" (valgrind: "Invalid read of size 4 at
finalizePythonInterpreter, 8 bytes inside a block of size 128 free'd by
__run_exit_handlers, alloc'd by pythonfmu::createInstance"). An FMU that ``dlclose``
unloads runs the two in the other order and is not affected.

The fix, ``patch_runtime``: ``finalizePythonInterpreter`` returns at once (one byte:
``ret`` after its ``endbr64``). The shared pointer's own static destructor is then the only
end of the ``PyState``, at exit as at ``dlclose``, where it ran right after the library
destructor anyway; what ending the ``PyState`` does (a host that is not Python: the thread
that started Python finalizes it) is unchanged. The fix in the sources would be the same:
no ``onLibraryUnload``, or a ``pyState`` that no static destructor frees.

The patch finds the function by its exported symbol (``.dynsym``), so it does not depend on
one build of the library; a library without the symbol is left as it is. Only the
``linux64`` library is patched: on Windows the C runtime ends a DLL's statics after
``DllMain``.
"""

from __future__ import annotations

import struct
from importlib.metadata import distribution
from pathlib import Path

#: the exported function whose body the patch replaces with ``ret``
SYMBOL = b"finalizePythonInterpreter"
#: the FMU folder of the library the patch applies to
PLATFORM_FOLDER = "binaries/linux64/"
_ENDBR64 = b"\xf3\x0f\x1e\xfa"
_RET = b"\xc3"
_SHT_DYNSYM = 11
_PT_LOAD = 1


def _symbol_offset(data: bytes, name: bytes) -> int | None:
    """File offset of the code of the exported function ``name`` in the ELF64
    little-endian library ``data`` (None: no such symbol, or not an ELF64 LE file)."""
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        return None
    phoff, shoff = struct.unpack_from("<QQ", data, 0x20)
    phentsize, phnum, shentsize, shnum = struct.unpack_from("<HHHH", data, 0x36)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize)
                for i in range(shnum)]
    address = None
    for sec in sections:
        if sec[1] != _SHT_DYNSYM:
            continue
        strtab = sections[sec[6]]
        for k in range(sec[5] // sec[9]):
            st_name, _info, _other, shndx, value, _size = struct.unpack_from(
                "<IBBHQQ", data, sec[4] + k * sec[9])
            end = data.index(b"\0", strtab[4] + st_name)
            if shndx != 0 and data[strtab[4] + st_name:end] == name:
                address = value
    if address is None:
        return None
    for i in range(phnum):
        p_type, _flags, offset, vaddr, _paddr, filesz, _memsz, _align = struct.unpack_from(
            "<IIQQQQQQ", data, phoff + i * phentsize)
        if p_type == _PT_LOAD and vaddr <= address < vaddr + filesz:
            return address - vaddr + offset
    return None


def patch_runtime(data: bytes) -> bytes:
    """pythonfmu's linux64 runtime library ``data`` with ``finalizePythonInterpreter`` made
    to return at once (module docstring); ``data`` unchanged where it has no such function.
    Patching a patched library changes nothing.

    >>> stock = stock_runtime().read_bytes()
    >>> fixed = patch_runtime(stock)
    >>> sum(a != b for a, b in zip(stock, fixed)), patch_runtime(fixed) == fixed
    (1, True)
    """
    offset = _symbol_offset(data, SYMBOL)
    if offset is None:
        return data
    if data[offset:offset + 4] == _ENDBR64:  # keep the landing pad of an indirect jump
        offset += 4
    return data[:offset] + _RET + data[offset + 1:]


def is_runtime(member: str) -> bool:
    """Is the FMU member ``member`` the linux64 runtime library that ``patch_runtime``
    fixes?"""
    return member.startswith(PLATFORM_FOLDER) and member.endswith(".so")


def stock_runtime() -> Path:
    """pythonfmu's own linux64 runtime library, as installed (found through the installed
    distribution: a host of pythonfmu FMUs may import ``pythonfmu`` from an FMU's
    resources, which hold no library)."""
    member = f"pythonfmu/resources/{PLATFORM_FOLDER}libpythonfmu-export.so"
    return Path(str(distribution("pythonfmu").locate_file(member)))
