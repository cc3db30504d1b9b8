"""The Python FMUs leave a host's heap intact, whatever the call sequence (issue 30, item 10).

Before, two writes into freed memory at a host's exit:

- pythonfmu's runtime library, still loaded when a host exits (the first pythonfmu FMU of
  a process always is), decremented a count inside a block its static destructor had
  freed (``finalizePythonInterpreter``; ``delaycomp.fmu.runtime``), and a later
  ``free`` aborted the host with "corrupted double-linked list": 8 of 300 plain fmpy hosts
  running the sequences below (0 to 2 of 30 per sequence), 23 of 100 hosts that ran the
  loop's three FMUs through ``FmuComponent``. Our build
  ships the library with that function returning at once;
- a state the host freed twice (pythonfmu drops one reference per free) reached zero while
  the interpreter's teardown still freed its pins, which then read and wrote the freed
  token (``delaycomp.fmu.statehandle._never_freed``): the pins are now never freed.

Every host here is a fresh plain-fmpy process (``scripts/fmi_sequence_child.py``) that
leaves through the interpreter's normal exit. Whether such a write aborts a host depends on
how its heap lies at exit: the counts of fresh hosts alone (3 per sequence, 30 in all, at
the measured 2.7 %) would catch the first defect in about half of the CI runs. The host run
under valgrind finds each on every run (the first in 4 of 4 runs before, the second in 2
of 2), so the test fails reliably where valgrind is installed.
``scripts/crash_rate.py --fmi-sequences --runs 200`` counts hundreds of hosts per sequence
(docs/explanation/reliability.md).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from delaycomp.fmu.runtime import (
    SYMBOL,
    _symbol_offset,
    is_runtime,
    patch_runtime,
    stock_runtime,
)

from .external import need

pytestmark = pytest.mark.fmu

CHILD = Path(__file__).resolve().parents[1] / "scripts" / "fmi_sequence_child.py"
_spec = importlib.util.spec_from_file_location("fmi_sequence_child", CHILD)
assert _spec is not None and _spec.loader is not None
_child = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_child)
SEQUENCES = list(_child.SEQUENCES)
LOOP = ("DelaycompPlantLTI.fmu", "DelaycompDelay.fmu", "DelaycompControllerLTI.fmu")
#: fresh hosts per sequence (module docstring)
RUNS = 3


def run_host(sequence: str, fmus: list[str], prefix: tuple[str, ...] = (),
             env: dict | None = None) -> subprocess.CompletedProcess:
    """A fresh host (behind ``prefix``, e.g. valgrind) running ``sequence`` on ``fmus``."""
    return subprocess.run([*prefix, sys.executable, str(CHILD), sequence, *fmus],
                          capture_output=True, text=True, timeout=600, env=env)


@pytest.fixture(scope="module")
def loop_fmus(fmu_dir) -> list[str]:
    return [str(fmu_dir / name) for name in LOOP]


def test_every_fmu_ships_the_fixed_runtime_library(loop_fmus):
    """The linux64 library of each FMU is pythonfmu's, but for the one byte of the fix."""
    stock = stock_runtime().read_bytes()
    offset = _symbol_offset(stock, SYMBOL)
    assert offset is not None, "pythonfmu's library has no finalizePythonInterpreter"
    for path in loop_fmus:
        with zipfile.ZipFile(path) as zf:
            libraries = [n for n in zf.namelist() if is_runtime(n)]
            assert len(libraries) == 1, libraries
            shipped = zf.read(libraries[0])
        assert shipped == patch_runtime(stock) != stock
        assert [i for i, (a, b) in enumerate(zip(stock, shipped)) if a != b] == [offset + 4]
        assert shipped[offset:offset + 5] == b"\xf3\x0f\x1e\xfa\xc3"  # endbr64; ret


@pytest.mark.parametrize("sequence", SEQUENCES)
def test_each_sequence_in_fresh_hosts_exits_normally(loop_fmus, sequence):
    """Each call sequence, legal or illegal, on the loop's three FMUs in one host: the host
    ends with status 0 after ``DONE`` (before: SIGABRT now and then, after ``DONE``)."""
    for run in range(RUNS):
        proc = run_host(sequence, loop_fmus)
        assert proc.returncode == 0, (f"run {run}: status {proc.returncode}: "
                                      f"{proc.stderr[-1500:]}")
        assert f"DONE {sequence}" in proc.stdout


#: a valgrind error report, from its headline to the blank line that ends it
_REPORT = re.compile(r"^==\d+== (Invalid|Mismatched|Source and destination).*?(?=^==\d+== $)",
                     re.MULTILINE | re.DOTALL)


def invalid_accesses(log: str) -> list[str]:
    """valgrind's reports of invalid accesses and frees in ``log``, but for the dynamic
    loader's own (glibc's ``strncmp`` reads whole words past a string when it loads a
    library: ``is_dst (dl-load.c)``, in every Python process)."""
    reports = (m.group(0) for m in _REPORT.finditer(log + "\n==0== \n"))
    return [r for r in reports if "dl-load.c" not in r]


@pytest.mark.slow  # valgrind over a whole Python FMU loop (about 20 s)
def test_no_invalid_access_under_valgrind(fmu_dir, tmp_path):
    """Every sequence in turn on the controller FMU in one host under valgrind, the issue's
    (set the output ``u``, get, step, terminate, free) first among the illegal ones: no
    invalid access in the host. Before, on every run: "Invalid read of size 4 at
    finalizePythonInterpreter, 8 bytes inside a block of size 128 free'd by
    __run_exit_handlers" (the runtime library), and "Invalid read of size 8 at Py_DECREF,
    list_dealloc, 0 bytes inside a block of size 40 free'd" (a state's token freed twice by
    the host, then once more by the teardown: ``delaycomp.fmu.statehandle._never_freed``)."""
    valgrind = need("valgrind")
    log = tmp_path / "valgrind.txt"
    env = dict(os.environ, PYTHONMALLOC="malloc")  # every object on the C heap: checked
    proc = run_host("all", [str(fmu_dir / "DelaycompControllerLTI.fmu")],
                    (valgrind, "--error-limit=no", "--num-callers=30", f"--log-file={log}"),
                    env)
    assert proc.returncode == 0 and "DONE all" in proc.stdout, proc.stderr[-1500:]
    found = invalid_accesses(log.read_text(encoding="utf-8", errors="replace"))
    assert not found, "\n".join(found)[:4000]
