"""Archives bounded all the way down (issue 30, item 5).

An FMU inside an SSP is unpacked under the same limits as the archive itself, counted
together with it (``delaycomp.unpack``); a plant FMU of a loop file, the FMUs handed to
the container and the FMUs our master unpacks are held to the same limits, from the sizes
their zips declare, before anything is written. Before: a 4 MB SSP holding an FMU with a
600 MiB member was refused at the SSP's level only after its FMU had been unpacked whole
(600 MiB written to the temporary folder), and a loop file's plant FMU was unpacked with
no limit at all.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from delaycomp.unpack import MAX_BYTES, Budget, TooLarge, measure

from .test_broken_plant import LOOP

pytestmark = pytest.mark.fmu

#: what the refusals say (the limits of delaycomp.unpack)
LIMITS = r"at most 1000 files and 536870912 bytes are allowed"


def _with_zeros(src: Path, out: Path, mib: int, member: str = "resources/zeros.bin") -> Path:
    """``src`` (a zip) with one more member of ``mib`` MiB of zeros (they compress 1000:1)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            zout.writestr(item, zin.read(item))
        with zout.open(member, "w", force_zip64=True) as fh:
            block = bytes(2**20)
            for _ in range(mib):
                fh.write(block)
    return out


@pytest.fixture(scope="module")
def bomb(tmp_path_factory) -> Path:
    """The C test plant FMU with a member of 600 MiB of zeros (0.6 MB compressed)."""
    from tests.cfmu.build import build_oscillator

    folder = tmp_path_factory.mktemp("bomb")
    plain = build_oscillator(folder, "Plain.fmu")
    fmu = _with_zeros(plain, folder / "Broken.fmu", 600)
    assert fmu.stat().st_size < 3 * 2**20
    return fmu


def _run(*args, cwd: Path) -> tuple[subprocess.CompletedProcess, int]:
    """The CLI with its temporary folder under ``cwd``: the result and the bytes that
    folder holds afterwards (at most, while running, is not measured: the refusal comes
    before anything is written)."""
    tmp = cwd / "tmp"
    tmp.mkdir(exist_ok=True)
    proc = subprocess.run([sys.executable, "-m", "delaycomp", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "TMPDIR": str(tmp)})
    used = sum(f.stat().st_size for f in tmp.rglob("*") if f.is_file())
    return proc, used


def test_a_loop_files_plant_fmu_that_unpacks_too_much_is_refused(bomb, tmp_path):
    (tmp_path / "loop.toml").write_text(LOOP.replace('"Broken.fmu"', f'"{bomb}"'),
                                        encoding="utf-8")
    for args in (["run", "loop.toml"], ["export-loop", "loop.toml", "--out", "c.fmu"]):
        proc, used = _run(*args, cwd=tmp_path)
        assert proc.returncode == 2, proc.stdout + proc.stderr
        last = proc.stderr.strip()
        assert re.fullmatch(rf"delaycomp: error: \S*Broken\.fmu: unpacks to \d+ files of "
                            rf"\d+ bytes: {LIMITS}", last), last
        assert used < 2**20, used


def test_an_fmu_inside_an_ssp_counts_with_the_archive(bomb, tmp_path):
    """The SSP itself is small (3 MB): its plant FMU would unpack to 600 MiB."""
    from tests.cfmu.build import build_oscillator

    build_oscillator(tmp_path, "Broken.fmu")
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    proc, _ = _run("ssp", "loop.toml", "--out", "good.ssp", "--python", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    ssp = tmp_path / "bomb.ssp"
    with zipfile.ZipFile(tmp_path / "good.ssp") as zin, zipfile.ZipFile(ssp, "w") as zout:
        for item in zin.infolist():
            data = bomb.read_bytes() if item.filename == "resources/Broken.fmu" else \
                zin.read(item)
            zout.writestr(item, data)
    assert ssp.stat().st_size < 5 * 2**20
    proc, used = _run("run", "bomb.ssp", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert re.fullmatch(rf"delaycomp: error: bomb\.ssp: unpacks to \d+ files of \d+ bytes "
                        rf"\(with component plant: resources/Broken\.fmu\): {LIMITS}",
                        proc.stderr.strip()), proc.stderr
    assert used < 2**20, used  # the SSP's own members are removed with its folder


def test_one_budget_for_an_archive_and_the_archives_inside_it(tmp_path):
    """Two archives of 300 MiB each pass one by one and not together."""
    base = tmp_path / "empty.zip"
    with zipfile.ZipFile(base, "w") as zf:
        zf.writestr("modelDescription.xml", "<fmiModelDescription/>")
    half = _with_zeros(base, tmp_path / "half.fmu", 300)
    measure(half, Budget(half))  # alone: within the limits
    budget = Budget("outer.ssp")
    measure(half, budget, "component a")
    with pytest.raises(TooLarge, match=r"outer\.ssp: unpacks to 4 files of \d+ bytes "
                                       r"\(with component b\)"):
        measure(half, budget, "component b")
    assert budget.bytes > MAX_BYTES


@pytest.mark.parametrize("name", ["../evil.txt", "/etc/evil", "C:/evil", "a/../../evil"])
def test_a_member_that_leaves_the_folder_is_refused(tmp_path, name):
    from delaycomp.unpack import extract

    path = tmp_path / "x.fmu"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("modelDescription.xml", "<fmiModelDescription/>")
        zf.writestr(name, "x")
    with pytest.raises(TooLarge, match="it leaves the archive"):
        extract(path, tmp_path / "out")
    assert not (tmp_path / "out").exists()
