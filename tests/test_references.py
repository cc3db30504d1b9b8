"""Reference traces: independent of the package, and reproducible from their scripts.

A regenerated trace equals the committed one to round-off, not byte for byte: the last bits
depend on the machine's BLAS kernel (the scripts' matrix products and ``expm``), on its
libm (``exp``, ``sin``) and on the scipy version. Tolerances, per column, relative to the
column's peak (round-off made at the largest values is carried into the smaller ones):

- exact flows (Example 3.6, Example 3.8, Corollary 3.7, Proposition 4.2): each sample is a
  closed-form flow of a few operations per state (dot products of at most n + m <= 5
  terms: a few EPS each), carried along a loop that contracts or, uncompensated, grows with
  the signal itself: ``EXACT_ULPS`` = 64 EPS of the peak (measured at most 1.8 EPS with the
  SkylakeX, Haswell, Sandybridge and Nehalem kernels);
- ODE solves (Example 2.4, Corollary 4.1; DOP853 at rtol = atol = 1e-12): the step sizes the
  solver picks depend on the last bits of its error estimate, so a regeneration may take
  other steps and lands elsewhere within the solver's accuracy, which each script states
  (``--check``): Example 2.4 within 2.9e-12 of a run at 1e-13, Corollary 4.1 within 4e-14 of
  Radau and of DOP853 at a quarter of the step. Measured: at most 4.3e-14 (Example 2.4
  with the Haswell kernel, 218 EPS of the peak; 16 EPS with Sandybridge and Nehalem).
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys

import pytest

from .conftest import REPO
from .roundoff import EXACT_ULPS, assert_csv_close

#: script -> the accuracy it states for its ODE solve (absolute, on O(1) signals)
ODE_ACCURACY = {"example_2_4": 2.9e-12, "corollary_4_1": 4e-14}

#: what the scripts share (file writing, the ODE solve, the command line): no script itself
HELPER = REPO / "reference" / "reftools.py"
SCRIPTS = sorted(p for p in (REPO / "reference").glob("*.py")
                 if p.name not in ("__init__.py", HELPER.name))


def imported_roots(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            roots.add(node.module.split(".")[0])
    return roots


@pytest.mark.parametrize("script", [*SCRIPTS, HELPER], ids=[s.stem for s in [*SCRIPTS, HELPER]])
def test_reference_script_uses_only_stdlib_numpy_scipy(script):
    """The scripts and their helper import the standard library, numpy, scipy and (the
    scripts) the helper: nothing of delaycomp."""
    allowed = {"numpy", "scipy"} | ({HELPER.stem} if script != HELPER else set())
    foreign = imported_roots(script) - set(sys.stdlib_module_names) - allowed
    assert not foreign, f"{script.name} imports {sorted(foreign)}"


def test_the_scripts_share_their_file_writing_and_solver_set_up():
    """One helper writes every trace and sets up every ODE solve of the writing path: no
    script opens a CSV itself or keeps its own copy of the solve."""
    for script in SCRIPTS:
        text = script.read_text(encoding="utf-8")
        assert "write_trace(" in text and "csv.writer" not in text, script.name
        assert "def _ivp" not in text or "return solve(" in text, script.name
        assert "def split_delay" not in text, script.name


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_reference_script_reproduces_the_stored_traces(script, tmp_path):
    copy = tmp_path / "reference"
    shutil.copytree(REPO / "reference", copy)
    outputs = {p.relative_to(copy) for p in copy.rglob("*_ref.*")}
    for p in outputs:
        (copy / p).unlink()
    proc = subprocess.run([sys.executable, str(copy / script.name)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    made = {p.relative_to(copy) for p in copy.rglob("*_ref.*")}
    assert made, "the script wrote no trace"
    folders = {rel.parent for rel in made}
    assert made == {rel for rel in outputs if rel.parent in folders}, \
        "the script wrote other files than the committed ones"
    hint = f"regenerate with `python reference/{script.name}` if the method changed"
    for rel in made:
        new, kept = copy / rel, REPO / "reference" / rel
        if rel.suffix == ".opt":  # settings typed in the script: text, exactly
            assert new.read_text() == kept.read_text(), f"{rel} ({hint})"
        else:
            assert_csv_close(new, kept, EXACT_ULPS, atol=ODE_ACCURACY.get(script.stem, 0.0),
                             hint=hint)
