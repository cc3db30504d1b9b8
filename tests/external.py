"""Tools from outside the wheel, decided in one place for every test that needs one.

A test that runs OMSimulator, fmusim, a cross compiler, wine, qemu, valgrind, clang, the
sanitizer's library or a GPU asks ``need(name)`` for it. Where the tool is found it gets
what finding returned (a path, an install, a backend). Where it is absent:

- the test is **skipped** with the reason and how to get the tool (``-ra`` prints it in
  pytest's summary), so a fresh clone with nothing beside it is green;
- unless the environment **requires** the tool: ``DELAYCOMP_REQUIRE`` lists tool names
  (comma-separated, or ``all``), or the tool's own variable is set (``DELAYCOMP_OMSIMULATOR``,
  ``DELAYCOMP_FMUSIM``): then the test **fails** with the same one line. CI sets them
  (``.ci/run``), so a tool its machine should have never goes missing silently.

``TOOLS`` names every tool; asking for another name is an error of the test itself.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import pytest

#: the variable listing the tools whose absence fails a test (comma-separated, or ``all``)
REQUIRE = "DELAYCOMP_REQUIRE"
INSTALL = "scripts/install_platform_tools.sh"


@dataclass(frozen=True)
class Tool:
    """A tool from outside the wheel: how to get it, and the variable (if any) whose being
    set says that it is required here."""

    #: how to get it (one phrase, for the skip or failure line; empty where the finder's
    #: own message says it)
    how: str
    #: its own variable: set (to anything) means this machine is meant to have the tool
    env: str | None = None


def _apt(package: str) -> str:
    return f"`apt-get install {package}`, or {INSTALL}"


TOOLS: dict[str, Tool] = {
    # their locators' messages say how to get them (delaycomp.verify.omsimulator, .fmusim)
    "omsimulator": Tool("", env="DELAYCOMP_OMSIMULATOR"),
    "fmusim": Tool("", env="DELAYCOMP_FMUSIM"),
    "cc": Tool("install a C compiler (`apt-get install gcc`) or set CC"),
    "x86_64-w64-mingw32-gcc": Tool(_apt("gcc-mingw-w64-x86-64")),
    "aarch64-linux-gnu-gcc": Tool(_apt("gcc-aarch64-linux-gnu libc6-dev-arm64-cross")),
    "arm-none-eabi-gcc": Tool(_apt("gcc-arm-none-eabi libnewlib-arm-none-eabi")),
    "arm-none-eabi-nm": Tool(_apt("gcc-arm-none-eabi")),
    "wine": Tool(_apt("wine wine64")),
    "qemu-aarch64": Tool(_apt("qemu-user")),
    # the aarch64 C library qemu-user runs an aarch64 Linux program with
    "aarch64-libc": Tool(_apt("libc6-arm64-cross")),
    # the test extra's: Zig (the ziglang wheel of the native extra) and LIEF
    "zig": Tool("pip install 'delaycomp[native]' (the test extra has it), or a zig on PATH"),
    "lief": Tool("pip install lief (the test extra has it)"),
    "clang": Tool(_apt("clang")),
    "valgrind": Tool(_apt("valgrind")),
    "nm": Tool(_apt("binutils")),
    "gcc": Tool(_apt("gcc")),
    "libasan": Tool("the C compiler's -fsanitize=address runtime (`apt-get install gcc`, "
                    "which brings libasan)"),
    "gpu": Tool("pip install 'delaycomp[cupy]' on a machine with an NVIDIA GPU and CUDA 12"),
}


class Absent(Exception):
    """Raised by a ``find`` function: the tool is not here (the message says what was
    looked for)."""


def required(name: str, environ: dict[str, str] | None = None) -> bool:
    """Whether the environment says tool ``name`` must be here (its absence fails).

    Examples
    --------
    >>> required("wine", {"DELAYCOMP_REQUIRE": "qemu-aarch64, wine"})
    True
    >>> required("omsimulator", {"DELAYCOMP_OMSIMULATOR": "/opt/oms"})
    True
    >>> required("gpu", {"DELAYCOMP_REQUIRE": "all"}), required("gpu", {})
    (True, False)
    """
    environ = os.environ if environ is None else environ
    tool = TOOLS[name]
    names = {n.strip() for n in environ.get(REQUIRE, "").split(",") if n.strip()}
    return "all" in names or name in names or bool(tool.env and environ.get(tool.env))


def _which(name: str) -> Callable[[], str]:
    def find() -> str:
        path = shutil.which(name)
        if path is None:
            raise Absent(f"{name} is not on PATH")
        return path
    return find


def need(name: str, find: Callable[[], Any] | None = None,
         absent: tuple[type[BaseException], ...] = (), what: str = "") -> Any:
    """The tool ``name`` (``find()``'s result; by default its path on ``PATH``).

    Where ``find`` raises ``Absent`` or one of ``absent``, the test is skipped with one
    line naming the tool, why it was not found, how to get it and ``what`` was not checked;
    where the environment requires the tool (``required``) the test fails with that line.
    """
    if name not in TOOLS:
        raise KeyError(f"tests/external.py knows no tool {name!r}: add it to TOOLS")
    try:
        return (find or _which(name))()
    except (Absent, *absent) as exc:
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    how = TOOLS[name].how
    line = (f"{name} not found ({why})" + (f": {how}" if how else "")
            + (f"; {what} not checked" if what else ""))
    if required(name):
        pytest.fail(f"{line} [required here: {_why_required(name)}]", pytrace=False)
    pytest.skip(line)


def _why_required(name: str) -> str:
    tool = TOOLS[name]
    if tool.env and os.environ.get(tool.env):
        return f"{tool.env} is set"
    return f"{REQUIRE}={os.environ.get(REQUIRE, '')}"
