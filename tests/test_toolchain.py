"""The native FMUs' tool chains (issue 51, ``delaycomp.fmu.toolchain``), without compiling:
which platforms a build gives, which compiler builds each, the folders their libraries go
into, and the universal macOS binary, checked against an independent reader (LIEF).
"""

from __future__ import annotations

import dataclasses
import struct

import pytest

from delaycomp.fmu import toolchain
from delaycomp.fmu.toolchain import NativeBuildError, parse_platforms

from .binimports import lief


def _thin(cputype: int, subtype: int, body: bytes) -> bytes:
    """A minimal thin 64-bit Mach-O image: its header (no load commands) and a body."""
    return struct.pack("<IiIIIIII", 0xFEEDFACF, cputype, subtype, 6, 0, 0, 0, 0) + body


def test_universal_binary_holds_each_image_where_its_header_says():
    """``universal`` of an x86_64 and an arm64 image: the fat header (big-endian) lists
    both, each at an offset aligned to 2^14 with its size, and the bytes there are the
    image; LIEF reads two architectures from it."""
    x86 = _thin(0x01000007, 3, b"x" * 5000)
    arm = _thin(0x0100000C, 0, b"a" * 70)
    fat = toolchain.universal([x86, arm])
    magic, count = struct.unpack_from(">II", fat, 0)
    assert (magic, count) == (0xCAFEBABE, 2)
    for i, image in enumerate((x86, arm)):
        cputype, subtype, offset, size, align = struct.unpack_from(">iIIII", fat, 8 + 20 * i)
        assert (cputype, subtype) == struct.unpack_from("<iI", image, 4)
        assert align == 14 and offset % (1 << 14) == 0 and size == len(image)
        assert fat[offset:offset + size] == image
    lf = lief()
    parsed = lf.MachO.parse(list(fat))
    assert parsed is not None and parsed.size == 2
    assert {parsed.at(i).header.cpu_type for i in range(2)} == {
        lf.MachO.Header.CPU_TYPE.X86_64, lf.MachO.Header.CPU_TYPE.ARM64}


def test_universal_refuses_what_is_no_thin_macho_and_twice_one_architecture():
    with pytest.raises(ValueError, match="not a thin 64-bit Mach-O"):
        toolchain.universal([b"\x7fELF" + b"\0" * 60])
    image = _thin(0x0100000C, 0, b"")
    with pytest.raises(ValueError, match="two images of CPU type 0x100000c"):
        toolchain.universal([image, image])


def test_platform_lists_take_tuples_and_fmi2_names_in_one_order():
    assert parse_platforms("darwin64,linux64", "--platforms") == (
        "x86_64-linux", "x86_64-darwin", "aarch64-darwin")
    assert parse_platforms(" win64 , x86_64-windows,", "X") == ("x86_64-windows",)
    assert parse_platforms("", "X") == ()
    with pytest.raises(NativeBuildError) as info:
        parse_platforms("linux64,riscv64-linux", "DELAYCOMP_PLATFORMS")
    assert str(info.value) == (
        "DELAYCOMP_PLATFORMS names 'riscv64-linux': allowed are x86_64-linux, "
        "aarch64-linux, x86_64-windows, x86_64-darwin, aarch64-darwin (or linux64, win64, "
        "darwin64), comma-separated")


def test_requested_platforms(monkeypatch):
    """Default: all five; ``DELAYCOMP_PLATFORMS``: this machine's and those named; a
    ``chosen`` block (``build --platforms``): exactly those, this machine's or not."""
    here = toolchain.this_platform()
    assert here is not None  # this suite runs on one of the five
    monkeypatch.delenv("DELAYCOMP_PLATFORMS", raising=False)
    assert toolchain.requested() == tuple(toolchain.PLATFORMS)
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "")
    assert toolchain.requested() == (here,)
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "aarch64-darwin")
    assert set(toolchain.requested()) == {here, "aarch64-darwin"}
    with toolchain.chosen(("x86_64-windows",)):
        assert toolchain.requested() == ("x86_64-windows",)
    assert set(toolchain.requested()) == {here, "aarch64-darwin"}


def test_fmi2_folders_put_both_macs_in_darwin64_and_arm64_beside_it():
    assert toolchain.folders("x86_64-linux", 2) == ["linux64"]
    assert toolchain.folders("x86_64-windows", 2) == ["win64"]
    assert toolchain.folders("aarch64-linux", 2) == ["aarch64-linux"]
    assert toolchain.folders("x86_64-darwin", 2) == ["darwin64"]
    assert toolchain.folders("aarch64-darwin", 2) == ["darwin64", "aarch64-darwin"]
    assert [toolchain.folders(p, 3) for p in toolchain.PLATFORMS] == [
        [p] for p in toolchain.PLATFORMS]


def _members(data: bytes) -> list[bytes]:
    """The images of a library (a universal one's by its fat header; a thin one: itself),
    the members a placed library is compared by."""
    if data[:4] != b"\xca\xfe\xba\xbe":
        return [data]
    count = struct.unpack_from(">I", data, 4)[0]
    return [data[off:off + size] for _, _, off, size, _ in
            (struct.unpack_from(">iIIII", data, 8 + 20 * i) for i in range(count))]


def test_place_merges_the_macs_into_one_universal_library(tmp_path):
    """FMI 2.0: darwin64 holds one universal library of both images, aarch64-darwin the
    arm64 one; FMI 3.0: each in its tuple's folder (compared by their Mach-O images)."""
    images = {"x86_64-darwin": _thin(0x01000007, 3, b"x"),
              "aarch64-darwin": _thin(0x0100000C, 0, b"a")}
    files = {}
    for name, data in images.items():
        files[name] = tmp_path / f"{name}.dylib"
        files[name].write_bytes(data)
    toolchain.place(files, tmp_path / "b", "M", 2)
    placed = {p.relative_to(tmp_path / "b").as_posix(): _members(p.read_bytes())
              for p in (tmp_path / "b").rglob("*.dylib")}
    assert placed == {"darwin64/M.dylib": list(images.values()),
                      "aarch64-darwin/M.dylib": [images["aarch64-darwin"]]}
    toolchain.place({"x86_64-darwin": files["x86_64-darwin"]}, tmp_path / "c", "M", 3)
    placed = {p.relative_to(tmp_path / "c").as_posix(): _members(p.read_bytes())
              for p in (tmp_path / "c").rglob("*.dylib")}
    assert placed == {"x86_64-darwin/M.dylib": [images["x86_64-darwin"]]}


def test_which_compiler_builds_what(monkeypatch, tmp_path):
    """A compiler variable that is set wins (the user chose it); else Zig, for every
    platform; with no Zig, this machine's system compiler and the Debian cross compilers
    on PATH, none for macOS; ``DELAYCOMP_ZIG`` empty uses no Zig, naming no program is an
    error."""
    here = toolchain.this_platform()
    fake = tmp_path / "bin"
    fake.mkdir()
    for name in ("zig", "cc", "x86_64-w64-mingw32-gcc"):
        (fake / name).write_text("#!/bin/sh\n")
        (fake / name).chmod(0o755)
    monkeypatch.setenv("PATH", str(fake))
    for var in ("CC", "CC_WIN64", "CC_AARCH64"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("DELAYCOMP_ZIG", str(fake / "zig"))
    monkeypatch.setattr(toolchain, "_zig_version", lambda argv: "0.0-test")
    for name, p in toolchain.PLATFORMS.items():
        c = toolchain.compiler_for(name)
        assert c is not None and c.argv == (str(fake / "zig"), "cc", "-target", p.zig)
        assert c.label == "zig 0.0-test" and "-s" in c.flags
    assert toolchain.PLATFORMS["x86_64-linux"].zig == "x86_64-linux-gnu.2.17"
    assert "-D__USE_MINGW_ANSI_STDIO=1" in toolchain.compiler_for("x86_64-windows").flags
    monkeypatch.setenv("CC_WIN64", "x86_64-w64-mingw32-gcc")
    assert toolchain.compiler_for("x86_64-windows").argv == ("x86_64-w64-mingw32-gcc",)
    monkeypatch.setenv("CC", "cc")
    assert toolchain.compiler_for(here).argv == ("cc",)
    assert toolchain.host_compiler() == ["cc"]
    monkeypatch.delenv("CC")
    monkeypatch.delenv("CC_WIN64")
    assert toolchain.host_compiler() == [str(fake / "zig"), "cc", "-target",
                                         toolchain.PLATFORMS[here].zig, "-ffp-contract=off"]
    monkeypatch.setenv("DELAYCOMP_ZIG", "")
    assert toolchain.compiler_for(here).argv == (str(fake / "cc"),)
    assert toolchain.compiler_for("x86_64-windows").argv == ("x86_64-w64-mingw32-gcc",)
    assert toolchain.compiler_for("aarch64-linux") is None
    assert toolchain.compiler_for("aarch64-darwin") is None
    monkeypatch.setenv("DELAYCOMP_ZIG", "no-such-zig")
    with pytest.raises(NativeBuildError, match="DELAYCOMP_ZIG = 'no-such-zig' is not "
                                               "allowed: no such program on PATH"):
        toolchain.zig()


def test_no_compiler_for_any_asked_platform_is_one_line(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setenv("DELAYCOMP_ZIG", "")
    monkeypatch.delenv("CC", raising=False)
    for name, p in toolchain.PLATFORMS.items():  # no Debian cross compiler either
        if p.system:
            monkeypatch.setitem(toolchain.PLATFORMS, name, dataclasses.replace(
                p, system=(p.system[0], "no-such-gcc", p.system[2], ())))
    with toolchain.chosen(("x86_64-windows", "aarch64-darwin")), \
            pytest.raises(NativeBuildError) as info:
        toolchain.targets()
    assert str(info.value) == ("no C compiler for any platform asked for (x86_64-windows, "
                               "aarch64-darwin): `pip install 'delaycomp[native]'` brings "
                               "zig, which builds every platform")
    toolchain.pop_notes()

