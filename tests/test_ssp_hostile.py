"""Hostile ``.ssp`` archives (issue 16, item 5), read side: each is refused with one line.

Before the fixes: an SSD component whose ``source`` climbed out of the archive (``../``,
an absolute path) silently loaded an FMU from outside; a broken FMU inside gave a 42-line
traceback; ``N="0"`` a ZeroDivisionError; ``T="nan"`` an unclear message; nothing bounded
what an archive unpacks to.
"""

from __future__ import annotations

import re
import zipfile

import pytest

from delaycomp.formats import ssp

from .test_cli import cli

pytestmark = pytest.mark.fmu


@pytest.fixture(scope="module")
def good(tmp_path_factory, fmu_dir):
    spec, info = ssp.scenario_system("example-3.6")
    return ssp.pack(spec, info, tmp_path_factory.mktemp("ssp") / "good.ssp", fmu_dir=fmu_dir)


def _variant(good, path, ssd=None, replace_member=None, extra=None):
    """A copy of ``good`` with the SSD rewritten by ``ssd(text)``, one member replaced
    (``(name, bytes)``) or extra members added."""
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(path, "w") as zf:
        for item in src.namelist():
            data = src.read(item)
            if item == ssp.SSD_NAME and ssd is not None:
                data = ssd(data.decode("utf-8")).encode("utf-8")
            if replace_member and item == replace_member[0]:
                data = replace_member[1]
            zf.writestr(item, data)
        for name, data in (extra or []):
            zf.writestr(name, data)
    return path


def _refusal(path):
    with pytest.raises(ssp.SspError) as info:
        with ssp.Archive(path):
            pass
    message = str(info.value)
    assert "\n" not in message
    return message


def _first_source(text):
    return re.search(r'source="(resources/[^"]+\.fmu)"', text).group(1)


@pytest.mark.parametrize("source", ["../outside.fmu", "resources/../../outside.fmu",
                                    "/tmp/outside.fmu", "file:///tmp/outside.fmu"])
def test_component_source_outside_the_archive_is_refused(good, tmp_path, source):
    def ssd(text):
        return text.replace(f'source="{_first_source(text)}"', f'source="{source}"', 1)
    message = _refusal(_variant(good, tmp_path / "x.ssp", ssd=ssd))
    assert f"source {source!r} is not allowed" in message


def test_broken_fmu_inside_is_one_line(good, tmp_path):
    with zipfile.ZipFile(good) as zf:
        member = _first_source(zf.read(ssp.SSD_NAME).decode("utf-8"))
    path = _variant(good, tmp_path / "x.ssp", replace_member=(member, b"PK\x03\x04junk"))
    assert f"{member} is not an FMU: not a zip archive" in _refusal(path)
    proc = cli("run", str(path))
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


@pytest.mark.parametrize("attr,value,message", [
    ("N", "0", 'dc:Master N = 0 is not allowed: must be an integer from 1'),
    ("N", "-4", 'dc:Master N = -4 is not allowed'),
    ("T", "nan", "dc:Master T = nan is not allowed: must be a finite number > 0"),
    ("T", "0", "dc:Master T = 0.0 is not allowed"),
    ("T", "-inf", "dc:Master T = -inf is not allowed"),
])
def test_master_settings_out_of_range_are_named(good, tmp_path, attr, value, message):
    def ssd(text):
        return re.sub(rf'(<dc:Master[^>]* {attr}=")[^"]*"', rf'\g<1>{value}"', text, count=1)
    assert message in _refusal(_variant(good, tmp_path / "x.ssp", ssd=ssd))


def test_stop_time_nan_is_named(good, tmp_path):
    def ssd(text):
        return re.sub(r'stopTime="[^"]*"', 'stopTime="nan"', text, count=1)
    assert "stopTime = 'nan' is not allowed: must be a finite number >= 0" in _refusal(
        _variant(good, tmp_path / "x.ssp", ssd=ssd))


def test_archive_that_unpacks_too_much_is_refused_before_unpacking(good, tmp_path):
    """600 MiB of zeros compress to about 0.6 MB: refused from the sizes the zip declares,
    before anything is written."""
    path = tmp_path / "bomb.ssp"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for item in src.namelist():
            zf.writestr(item, src.read(item))
        with zf.open("resources/zeros.bin", "w", force_zip64=True) as fh:
            block = bytes(2**20)
            for _ in range(600):
                fh.write(block)
    assert path.stat().st_size < 5 * 2**20
    message = _refusal(path)
    assert re.search(r"unpacks to \d+ files of \d+ bytes: at most 1000 files and 536870912 "
                     r"bytes are allowed", message), message
