"""FMU files and the shared build cache (issue 16, items 5 and 6).

Before the fixes: four parallel first runs on an empty cache failed 22 of 52 times
(BadZipFile, EOFError: a reader found a half-written FMU); a ``--fmu-dir`` entry that is
a symlink to ``/dev/zero`` was read until the kernel killed the process, a FIFO hung, a
dangling symlink made ``build`` write outside the folder; killed builds left
``delaycomp-build-*`` folders behind.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import zipfile

import pytest

from delaycomp.errors import BadFileError
from delaycomp.fmu.build import DEFAULT_CONFIG, build_fmu
from delaycomp.fmu.cache import fmu_file_name, fmu_path
from delaycomp.tmpfiles import sweep

pytestmark = pytest.mark.fmu

FIRST_RUN = textwrap.dedent('''
    import sys, zipfile
    from pathlib import Path
    from delaycomp.fmu.build import DEFAULT_CONFIG
    from delaycomp.fmu.cache import fmu_path
    for kind in ("plant", "delay", "controller"):
        path = fmu_path(kind, dict(DEFAULT_CONFIG[kind]), Path(sys.argv[1]))
        with zipfile.ZipFile(path) as zf:
            assert zf.testzip() is None
    print("OK")
''')


def test_parallel_first_runs_share_one_build(tmp_path):
    """Four processes start together on an empty folder: one builds each FMU while the
    others wait; all four find complete FMUs, and no partial file is left."""
    cache = tmp_path / "cache"
    script = tmp_path / "first_run.py"
    script.write_text(FIRST_RUN, encoding="utf-8")
    procs = [subprocess.Popen([sys.executable, str(script), str(cache)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(4)]
    outcomes = [p.communicate(timeout=600) for p in procs]
    assert [p.returncode for p in procs] == [0] * 4, [err[-500:] for _, err in outcomes]
    assert all(out.strip() == "OK" for out, _ in outcomes)
    files = sorted(p.name for p in cache.iterdir() if not p.name.startswith(".")
                   or not p.name.endswith(".lock"))
    assert files == sorted(fmu_file_name(k, DEFAULT_CONFIG[k])
                           for k in ("plant", "delay", "controller"))


@pytest.mark.parametrize("kind", ["link_to_dev_zero", "fifo", "dangling_link", "folder"])
def test_fmu_dir_entry_that_is_not_a_regular_file_is_refused(tmp_path, kind):
    """Each is refused at once with a one-line BadFileError naming the path; nothing is
    read from it, and nothing is written at the link's target."""
    folder = tmp_path / "fmus"
    folder.mkdir()
    name = fmu_file_name("delay", DEFAULT_CONFIG["delay"])
    entry = folder / name
    outside = tmp_path / "outside.fmu"
    if kind == "link_to_dev_zero":
        entry.symlink_to("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(entry)
    elif kind == "dangling_link":
        entry.symlink_to(outside)
    else:
        entry.mkdir()
    with pytest.raises(BadFileError) as info:
        fmu_path("delay", dict(DEFAULT_CONFIG["delay"]), folder)
    message = str(info.value)
    assert name in message and "\n" not in message
    expected = "is a symbolic link" if "link" in kind else "is not a regular file"
    assert expected in message
    assert not outside.exists()


def test_build_replaces_a_link_instead_of_writing_through_it(tmp_path):
    """``delaycomp build`` into a folder holding a (dangling) link under the FMU's name:
    the link is replaced by the file; the link's target is never created."""
    folder = tmp_path / "out"
    folder.mkdir()
    outside = tmp_path / "outside.fmu"
    (folder / "DelaycompDelay.fmu").symlink_to(outside)
    path = build_fmu("delay", folder)
    assert not outside.exists()
    assert path.is_file() and not path.is_symlink()
    with zipfile.ZipFile(path) as zf:
        assert "modelDescription.xml" in zf.namelist()


def test_folders_of_killed_processes_are_swept(tmp_path):
    """A ``delaycomp-build-<pid>-*`` folder whose process is gone is removed; one of a
    running process (this one's parent) and one without a pid are kept."""
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead_pid = int(dead.stdout)
    stale = tmp_path / f"delaycomp-build-{dead_pid}-abc"
    alive = tmp_path / f"delaycomp-build-{os.getppid()}-def"
    other = tmp_path / "delaycomp-build-xyz"
    for folder in (stale, alive, other):
        folder.mkdir()
        (folder / "file").write_text("x", encoding="utf-8")
    assert sweep("delaycomp-build-", tmp_path) == 1
    assert not stale.exists() and alive.exists() and other.exists()


def test_a_killed_build_leaves_nothing_after_the_next_build(tmp_path, monkeypatch):
    """Build folders are named after their process: a build killed mid-way leaves one,
    the next build in any process removes it."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", None)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    leftover = tmp_path / f"delaycomp-build-{int(dead.stdout)}-killed"
    leftover.mkdir()
    build_fmu("delay", tmp_path / "out")
    assert not leftover.exists()
    assert not list(tmp_path.glob("delaycomp-build-*"))


def test_ecos_runs_leave_no_unpacked_archive(tmp_path, monkeypatch, fmu_dir):
    """Each Ecos run left a 2.2 MB ``ecos_ssp_*`` folder in the temporary folder (its
    process leaves with ``os._exit``): it now unpacks inside the run's own folder."""
    from delaycomp.paper import scenarios
    from delaycomp.verify import thirdparty
    packed = thirdparty.pack_jacobi(scenarios.get("example-3.6").loop(), tmp_path / "j.ssp",
                                    fmu_dir)
    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setenv("TMPDIR", str(temp))
    result = thirdparty.run_ssp("ecos", packed, 0.5)
    assert result.success, result.message
    assert list(temp.iterdir()) == []
