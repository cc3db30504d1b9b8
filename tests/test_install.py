"""The install as users do it: one namespace, package data, children that find our code,
``python -m delaycomp``, and optional masters reported honestly.

The wheel itself is built here from a copy of the checkout (``pip wheel``), and its file
list is checked; ``.ci/wheel-smoke`` installs it into a fresh venv and runs the commands.
"""

from __future__ import annotations

import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

import delaycomp
from delaycomp.child import module_argv
from delaycomp.verify import check

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """A wheel built from the checkout's tracked and new files (not the ignored ones)."""
    tmp = tmp_path_factory.mktemp("wheel")
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"],
                           cwd=REPO, capture_output=True, text=True, check=True).stdout.split()
    src = tmp / "src"
    with tarfile.open(tmp / "src.tar", "w") as tar:
        for name in files:
            if (REPO / name).exists():
                tar.add(REPO / name, arcname=name)
    with tarfile.open(tmp / "src.tar") as tar:
        tar.extractall(src, filter="data")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w",
                           str(tmp / "dist"), str(src)], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (whl,) = (tmp / "dist").glob("delaycomp-*.whl")
    return whl


def test_wheel_installs_only_the_delaycomp_namespace(wheel):
    with zipfile.ZipFile(wheel) as z:
        tops = {name.split("/")[0] for name in z.namelist()}
    assert tops == {"delaycomp", f"delaycomp-{delaycomp.__version__}.dist-info"}


def test_wheel_holds_every_package_and_the_data_commands_read(wheel):
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
    # every package folder of the repository, under the name it installs as
    mapping = {"delaycomp": "delaycomp", "orchestrator": "delaycomp/orchestrator",
               "fmus": "delaycomp/fmus", "reference": "delaycomp/reference"}
    for folder, installed in mapping.items():
        for init in (REPO / folder).rglob("__init__.py"):
            rel = init.relative_to(REPO / folder).as_posix()
            assert f"{installed}/{rel}" in names, f"{folder}/{rel} is not in the wheel"
    # what the commands read at run time: every reference trace, the FMU READMEs
    for c in check.CASES:
        for path in (c.csv_path, c.opt_path):
            rel = path.relative_to(REPO / "reference").as_posix()
            assert f"delaycomp/reference/{rel}" in names
    for readme in (REPO / "fmus").glob("*/README.md"):
        assert f"delaycomp/fmus/{readme.parent.name}/README.md" in names
    for loop in (REPO / "delaycomp" / "paper" / "loops").glob("*.toml"):  # the scenarios as data
        assert f"delaycomp/paper/loops/{loop.name}" in names
    # the C sources that `build --native` compiles, and the C host
    for source in (REPO / "fmus" / "native").rglob("*.[ch]"):
        rel = source.relative_to(REPO / "fmus").as_posix()
        assert f"delaycomp/fmus/{rel}" in names, f"fmus/{rel} is not in the wheel"


def test_python_m_delaycomp_is_the_command(tmp_path):
    got = subprocess.run([sys.executable, "-m", "delaycomp", "--version"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=60)
    assert got.returncode == 0, got.stderr
    assert got.stdout.strip() == f"delaycomp {delaycomp.__version__}"


def test_children_ignore_a_delaycomp_folder_in_their_working_folder(tmp_path):
    """A working folder holding a ``delaycomp/`` (a checkout, a build's staging copy) must
    not shadow this process's package in a child."""
    fake = tmp_path / "delaycomp"
    fake.mkdir()
    (fake / "__init__.py").write_text("raise ImportError('the shadowing copy was imported')\n")
    got = subprocess.run(module_argv("delaycomp", "--version"), cwd=tmp_path,
                         capture_output=True, text=True, timeout=60)
    assert got.returncode == 0, got.stderr
    assert got.stdout.strip() == f"delaycomp {delaycomp.__version__}"


@pytest.fixture
def absent_master(monkeypatch):
    """An optional master whose module is not installed."""
    calls = []
    masters = dict(check.PROVIDERS.masters)
    masters["nowhere"] = check.RegisteredMaster(
        lambda cases: calls.append(cases) or [],
        check.Requirement(("delaycomp_no_such_module",), "pip install nowhere"))
    monkeypatch.setattr(check.PROVIDERS, "masters", masters)
    return calls


def test_absent_optional_master_is_skipped_not_failed(absent_master):
    (row,) = [r for r in check.run_checks([], None) if r.master == "nowhere"]
    assert row.passed is None
    assert "not installed (delaycomp_no_such_module): pip install nowhere" in row.note
    assert absent_master == []  # never called
    assert "skipped" in check.format_table([row])


@pytest.mark.parametrize("how", ["named", "require_all"])
def test_absent_master_is_a_failure_when_required(absent_master, how):
    if how == "named":
        rows = check.run_checks([], ["nowhere"])
    else:
        rows = [r for r in check.run_checks([], None, require_all=True)
                if r.master == "nowhere"]
    assert [r.passed for r in rows] == [False]
    assert "pip install nowhere" in rows[0].note
