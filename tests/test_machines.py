"""Green on every machine: the suite keeps the machine's BLAS settings and compares no file
of computed numbers byte for byte (tests/roundoff.py says why and how instead).

Some processors need ``OPENBLAS_CORETYPE`` (and ``OPENBLAS_L2_SIZE``) set, because other
kernels crash or compute wrong results there: no test and no CI script may set or unset
them, and a child started with a cleared environment (``env -i``) gets them passed on."""

from __future__ import annotations

import re

import pytest

from .conftest import REPO, machine_blas_settings

#: what sets, unsets or drops an OPENBLAS_ variable in Python or shell
TOUCHES_BLAS = re.compile(
    r"OPENBLAS_\w*\s*=|environ\[['\"]OPENBLAS|(?:pop|delenv|setenv)\(['\"]OPENBLAS|"
    r"unset\s+OPENBLAS|-u\s+OPENBLAS")
#: comparisons of whole files byte for byte
FILE_BYTES = re.compile(r"filecmp|read_bytes\(\)\s*[!=]=|[!=]=\s*[\w.()/\[\]\" ]*read_bytes\(\)")

#: every test module and CI script but this one (whose patterns and examples name them)
TESTS = sorted(p for p in REPO.glob("tests/*.py") if p.name != "test_machines.py")
SCRIPTS = [*TESTS, *sorted(REPO.glob(".ci/*"))]


@pytest.mark.parametrize("path", SCRIPTS, ids=[p.name for p in SCRIPTS])
def test_no_test_or_ci_script_touches_the_blas_settings(path):
    text = path.read_text(encoding="utf-8")
    hits = [m.group(0) for m in TOUCHES_BLAS.finditer(text)]
    assert not hits, f"{path.name} sets or unsets the machine's BLAS settings: {hits}"


@pytest.mark.parametrize("path", TESTS, ids=[p.name for p in TESTS])
def test_no_test_compares_files_byte_for_byte(path):
    """Files of computed numbers are compared to round-off (tests/roundoff.py); a file
    whose bytes are the contract (an archive, generated text) is compared as text or by
    its members, saying so."""
    text = path.read_text(encoding="utf-8")
    hits = [m.group(0) for m in FILE_BYTES.finditer(text)]
    assert not hits, f"{path.name}: {hits}"


def test_the_guards_catch_what_they_are_for():
    for bad in ("OPENBLAS_CORETYPE=Nehalem pytest", 'os.environ["OPENBLAS_CORETYPE"] = "x"',
                'monkeypatch.delenv("OPENBLAS_CORETYPE")', "unset OPENBLAS_L2_SIZE",
                "env -u OPENBLAS_CORETYPE python"):
        assert TOUCHES_BLAS.search(bad), bad
    for bad in ("filecmp.cmp(a, b)", "assert a.read_bytes() == b.read_bytes()",
                'assert (tmp / "a.csv").read_bytes() != c'):
        assert FILE_BYTES.search(bad), bad
    assert FILE_BYTES.search('png.read_bytes()[:4] == b"PNG"') is None


def test_a_cleared_environment_gets_the_machines_blas_settings():
    environ = {"OPENBLAS_CORETYPE": "Haswell", "OPENBLAS_L2_SIZE": "1048576", "PATH": "/bin"}
    assert machine_blas_settings(environ) == ["OPENBLAS_CORETYPE=Haswell",
                                              "OPENBLAS_L2_SIZE=1048576"]
